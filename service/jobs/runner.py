"""Runs one job in a worker: claim, heartbeat, progress, cancellation, time limit, result.

Only the attempt that claimed the job (``attempts`` counter) may write its progress or
final state, so a job re-queued by the reaper while its old worker was merely slow
is finished once.
"""

from __future__ import annotations

import logging
import threading
import time

from service import warm
from service.cache import OperatorCache
from service.errors import ApiError, error_dict
from service.jobs.db import CANCELLED, FAILED, SUCCEEDED, JobRepository, worker_identity
from service.jobs.fanout import FanOut
from service.operations.base import RunContext
from service.renames import current_decision, current_params
from service.settings import Settings
from service.storage_probe import STORAGE_ERRNOS, storage_reason
from service.store import IN_ROW, Store
from solvers.errors import CancelledError, OTGeoError

log = logging.getLogger("otgeo.worker")

PROGRESS_WRITE_INTERVAL = 0.25  # seconds between progress writes to the job table


def _stopped_state(timed_out: bool, limit: float) -> tuple[str, dict]:
    """``(state, error)`` of a job stopped by its time limit (failed) or by a cancel."""
    if timed_out:
        return FAILED, {"code": "time_limit_exceeded", "field": "time_limit",
                        "message": f"job exceeded its time limit of {limit:g} s"}
    return CANCELLED, {"code": "cancelled", "message": "cancelled on request", "field": None}


def _failure_error(job_id: str, exc: Exception) -> dict:
    """The error recorded on a job that raised ``exc`` (unexpected ones logged with their
    traceback; storage errors without server paths)."""
    if not isinstance(exc, (OTGeoError, ApiError)):
        log.exception("job %s failed", job_id)
    if isinstance(exc, OSError) and exc.errno in STORAGE_ERRNOS:  # no server paths
        return {"code": "storage_unavailable", "field": None,
                "message": "the result could not be stored "
                           f"({storage_reason(exc)}); retry later"}
    return error_dict(exc)


class _Beater:
    """One background thread per worker refreshing the running jobs' heartbeats (also during
    long single steps); no thread is started or joined per job.  A job may run another inside
    it (a block of a fanned-out job, service.jobs.fanout): both beat."""

    def __init__(self):
        self._lock = threading.Lock()
        self._current: list[_Heartbeat] = []
        self._thread: threading.Thread | None = None

    def attach(self, hb: _Heartbeat) -> None:
        with self._lock:
            self._current.append(hb)
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, daemon=True,
                                                name="heartbeat")
                self._thread.start()

    def detach(self, hb: _Heartbeat) -> None:
        with self._lock:
            if hb in self._current:
                self._current.remove(hb)

    def _loop(self) -> None:
        while True:
            with self._lock:
                beats = list(self._current)
            tick = min([0.5] + [hb.interval / 4 for hb in beats])
            time.sleep(tick)
            for hb in beats:
                with self._lock:
                    attached = hb in self._current
                if attached and hb.due(hb.interval):
                    hb.beat()  # after detach a beat is a no-op: the job is no longer running


class _Heartbeat:
    """Heartbeat and progress of one job attempt (written by _Beater and on progress)."""

    def __init__(self, repo: JobRepository, job_id: str, attempt: int, interval: float,
                 beater: _Beater):
        self.repo, self.job_id, self.attempt, self.interval = repo, job_id, attempt, interval
        self.cancel = threading.Event()
        self.lost = threading.Event()
        self.progress: dict = {}
        self._beater = beater
        self._lock = threading.Lock()
        self._last_write = time.monotonic()  # the claim just wrote a heartbeat

    def start(self) -> None:
        self._beater.attach(self)

    def stop(self) -> None:
        self._beater.detach(self)

    def due(self, interval: float) -> bool:
        with self._lock:
            return time.monotonic() - self._last_write >= interval

    def beat(self) -> None:
        with self._lock:
            progress = dict(self.progress)
            self._last_write = time.monotonic()
        try:
            owned, cancel = self.repo.heartbeat(self.job_id, self.attempt, **progress)
        except Exception:  # database briefly unavailable: try again next beat
            log.exception("heartbeat of job %s failed", self.job_id)
            return
        if not owned:
            self.lost.set()
            self.cancel.set()
        elif cancel:
            self.cancel.set()

    max_iter: int | None = None  # the request's iteration bound (fraction fallback)

    def on_stage(self, stage: str | None) -> None:
        """What the job does before its solver reports iterations (written at once)."""
        with self._lock:
            self.progress = {**self.progress, "stage": stage}
        self.beat()

    def on_progress(self, iteration: int, residual: float, fraction: float | None = None
                    ) -> None:
        """``progress(iteration, residual[, fraction])`` (solvers.monitor.Monitor passes the
        fraction done it estimates from the residual; else iteration / max_iter)."""
        done = fraction if fraction is not None and fraction == fraction else None
        if self.max_iter:
            by_count = min(int(iteration) / self.max_iter, 1.0)
            done = by_count if done is None else max(done, by_count)
        with self._lock:
            self.progress = {"stage": None, "iteration": int(iteration),
                             "residual": float(residual) if residual == residual else None,
                             "fraction": None if done is None else
                             float(min(max(done, 0.0), 1.0))}
            due = time.monotonic() - self._last_write >= PROGRESS_WRITE_INTERVAL
        if due:
            self.beat()


def not_converged_error(values: dict, params) -> dict | None:
    """The job's error when its solver reports ``converged: false`` (else None): such a job
    ends ``failed`` with code ``not_converged``, its result kept for inspection."""
    if values.get("converged") is not False:
        return None
    residual, iterations = values.get("residual"), values.get("iterations")
    measured = ""
    if isinstance(residual, (int, float)) and isinstance(iterations, int):
        measured = f" (residual {float(residual):.3g} after {iterations} iterations)"
    field = "max_iter" if getattr(params, "max_iter", None) is not None else None
    return {"code": "not_converged", "field": field,
            "message": f"the solver did not converge{measured}; the partial result is "
                       "readable at the job's result link but is not a solution (raise "
                       "max_iter or gamma)"}


class JobRunner:
    def __init__(self, settings: Settings, store: Store, repo: JobRepository,
                 cache: OperatorCache, operations):
        self.settings, self.store, self.repo, self.cache = settings, store, repo, cache
        self.operations = operations  # name -> Operation (service.operations.build_registry)
        self.worker_id = worker_identity()
        self.jobs_done = 0
        self.last_finished = 0.0  # time.monotonic() at the end of the last job
        self.current: tuple[str, int] | None = None
        self._beater = _Beater()
        self.on_finished = None  # optional callable() after every job (statistics)
        self.notify_done = None  # optional callable(job_id) once the final state is committed
        self.enqueue = None  # optional callable(job_id, queue): sends a fanned-out job's blocks

    def domain(self, domain_id: str):
        return self.cache.get_or_build(("domain", domain_id),
                                       lambda: self.store.load_domain(domain_id))

    def run(self, job_id: str) -> None:
        claim = self.repo.claim(job_id, self.worker_id)
        if claim is None:
            log.info("job %s not claimable (already taken, cancelled or finished)", job_id)
            return
        self.run_claimed(claim)

    def run_claimed(self, claim) -> None:
        """Run a job this worker has claimed (``JobRepository.claim`` / ``claim_next``)."""
        job, attempt = claim.job, claim.attempt
        job_id = job.id
        outer, self.current = self.current, (job_id, attempt)  # outer: a block's parent job
        log.info("job %s (%s) attempt %d started", job_id, job.operation, attempt)
        limit = min(job.time_limit or self.settings.job_time_limit,
                    self.settings.job_time_limit)
        deadline = time.monotonic() + limit
        hb = _Heartbeat(self.repo, job_id, attempt, self.settings.heartbeat_interval,
                        self._beater)
        timed_out = threading.Event()

        def should_cancel() -> bool:
            if time.monotonic() > deadline:
                timed_out.set()
                return True
            return hb.cancel.is_set()

        hb.start()
        state, error, location, kept, built = FAILED, None, None, None, None
        ctx = RunContext(self.store, self.settings, self.domain, job.domain_id)
        ctx.fanout = FanOut(self, job, attempt)
        try:
            op = self.operations.get_operation(job.operation)
            # checked strictly at the door; stored JSON gives lists for tuples
            params = op.request_model.model_validate(
                current_params(job.operation, job.params), strict=False)
            max_iter = getattr(params, "max_iter", None)
            if isinstance(max_iter, int) and max_iter > 0 and not op.progress_counts_items:
                hb.max_iter = max_iter
            if not warm.is_warm(op):  # the first job of this worker: compiled kernels first
                hb.on_stage(warm.WARM_STAGE)
                warm.ensure(op)
                hb.on_stage(None)
            try:
                output = ctx.run(op, params, hb.on_progress, should_cancel,
                                 current_decision(job.decision))
            finally:
                built = ctx.operator_builds()
                self.cache.operator_builds += built
            if should_cancel():
                raise CancelledError("cancelled")
            location, kept = self._store_output(job_id, job, output)
            state, error = SUCCEEDED, not_converged_error(output.values, params)
            if error is not None:  # the partial result stays readable; never a success
                state = FAILED
        except CancelledError as exc:
            partial = getattr(exc, "partial_output", None)
            if partial is not None:  # e.g. a distance matrix's finished rows
                location, kept = self._store_output(job_id, job, partial)
            state, error = _stopped_state(timed_out.is_set(), limit)
        except Exception as exc:  # every failure is recorded on the job, never lost
            error = getattr(exc, "job_error", None) or _failure_error(job_id, exc)
        finally:
            hb.stop()
        progress = dict(hb.progress)
        if state == SUCCEEDED:
            progress["fraction"] = 1.0
        if not self.repo.finish(job_id, attempt, state, error=error, result_location=location,
                                result=kept, started_at=job.started_at, **progress):
            log.warning("job %s attempt %d lost ownership; result discarded", job_id, attempt)
        else:  # the waiting API on this machine first (a datagram), then the marker
            if self.notify_done is not None:
                self.notify_done(job_id)
            self.store.mark_done(job_id)
        self._after_job(job_id, state, ctx.domains, built)
        self.current = outer

    def _after_job(self, job_id: str, state: str, domain_ids, built) -> None:
        """The worker's bookkeeping once a job's final state is recorded: the cached
        domains' sizes re-estimated when operators were built (``built`` None: unknown),
        the counters, and the after-job hook."""
        if built is None or built:  # operators were added: re-estimate the entries' sizes
            for domain_id in domain_ids:
                self.cache.refresh(("domain", domain_id))
        self.current = None
        self.jobs_done += 1
        self.last_finished = time.monotonic()
        log.info("job %s finished: %s", job_id, state)
        if self.on_finished is not None:
            try:
                self.on_finished()
            except Exception:
                log.exception("after-job hook failed")

    def _store_output(self, job_id: str, job, output) -> tuple[str, dict | None]:
        """Store an operation's output as the job's result: ``(location, document)``, the
        document for the job row when it is small (``Store.row_result``; nothing is written
        yet: ``finish`` commits it with the final state), else None once in files."""
        payload = {"job_id": job_id, "operation": job.operation,
                   "domain_id": job.domain_id, "decision": current_decision(job.decision),
                   "values": output.values,
                   "arrays": {k: {"shape": list(v.shape), "dtype": str(v.dtype)}
                              for k, v in output.arrays.items()},
                   "export": output.export}
        kept = self.store.row_result(payload, output.arrays, output.files)
        if kept is not None:
            return IN_ROW, kept
        return self.store.put_result(job_id, payload, output.arrays, output.files), None

    def release_current(self) -> str | None:
        """On worker shutdown: hand the running job back to the queue (not an attempt)."""
        current = self.current
        if current is None:
            return None
        job_id, attempt = current
        return job_id if self.repo.release(job_id, attempt) else None
