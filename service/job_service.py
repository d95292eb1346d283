"""Job submission and observation (what the API routers call): the application layer over
the runtime, the job machinery of :mod:`service.jobs` and the operations."""

from __future__ import annotations

import logging
import time
import uuid

import numpy as np
from sqlalchemy.exc import IntegrityError

from service.domains import DomainService
from service.errors import Conflict, NotFound
from service.idempotency import Idempotency
from service.jobs.db import QUEUED, TERMINAL, JobRow, WriteBusy, queued_job_row
from service.jobs.queue import queue_for_cost
from service.operations.base import (
    OperationRequest,
    SubmitContext,
    check_job_memory,
    view_of_info,
)
from service.operations.cost import estimate_cost
from service.runtime import Runtime
from service.store import IN_ROW
from service.tenants import ANONYMOUS, Tenant, check_queued_quota

log = logging.getLogger("otgeo.jobs")

# domains up to this many points have their bounded submissions validated on the event loop
# (distances with an explicit gamma: ~0.1 ms at 35k points, once the domain's arrays are read)
LOOP_SUBMISSION_POINTS = 50_000


class PendingJob(Exception):
    """A validated job not recorded yet: the job table's write lock was held (``nowait``)."""

    def __init__(self, job: JobRow):
        super().__init__(job.id)
        self.job = job


def has_partial_result(job: JobRow) -> bool:
    """A finished job that kept a partial result: a solver that stopped without converging
    (failed, ``not_converged``), or a cancelled or timed-out job that kept its finished part
    (a distance matrix's rows)."""
    return job.state in TERMINAL and bool(job.result_location)


class JobService:
    """Jobs as one tenant sees them: its own (every job for an admin); another tenant's job
    is "unknown" (404), so ids do not leak."""

    def __init__(self, runtime: Runtime, tenant: Tenant = ANONYMOUS):
        self.rt = runtime
        self.tenant = tenant

    @property
    def domains(self):
        return DomainService(self.rt, self.tenant)

    def create(self, operation: str, domain_id: str | None, request: OperationRequest,
               idempotency: Idempotency | None = None, *, nowait: bool = False) -> JobRow:
        """Validate (against the stored domain, or the stored inputs of a global operation),
        take the operation's automatic decisions (``Operation.decide``), record the job with
        them, enqueue its id. With ``idempotency``: the job an earlier request with the same
        key created, if any (``job.replayed``), else a new job recorded with the key.
        ``nowait``: :class:`PendingJob` (the validated job, not recorded) instead of waiting
        for the job table's write lock (``JobRepository.create``); ``record`` it then."""
        if idempotency is not None:
            earlier = idempotency.previous()
            if earlier is not None:
                return self._replayed(earlier.resource_id)
        check_queued_quota(self.rt.settings, self.tenant,
                           lambda: self.rt.repo.queued_of(self.tenant.id))
        job = self._new_job(operation, domain_id, request)
        try:
            return self.record(job, idempotency, nowait=nowait)
        except WriteBusy as busy:
            raise PendingJob(job) from busy

    def submits_on_loop(self, operation: str, domain_id: str | None,
                        request: OperationRequest) -> bool:
        """Whether this submission may run on the API's event loop instead of the thread
        pool (a thread hop each way costs more than the work): a local SQLite job table and
        queue (recording is one INSERT that does not wait for a lock, enqueueing a datagram),
        a domain operation whose validation and decision are bounded for this request
        (``Operation.bounded_submission``) on a domain of at most ``LOOP_SUBMISSION_POINTS``
        points. Never changes what is validated, decided or recorded."""
        op = self.rt.operations.get_operation(operation)
        if (op.scope != "domain" or op.bounded_submission is None or not self.rt.repo.local
                or self.rt.settings.queue != "sqlite"):
            return False
        info = self.domains.info(domain_id)
        return (info.n <= LOOP_SUBMISSION_POINTS
                and op.bounded_submission(view_of_info(info), request))

    def record(self, job: JobRow, idempotency: Idempotency | None = None, *,
               nowait: bool = False) -> JobRow:
        """Record a validated job (``_new_job``) with its idempotency key and enqueue it."""
        also = [idempotency.record("job", job.id)] if idempotency is not None else []
        try:
            self.rt.repo.create(job, *also, nowait=nowait)
        except IntegrityError:
            if idempotency is None:
                raise
            earlier = idempotency.previous()  # a concurrent request with the key won
            if earlier is None:
                raise
            return self._replayed(earlier.resource_id)
        if idempotency is not None:
            self.rt.tenancy.prune_keys(self.rt.settings.idempotency_key_ttl)
        try:
            self.rt.enqueue(job.id, job.queue)
        except Exception:  # broker unreachable: the job is recorded, the reaper re-sends it
            log.exception("could not enqueue job %s; it stays queued", job.id)
        if self.rt.settings.queue == "immediate":  # it has run inside enqueue
            return self.get(job.id)
        return job  # as recorded (a worker may have claimed it already: not re-read)

    def _replayed(self, job_id: str) -> JobRow:
        job = self.get(job_id)
        job.replayed = True  # read by the route (Idempotent-Replayed header)
        return job

    def _new_job(self, operation: str, domain_id: str | None, request: OperationRequest
                 ) -> JobRow:
        """The validated job row, not yet recorded."""
        op = self.rt.operations.get_operation(operation)
        size = None  # points of the job's domain (its cost estimate picks the queue)
        if op.scope == "domain":
            view = context = view_of_info(self.domains.info(domain_id))
            size = view.n
            op.check_kind(view)
            op.validate(view, request)
            check_job_memory(op, view, request, self.rt.settings.job_memory_bytes)
            decision = op.decide(view, request) if op.decide is not None else None
        else:
            ctx = context = SubmitContext(self.rt.store, self.rt.settings,
                                          holds=self.domains.holds)
            op.validate(ctx, request)
            check_job_memory(op, ctx, request, self.rt.settings.job_memory_bytes)
            decision = op.decide(ctx, request) if op.decide is not None else None
            domain_id = op.primary_domain(request)
        limit = self.rt.settings.job_time_limit
        if request.time_limit is not None:
            limit = min(limit, request.time_limit)
        if size is None and domain_id:  # a global operation's primary domain
            try:
                size = self.rt.store.domain_info(domain_id).n
            except NotFound:
                size = None
        cost = (op.estimate_cost or estimate_cost)(size or 1, request, context)
        queue = queue_for_cost(self.rt.settings, cost)
        now = time.time()
        job = queued_job_row(id=uuid.uuid4().hex, operation=operation, domain_id=domain_id,
                             queue=queue, cost=cost, params=request.model_dump(mode="json"),
                             max_attempts=self.rt.settings.max_attempts, time_limit=limit,
                             created_at=now, enqueued_at=now, decision=decision,
                             tenant=self.tenant.id)
        return job

    def get(self, job_id: str) -> JobRow:
        job = self.rt.repo.get(job_id)
        if job is None or not (self.tenant.admin or job.tenant == self.tenant.id):
            raise NotFound(f"unknown job {job_id!r}", field="job_id")
        if job.state == QUEUED:  # read by JobOut.from_row
            job.queue_position = self.rt.repo.queue_position(job)
        return job

    def list(self, limit: int, state: str | None = None, **filters) -> list[JobRow]:
        """The tenant's jobs (every job for an admin), newest first (``JobRepository.list``)."""
        tenant = None if self.tenant.admin else self.tenant.id
        return self.rt.repo.list(limit, state, tenant=tenant, **filters)

    def cancel(self, job_id: str) -> JobRow:
        job = self.get(job_id)
        if job.state in ("succeeded", "failed"):
            raise Conflict(f"job {job_id} already {job.state}", field="job_id",
                           code="job_finished")
        return self.rt.repo.request_cancel(job_id)

    def result(self, job_id: str, include_arrays: bool = True) -> dict:
        job = self.get(job_id)
        if job.state != "succeeded" and not has_partial_result(job):
            if job.state in TERMINAL:
                raise Conflict(f"job {job_id} {job.state}; it has no result", field="job_id",
                               code="job_" + job.state)
            raise Conflict(f"job {job_id} is {job.state}; the result is not ready",
                           field="job_id", code="job_not_finished")
        from service.export import result_document

        store = self.rt.store
        return result_document(job_id, self._payload(job), store.result_array_index(job_id),
                               lambda name: store.get_result_array(job_id, name),
                               self.rt.settings.result_json_bytes, include_arrays)

    def _payload(self, job: JobRow) -> dict:
        """The stored result document of a finished job: in its row, or its JSON file."""
        if job.result_location == IN_ROW and job.result is not None:
            return job.result
        return self.rt.store.get_result(job.id)

    def result_npy(self, job_id: str, name: str):
        """``(chunks, size)`` of a result array's .npy file."""
        self.result(job_id, include_arrays=False)  # state checks
        return self.rt.store.result_array_npy(job_id, name)

    def result_file(self, job_id: str, name: str) -> tuple[bytes, str]:
        """``(data, media_type)`` of a file the job produced (an image, a GLB, ...)."""
        self.result(job_id, include_arrays=False)  # state checks
        return self.rt.store.get_result_file(job_id, name, self._payload(self.get(job_id)))

    def result_row(self, job_id: str, name: str, row: int) -> list:
        """Row ``row`` of a stored 2-D result array (e.g. one source vertex's distribution
        in a soft map) without sending the whole array."""
        from service.errors import InvalidInput
        from service.store import jsonable

        self.result(job_id, include_arrays=False)  # state checks
        op = self.rt.operations.get_operation(self.get(job_id).operation)
        if op.result_row is not None:  # e.g. a soft map's rows, prolonged when asked for
            derived = op.result_row(lambda n: self.rt.store.get_result_array(job_id, n),
                                    name, row)
            if derived is not None:
                return jsonable(derived)
        stored = self.rt.store.result_array_index(job_id).get(name)
        if stored is None:
            raise NotFound(f"job {job_id} has no array {name!r}", field="name")
        if len(stored.shape) != 2:
            raise InvalidInput(f"array {name!r} has shape {list(stored.shape)}; rows exist only "
                               "for 2-D arrays", field="name")
        if not 0 <= row < stored.shape[0]:
            raise InvalidInput(f"row {row} out of range [0, {stored.shape[0] - 1}]",
                               field="row")
        return jsonable(self.rt.store.get_result_row(job_id, name, row))

    def result_glb(self, job_id: str) -> bytes:
        """The result as glTF 2.0 binary: the file ``result.glb`` the operation produced, or
        the generic export over its domain (see service.export.domain_glb)."""
        from service.export import domain_glb

        self.result(job_id, include_arrays=False)  # state checks
        payload = self._payload(self.get(job_id))
        if "result.glb" in (payload.get("files") or {}):
            return self.rt.store.get_result_file(job_id, "result.glb", payload)[0]
        if not payload.get("domain_id"):
            raise Conflict(f"job {job_id}'s operation has no glTF export", field="job_id",
                           code="no_glb")
        arrays = self.rt.store.get_result_arrays(job_id)
        export = payload.get("export") or {}
        domain = self.rt.runner.domain(payload["domain_id"])
        fields = {name: arrays[name] for name in export.get("fields", []) if name in arrays}
        flow = arrays.get(export["flow"]) if export.get("flow") else None
        return domain_glb(domain, fields=fields, flow=flow, color=export.get("color"),
                          frames=export.get("frames"),
                          metadata={"job_id": job_id, "operation": payload["operation"],
                                    "values": {k: v for k, v in payload["values"].items()
                                               if np.isscalar(v) or v is None}})
