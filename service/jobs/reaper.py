"""Re-queues jobs whose worker died (stale heartbeat) and queue messages that got lost.

Safe to run in any number of processes at once: every transition is a conditional
update, so exactly one reaper wins each job.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from service.jobs.db import JobRepository
from service.settings import Settings

log = logging.getLogger("otgeo.reaper")


DONE_MARKER_TTL = 3600.0  # seconds a completion marker is kept (waiting clients only)


class Reaper:
    def __init__(self, settings: Settings, repo: JobRepository,
                 enqueue: Callable[[str, str | None], None], store=None, watch=None,
                 sweep: Callable[[], list[str]] | None = None):
        self.settings, self.repo, self.enqueue, self.store = settings, repo, enqueue, store
        self.watch = watch  # a BrokerWatch (service.jobs.broker), checked more often
        self.sweep = sweep  # removes released content nobody holds (service.domains)
        self._broker_down = False
        self._last_prune = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def run_once(self) -> dict[str, list[str]]:
        now = time.time()
        requeued, failed, resent = [], [], []
        before = now - self.settings.stale_after
        for job in self.repo.stale_running(before):
            if job.attempts >= (job.max_attempts or self.settings.max_attempts):
                error = {"code": "worker_lost", "field": None,
                         "message": f"the worker running this job stopped responding "
                                    f"{job.attempts} time(s); giving up"}
                if self.repo.fail_stale(job, before, error):
                    failed.append(job.id)
            elif self.repo.requeue(job, before):
                requeued.append(job.id)
                self._send(job.id, job.queue)
        # A worker stuck in a step that never checks for cancellation: the job is reported
        # failed; the worker's late result is refused (it no longer owns the job).
        for job in self.repo.overdue_running(now, self.settings.stale_after):
            error = {"code": "time_limit_exceeded", "field": "time_limit",
                     "message": f"job exceeded its time limit of {job.time_limit:g} s"}
            if self.repo.fail_overdue(job, error):
                failed.append(job.id)
        for job in self._unsent(now):
            if self.repo.touch_queued(job):
                resent.append(job.id)
                self._send(job.id, job.queue)
        if self.store is not None and now - self._last_prune > DONE_MARKER_TTL / 4:
            self._last_prune = now
            self.store.prune_done_markers(DONE_MARKER_TTL)
        if requeued or failed or resent:
            log.warning("reaper: requeued %s, failed %s, re-sent %s", requeued, failed, resent)
        return {"requeued": requeued, "failed": failed, "resent": resent}

    def _unsent(self, now: float) -> list:
        """Queued jobs to re-send as a last resort: none on the embedded queue, where the
        job row is the message (nothing to lose, and a re-send only woke the workers)."""
        if self.settings.queue != "redis":
            return []
        return self.repo.stale_queued(now - self.settings.requeue_queued_after)

    def _send(self, job_id: str, queue: str | None = None) -> None:
        try:
            self.enqueue(job_id, queue)
        except Exception:  # broker down: the job stays queued and is re-sent later
            log.exception("could not enqueue job %s", job_id)

    def check_broker(self) -> list[str]:
        """Re-send the queued jobs the broker lost (logged once per outage when down)."""
        try:
            resent = self.watch.check()
        except Exception as exc:
            if not self._broker_down:
                log.warning("broker check failed (%s); retrying", type(exc).__name__)
            self._broker_down = True
            return []
        if self._broker_down:
            log.warning("broker reachable again")
        self._broker_down = False
        return resent

    def sweep_once(self) -> list[str]:
        """The stored domains removed by ``sweep`` (none without one)."""
        if self.sweep is None:
            return []
        try:
            return self.sweep()
        except Exception:
            log.exception("sweep of released domains failed")
            return []

    def start(self, sweep_only: bool = False) -> None:
        """The loop in a thread; ``sweep_only`` (the immediate queue: jobs run in requests,
        no broker) runs only the sweep."""
        interval = self.settings.reaper_interval
        tick = interval if self.watch is None else \
            min(interval, self.settings.broker_check_interval)

        def loop():
            next_pass = time.monotonic() + interval
            while not self._stop.wait(tick):
                if self.watch is not None and not sweep_only:
                    self.check_broker()
                if time.monotonic() < next_pass:
                    continue
                next_pass = time.monotonic() + interval
                self.sweep_once()
                if sweep_only:
                    continue
                try:
                    self.run_once()
                except Exception:
                    log.exception("reaper pass failed")

        self._thread = threading.Thread(target=loop, daemon=True, name="reaper")
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
