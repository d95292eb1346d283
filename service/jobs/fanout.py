"""A job fanned out over the workers: its blocks are jobs of their own on the same queue.

An operation that splits (``Operation.fans_out``; the distance matrix: blocks of rows) runs
as a *parent* job on one worker.  :meth:`FanOut.run` records its blocks as rows of the job
table (``parent`` = the parent's id, deterministic ids, the parent's queue, each with its
own stored decision: the block's rows), sends them to the queue, and then

* runs queued blocks itself, one at a time (a block is claimed like any job: whichever
  worker claims it first runs it; with one worker the parent runs them all, in order);
* reads the blocks' progress from the job table and reports the sum as its own;
* on cancellation (or its time limit) cancels the blocks (queued ones at once, running ones
  flagged), waits for the running ones to stop, and returns what finished;
* once every block has succeeded, returns their rows: the operation merges their stored
  results, in one place (the parent), into the job's result.

Recovery is the job table's own: a block is an ordinary job, so a worker killed mid-block
leaves a stale heartbeat, the reaper re-queues that block (only it: the finished blocks are
stored results) and any worker, the parent's included, runs it again.  A parent whose own
worker dies is re-queued the same way; its next attempt finds the blocks recorded (ids are a
function of the parent's id and the block's index), keeps the succeeded ones and waits for
or runs the rest.  Only the attempt that owns a block may finish it, so a block's result is
stored once.
"""

from __future__ import annotations

import logging
import time
import uuid

from service.jobs.db import CANCELLED, FAILED, QUEUED, SUCCEEDED, TERMINAL, JobRow, queued_job_row
from service.store import IN_ROW
from solvers.errors import CancelledError

log = logging.getLogger("otgeo.worker")

_NAMESPACE = uuid.UUID("5b8c2d1e-8a59-4d0b-9d65-0f6f3a1c7e42")
POLL_SECONDS = 0.05  # the parent's wait between reads of its blocks' rows


class BlockFailed(Exception):
    """A block failed: the parent fails with the block's error (``job_error``)."""

    def __init__(self, index: int, error: dict | None):
        error = dict(error or {"code": "block_failed", "field": None, "message": "failed"})
        error["message"] = f"block {index} of the job failed: {error.get('message')}"
        super().__init__(error["message"])
        self.job_error = error


def block_id(parent_id: str, index: int) -> str:
    """The id of block ``index`` of job ``parent_id`` (the same for every attempt)."""
    return uuid.uuid5(_NAMESPACE, f"{parent_id}/{index}").hex


class FanOut:
    """The blocks of the job a worker runs (``RunContext.fanout``; see the module)."""

    def __init__(self, runner, job: JobRow, attempt: int):
        self.runner, self.job, self.attempt = runner, job, attempt
        self.repo = runner.repo

    # -- recording and sending ------------------------------------------------------------
    def _rows(self, decisions: list[dict]) -> list[JobRow]:
        job, now = self.job, time.time()
        return [queued_job_row(id=block_id(job.id, k), operation=job.operation,
                               domain_id=job.domain_id, params=job.params,
                               max_attempts=job.max_attempts, time_limit=job.time_limit,
                               created_at=now, enqueued_at=now, queue=job.queue, decision=d,
                               parent=job.id)
                for k, d in enumerate(decisions)]

    def _record(self, decisions: list[dict]) -> None:
        new = self.repo.create_missing(self._rows(decisions))
        if self.runner.enqueue is None or self.runner.settings.queue == "immediate":
            return  # immediate mode: the parent runs its blocks itself
        for row in new:
            try:
                self.runner.enqueue(row.id, row.queue)
            except Exception:  # broker down: the parent runs them, the reaper re-sends
                log.exception("could not enqueue block %s of job %s", row.id, self.job.id)

    # -- the parent's loop ----------------------------------------------------------------
    def run(self, decisions: list[dict], progress, should_cancel, total: int
            ) -> list[JobRow]:
        """Record the blocks (``decisions``: one stored decision each), run or await them;
        returns the blocks' rows in order, every one succeeded.  On ``should_cancel``:
        :class:`~solvers.errors.CancelledError` with ``blocks``, the rows once every block
        stopped.  A failed block: :class:`BlockFailed`.  ``progress(done, worst,
        fraction)`` sums the blocks' counts (``iteration`` of each row) over ``total``."""
        self._record(decisions)
        ids = [block_id(self.job.id, k) for k in range(len(decisions))]
        while True:
            rows = self._ordered(ids)
            self._report(rows, progress, total)
            # a cancelled block: the job's cancellation reached it first (request_cancel)
            if should_cancel() or any(r.state == CANCELLED for r in rows):
                raise self._cancelled(ids)
            failed = next(((k, r) for k, r in enumerate(rows) if r.state == FAILED), None)
            if failed is not None:
                self._cancel(ids)
                raise BlockFailed(failed[0], failed[1].error)
            if all(r.state == SUCCEEDED for r in rows):
                return rows
            if not self._run_one(rows):
                time.sleep(POLL_SECONDS)

    def _ordered(self, ids: list[str]) -> list[JobRow]:
        by_id = {r.id: r for r in self.repo.children(self.job.id)}
        return [by_id[i] for i in ids]

    def _run_one(self, rows: list[JobRow]) -> bool:
        """Claim and run the first queued block here; False when none was claimed."""
        for row in rows:
            if row.state != QUEUED:
                continue
            claim = self.repo.claim(row.id, self.runner.worker_id)
            if claim is not None:
                self.runner.run_claimed(claim)
                return True
        return False

    @staticmethod
    def _report(rows: list[JobRow], progress, total: int) -> None:
        done = sum(int(r.iteration or 0) for r in rows)
        worst = max((float(r.residual) for r in rows if r.residual is not None), default=0.0)
        if done:
            progress(done, worst, min(done / max(total, 1), 1.0))

    def _cancel(self, ids: list[str]) -> None:
        for i in ids:
            self.repo.request_cancel(i)

    def _cancelled(self, ids: list[str]) -> CancelledError:
        """Cancel every block, wait (at most ``stale_after``) for the running ones to stop;
        the error carries the blocks' rows (finished ones keep their results)."""
        self._cancel(ids)
        deadline = time.monotonic() + self.runner.settings.stale_after
        rows = self._ordered(ids)
        while any(r.state not in TERMINAL for r in rows) and time.monotonic() < deadline:
            time.sleep(POLL_SECONDS)
            rows = self._ordered(ids)
        error = CancelledError("cancelled between blocks")
        error.blocks = rows
        return error

    def result(self, row: JobRow) -> tuple[dict, dict]:
        """``(values, arrays)`` a block stored (empty for a block cancelled while queued)."""
        if row.state == CANCELLED and not row.result_location:
            return {}, {}
        store = self.runner.store
        if row.result_location == IN_ROW:
            payload = self.repo.get(row.id).result
        else:
            payload = store.get_result(row.id)
        return payload["values"], store.get_result_arrays(row.id)
