"""Huey queues from the settings: SqliteHuey (embedded), RedisHuey (scaled out) or immediate
mode (tests).  The task code is the same for all: it receives a job id only.

Two queues (``short`` and ``long``, see :func:`queue_for_cost`) keep short jobs from waiting
behind long ones; a worker serves one or both (service.jobs.consumer).

Trust boundary: a queue message is JSON ``{"v": 1, "id", "name", "args": [job_id]}``
(:class:`JsonSerializer`), never a pickle. Whoever can write to the broker (Redis, or the
SQLite queue file) can only name job ids, which the worker looks up in the job table; any
other message is logged and dropped without being decoded further.
"""

from __future__ import annotations

import json
import logging
import re

from huey import Huey, RedisHuey, SqliteHuey
from huey.registry import Message
from huey.serializer import Serializer
from huey.storage import SqliteStorage

from service.settings import Settings

log = logging.getLogger("otgeo.queue")

TASK_NAME = "otgeo.run_job"
TASK_STRING = f"{__name__}.{TASK_NAME}"  # how Huey's registry names the task in a message
QUEUES = ("short", "long")
MESSAGE_VERSION = 1
_JOB_ID = re.compile(r"^[0-9A-Za-z_-]{1,64}$")
_MESSAGE_ID = re.compile(r"^[0-9a-zA-Z-]{1,64}$")


class UnsafeMessage(ValueError):
    """A queue message that is not one of ours (never unpickled: dropped)."""


class JsonSerializer(Serializer):
    """Huey messages as JSON carrying one job id; anything else is refused both ways."""

    def _serialize(self, message: Message) -> bytes:
        extras = (message.eta, message.on_complete, message.on_error, message.expires,
                  message.chord_config, message.timeout)
        if any(x is not None for x in extras) or message.kwargs or message.retries:
            raise UnsafeMessage("only plain job-id messages are sent (no eta, retries, "
                                "pipelines or keyword arguments)")
        args = list(message.args or ())
        if message.name != TASK_STRING:
            raise UnsafeMessage(f"unknown task {message.name!r}")
        if len(args) != 1 or not isinstance(args[0], str):
            raise UnsafeMessage("a queue message carries exactly one job id")
        return json.dumps({"v": MESSAGE_VERSION, "id": str(message.id),
                           "name": message.name, "args": args,
                           "priority": message.priority}, separators=(",", ":")).encode()

    def _deserialize(self, data: bytes) -> Message:
        try:
            obj = json.loads(data)
        except (ValueError, UnicodeDecodeError, RecursionError) as exc:
            raise UnsafeMessage("queue message is not JSON") from exc
        if not isinstance(obj, dict) or obj.get("v") != MESSAGE_VERSION or \
                set(obj) - {"v", "id", "name", "args", "priority"}:
            raise UnsafeMessage("queue message has an unknown shape")
        args, mid, name = obj.get("args"), obj.get("id"), obj.get("name")
        priority = obj.get("priority")
        if name != TASK_STRING or not isinstance(mid, str) or not _MESSAGE_ID.match(mid) or \
                not isinstance(args, list) or len(args) != 1 or \
                not isinstance(args[0], str) or not _JOB_ID.match(args[0]) or \
                not (priority is None or type(priority) is int):
            raise UnsafeMessage("queue message does not name one job id")
        return Message(id=mid, name=name, eta=None, retries=0, retry_delay=0,
                       priority=priority, args=(args[0],), kwargs={}, on_complete=None,
                       on_error=None, expires=None, expires_resolved=None, timeout=None,
                       chord_config=None, retry_backoff=None)


class WalNormalSqliteStorage(SqliteStorage):
    """Huey's SQLite storage with ``synchronous=NORMAL`` (WAL): no fsync per enqueue and still
    never corrupted by a crash. Jobs are not sent through it (the job table is the embedded
    queue, ``JobRepository.claim_next``); it carries messages of older APIs only."""

    def _create_connection(self):
        conn = super()._create_connection()
        conn.execute("pragma synchronous=1")
        return conn

    wake = None  # a WakeSocket in worker processes (service.jobs.wake)
    wake_timeout = 1.0  # longest block on it; then the queue is read anyway

    def dequeue_now(self):
        """The next message without blocking (None when empty). An empty queue (the usual
        case: the job table is the queue) is seen by a read, without the exclusive
        transaction huey's dequeue opens."""
        with self.db() as curs:
            curs.execute("SELECT 1 FROM task WHERE queue = ? LIMIT 1", (self.name,))
            if curs.fetchone() is None:
                return None
        return SqliteStorage.dequeue(self)

    def dequeue(self):
        """Block on the wake-up socket while the queue is empty (no idle polling): the
        API sends a datagram after every enqueue."""
        data = super().dequeue()
        if data is None and self.wake is not None and self.wake.sock is not None:
            if self.wake.wait(self.wake_timeout):
                data = super().dequeue()
        return data


def queue_name(settings: Settings, queue: str) -> str:
    return settings.queue_name if queue == "short" else f"{settings.queue_name}-{queue}"


def make_huey(settings: Settings, queue: str = "short") -> Huey:
    name = queue_name(settings, queue)
    serializer = JsonSerializer()
    if settings.queue == "redis":
        return RedisHuey(name, url=settings.redis_url, results=False, blocking=True,
                         read_timeout=1, serializer=serializer)
    if settings.queue == "immediate":
        return SqliteHuey(name, results=False, immediate=True, serializer=serializer)
    settings.ensure_dirs()
    return SqliteHuey(name, filename=str(settings.data_dir / "queue.sqlite3"),
                      results=False, storage_class=WalNormalSqliteStorage,
                      serializer=serializer)


def make_queues(settings: Settings) -> dict[str, Huey]:
    return {q: make_huey(settings, q) for q in QUEUES}


def register_task(huey: Huey, run):
    """Register ``run(job_id)`` as the one queue task; returns the task wrapper."""

    @huey.task(name=TASK_NAME)
    def run_job(job_id: str) -> None:
        run(job_id)

    return run_job


# -- which queue a job goes to ------------------------------------------------------------
def queue_for_cost(settings: Settings, cost: float) -> str:
    """``"long"`` for a job whose estimated cost (``Operation.estimate_cost``, else
    :func:`service.operations.cost.estimate_cost`) reaches ``long_job_cost``, else
    ``"short"``."""
    return "long" if cost >= settings.long_job_cost else "short"
