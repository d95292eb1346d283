"""Huey instance from the settings: SqliteHuey (embedded), RedisHuey (scaled out) or
immediate mode (tests).  The task code is the same for all: it receives a job id only."""

from __future__ import annotations

from huey import Huey, RedisHuey, SqliteHuey
from huey.storage import SqliteStorage

from service.settings import Settings

TASK_NAME = "otgeo.run_job"


class WalNormalSqliteStorage(SqliteStorage):
    """Huey's SQLite storage with ``synchronous=NORMAL`` (WAL): no fsync per enqueue and still
    never corrupted by a crash; a message lost to a power cut is re-sent by the reaper from
    the job table (``requeue_queued_after``)."""

    def _create_connection(self):
        conn = super()._create_connection()
        conn.execute("pragma synchronous=1")
        return conn

    wake = None  # a WakeSocket in worker processes (service.jobs.wake)
    wake_timeout = 1.0  # longest block on it; then the queue is read anyway

    def dequeue(self):
        """Block on the wake-up socket while the queue is empty (no idle polling): the
        API sends a datagram after every enqueue."""
        data = super().dequeue()
        if data is None and self.wake is not None and self.wake.sock is not None:
            if self.wake.wait(self.wake_timeout):
                data = super().dequeue()
        return data


def make_huey(settings: Settings) -> Huey:
    if settings.queue == "redis":
        return RedisHuey(settings.queue_name, url=settings.redis_url, results=False,
                         blocking=True, read_timeout=1)
    if settings.queue == "immediate":
        return SqliteHuey(settings.queue_name, results=False, immediate=True)
    settings.ensure_dirs()
    return SqliteHuey(settings.queue_name, filename=str(settings.data_dir / "queue.sqlite3"),
                      results=False, storage_class=WalNormalSqliteStorage)


def register_task(huey: Huey, run):
    """Register ``run(job_id)`` as the one queue task; returns the task wrapper."""

    @huey.task(name=TASK_NAME)
    def run_job(job_id: str) -> None:
        run(job_id)

    return run_job
