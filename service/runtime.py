"""Everything one process of the service holds: settings, storage, job table, queue,
operator cache, runner and reaper.  Built once per process (API or worker)."""

from __future__ import annotations

import logging
import threading
import time

from service.cache import OperatorCache
from service.domains import sweep_released_domains
from service.jobs.broker import BrokerWatch
from service.jobs.db import JobRepository, worker_identity
from service.jobs.queue import QUEUES, make_queues, register_task
from service.jobs.reaper import Reaper
from service.jobs.runner import JobRunner
from service.jobs.tenancy import TenancyRepository
from service.jobs.wake import WakeSender
from service.operations import build_registry
from service.settings import Settings
from service.storage_probe import STORAGE_ERRNOS, storage_reason, storage_status  # noqa: F401
from service.store import Store
from service.tenants import TenantDirectory

log = logging.getLogger("otgeo")


class Runtime:
    def __init__(self, settings: Settings, role: str = "api"):
        settings.ensure_dirs()
        self.settings = settings
        self.role = role
        self.started_at = time.time()
        self.store = Store(settings.data_dir)
        self.repo = JobRepository(settings.job_database_url)
        self.tenancy = TenancyRepository(self.repo)  # holdings and idempotency keys
        self.tenants = TenantDirectory(settings)  # API keys -> tenants
        self.cache = OperatorCache(settings.cache_bytes)
        self.operations = build_registry()
        self.hueys = make_queues(settings)  # "short" and "long" (service.jobs.queue)
        self.huey = self.hueys["short"]
        self.runner = JobRunner(settings, self.store, self.repo, self.cache, self.operations)
        self.tasks = {q: register_task(h, self.runner.run) for q, h in self.hueys.items()}
        self.runner.enqueue = self.enqueue  # a fanned-out job's blocks (service.jobs.fanout)
        self.task = self.tasks["short"]
        self.broker_watch = BrokerWatch(settings, self.repo, self.hueys, self.enqueue)
        self.reaper = Reaper(settings, self.repo, self.enqueue, self.store, self.broker_watch,
                             sweep=self.sweep_released)
        # wake-up datagrams to this machine's processes (enqueued -> workers, done -> API)
        self.wake = WakeSender(settings.data_dir) if settings.queue != "immediate" else None
        if self.wake is not None:
            self.runner.notify_done = lambda job_id: self.wake.notify("api", job_id)
        self._stop = threading.Event()
        self._published = threading.Event()
        self._presence: threading.Thread | None = None
        self.waiters = None  # API: JobWaiters while the app runs (service.jobs.wake)

    def sweep_released(self) -> list[str]:
        """Remove the stored domains that tenants released and nobody holds now."""
        return sweep_released_domains(self)

    @property
    def process_id(self) -> str:
        return worker_identity()

    def enqueue(self, job_id: str, queue: str | None = None) -> None:
        """Send a job id to its queue (``short`` unless given; in immediate mode: run it).

        On the embedded SQLite queue the job table is the queue (the recorded job row is the
        message: ``JobRepository.claim_next``): only the local workers are woken."""
        queue = queue if queue in QUEUES else "short"
        if self.settings.queue != "sqlite":
            self.tasks[queue](job_id)
        elif self.wake is not None:
            self.wake.notify("worker", job_id)  # Redis workers block on the list already

    def pending_messages(self) -> int | None:
        if self.settings.queue == "immediate":
            return 0
        try:
            messages = sum(int(h.pending_count()) for h in self.hueys.values())
            if self.settings.queue == "sqlite":  # the job table is the queue
                messages += sum(self.repo.queued_by_queue().values())
            return messages
        except Exception:  # broker down
            return None

    _broker_checked = (0.0, None)
    BROKER_CHECK_EVERY = 1.0  # seconds a broker probe result is reused

    def broker_status(self) -> dict:
        """Whether the queue's broker answers, its messages and the restarts seen (probed at
        most once a second)."""
        at, status = self._broker_checked
        if status is None or time.monotonic() - at > self.BROKER_CHECK_EVERY:
            status = {"reachable": True, "messages": None,
                      "restarts": self.broker_watch.restarts, "reason": None}
            try:
                if self.settings.queue == "redis":
                    self.huey.storage.conn.ping()
                status["messages"] = self.pending_messages()
            except Exception as exc:  # the broker is down: no details (they name hosts)
                status.update(reachable=False, reason=f"{type(exc).__name__}: the broker "
                              "does not answer")
            self._broker_checked = (time.monotonic(), status)
        return status

    # -- storage -----------------------------------------------------------
    _storage_checked = (0.0, None)
    STORAGE_CHECK_EVERY = 1.0  # seconds a storage probe result is reused

    def storage_status(self) -> dict:
        """Whether the data directory takes writes, and its free bytes (probed at most
        once a second)."""
        at, status = self._storage_checked
        if status is None or time.monotonic() - at > self.STORAGE_CHECK_EVERY:
            status = storage_status(self.settings.data_dir,
                                    (self.store.domain_dir, self.store.result_dir))
            status["low_space"] = status["free_bytes"] is not None and \
                status["free_bytes"] < self.settings.min_free_bytes
            self._storage_checked = (time.monotonic(), status)
        return status

    # -- background threads ---------------------------------------------
    def start_background(self, publish: bool) -> None:
        """Start the reaper (and, in workers, publishing of cache statistics)."""
        self.reaper.start(sweep_only=self.settings.queue == "immediate")
        if publish:
            self.runner.on_finished = self._published.set  # publish once idle, see below
            self._presence = threading.Thread(target=self._publish_loop, daemon=True,
                                              name="presence")
            self._presence.start()

    def publish(self) -> None:
        self.repo.publish_worker(self.process_id, self.started_at, self.runner.jobs_done,
                                 self.cache.stats())

    def _publish_loop(self) -> None:
        while True:
            try:
                self.publish()
            except Exception:
                log.exception("could not publish worker statistics")
            finished = self._published.wait(self.settings.heartbeat_interval)
            self._published.clear()
            if self._stop.is_set():
                return
            if finished:
                self._wait_idle(self.settings.heartbeat_interval)

    PUBLISH_IDLE = 0.05  # seconds without a job before statistics are published after one

    def _wait_idle(self, longest: float) -> None:
        """After a job: wait until the worker has been idle ``PUBLISH_IDLE`` seconds (at most
        ``longest``), so the publish stays off the path of back-to-back jobs and of the
        waiting client's response, yet /metrics is current as soon as the worker rests."""
        deadline = time.monotonic() + longest
        while time.monotonic() < deadline and not self._stop.is_set():
            runner = self.runner
            if runner.current is None and \
                    time.monotonic() - runner.last_finished >= self.PUBLISH_IDLE:
                return
            time.sleep(self.PUBLISH_IDLE / 2)

    def close(self) -> None:
        self._stop.set()
        self._published.set()
        self.reaper.stop()
        if self._presence is not None:
            self._presence.join(timeout=5)
            try:
                self.repo.remove_worker(self.process_id)
            except Exception:
                pass
        self.repo.dispose()
        if self.wake is not None:
            self.wake.close()
        # the domains and their factorizations go now, not whenever the runtime is collected
        self.cache.discard_where(lambda key: True)

