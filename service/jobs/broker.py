"""Recovery from a lost broker: re-send queued jobs whose messages are gone, at once.

The job table is the source of truth; the broker only carries job ids. A Redis restarted
without persistence (or flushed) loses every message: the jobs stay ``queued`` in the table
and, before this watch, waited for ``requeue_queued_after`` (300 s). Every
``broker_check_interval`` seconds each process with a reaper compares the broker with the
table: a changed Redis ``run_id`` (a restart), or a queue holding fewer messages than the
table has queued jobs, triggers a diff; every queued job whose id is in no message is
re-sent, oldest first. A job is re-sent by one process only (the conditional update of its
``enqueued_at``, as for the reaper's re-sends). A message re-sent for a job a worker had just
taken is dropped by the claim (it takes only queued jobs): no duplicate runs.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

log = logging.getLogger("otgeo.reaper")

SETTLE_SECONDS = 2.0  # jobs (re-)enqueued this recently may not be in the broker yet


class BrokerWatch:
    def __init__(self, settings, repo, hueys: dict, enqueue: Callable[[str, str | None], None]):
        self.settings, self.repo, self.hueys, self.enqueue = settings, repo, hueys, enqueue
        self.run_id: str | None = None
        self.restarts = 0  # broker restarts seen by this process

    def broker_run_id(self) -> str | None:
        """Redis's ``run_id`` (new at every start); None on other queues. Raises when the
        broker is unreachable."""
        if self.settings.queue != "redis":
            return None
        info = self.hueys["short"].storage.conn.info("server")
        return str(info.get("run_id"))

    def message_ids(self) -> dict[str, set[str]]:
        """The job ids of the messages in each queue."""
        out = {}
        for name, huey in self.hueys.items():
            ids = set()
            for data in huey.storage.enqueued_items():
                try:
                    ids.add(huey.serializer.deserialize(data).args[0])
                except Exception:  # not one of ours: the consumer drops it
                    continue
            out[name] = ids
        return out

    def check(self) -> list[str]:
        """Compare the broker with the job table; re-send the lost messages. Returns the ids
        re-sent (raises when the broker or the table is unreachable)."""
        if self.settings.queue != "redis":
            # the embedded queue is the job table itself (JobRepository.claim_next): a
            # queued job cannot be missing from it, and Huey's SQLite queue holds no message
            # for it, which the count below took for a loss (re-sending waiting jobs)
            return []
        run_id = self.broker_run_id()
        restarted = self.run_id is not None and run_id != self.run_id
        if restarted:
            self.restarts += 1
            log.warning("broker restarted (run id %s -> %s): checking queued jobs",
                        self.run_id, run_id)
        self.run_id = run_id
        queued = self.repo.stale_queued(time.time() - SETTLE_SECONDS)
        if not queued:
            return []
        if not restarted:
            table: dict[str, int] = {}
            for job in queued:
                table[job.queue or "short"] = table.get(job.queue or "short", 0) + 1
            if all(int(self.hueys[q].storage.queue_size()) >= n for q, n in table.items()
                   if q in self.hueys):
                return []
        present = self.message_ids()
        lost = sorted((j for j in queued
                       if j.id not in present.get(j.queue or "short", present["short"])),
                      key=lambda j: (j.enqueued_at or j.created_at, j.id))
        resent = []
        for job in lost:
            if self.repo.touch_queued(job):  # one process re-sends each job
                self.enqueue(job.id, job.queue)
                resent.append(job.id)
        if resent:
            log.warning("re-sent %d queued job(s) missing from the broker: %s", len(resent),
                        resent[:20])
        return resent
