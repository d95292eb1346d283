"""Operation routes: validate, create a job, optionally wait.

``POST /v1/domains/{domain_id}/<operation>`` for domain-scoped operations and ``POST
/v1/<operation>`` for global ones (several domains, uploaded blobs). One route per
operation of the app's registry, each with its own request model and a stable
operationId. (No ``from __future__ import annotations``: the request model types are
bound per route at runtime.)"""

import asyncio
import time

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.routing import APIRoute

from service.api.bodies import parse_json
from service.api.deps import IdempotencyKeyDep, JobSvc, RuntimeDep
from service.errors import InvalidInput, responses
from service.idempotency import REPLAYED, for_request
from service.job_service import PendingJob
from service.jobs.db import QUEUED, TERMINAL
from service.operations import Operation, Registry
from service.operations.guide_pages import openapi_extra
from service.schemas import RETRY_AFTER_HEADERS, JobOut, retry_after

WAIT_DESCRIPTION = ("seconds to wait for the job to finish: if it ends in time the finished job "
                    "is returned with status 200, otherwise 202 with the job as it is")


MARKER_POLL = 0.002  # seconds between checks of the job's completion marker (a stat)
MARKER_POLL_WOKEN = 0.02  # the same on the embedded SQLite queue (workers send datagrams)
TABLE_POLL = 0.25  # seconds between job-table reads while waiting (markers can be missed)


async def wait_for(svc, job_id: str, seconds: float, job=None):
    """Wait until the job is terminal or ``seconds`` elapsed.

    A worker on this machine sends a "done" datagram after committing the final state
    (service.jobs.wake): the waiting request wakes at once and reads the job table. Workers
    elsewhere touch a completion marker in shared storage; checking it is a ``stat`` (every
    ``MARKER_POLL_WOKEN`` seconds on the SQLite queue, whose workers share this machine,
    ``MARKER_POLL`` otherwise). The job
    table is also read every ``TABLE_POLL`` seconds in case both are missed (a job failed by
    the reaper, or storage that caches file metadata), on the event loop when it is a local
    SQLite file. ``job``: its row as just read."""
    deadline = time.monotonic() + seconds
    waiters = svc.rt.waiters
    event = waiters.register(job_id) if waiters is not None and waiters.active else None
    # with Redis, workers may run on other machines (no datagram): keep the fast marker poll
    local = event is not None and svc.rt.settings.queue == "sqlite"
    poll = MARKER_POLL_WOKEN if local else MARKER_POLL
    # a primary-key read of a local SQLite table (WAL: readers never wait for writers) takes
    # less than the two thread hops around it; a server database is read off the loop
    on_loop = svc.rt.repo.local
    try:
        if job is None:
            job = await run_in_threadpool(svc.get, job_id)
        last_read = time.monotonic()
        while job.state not in TERMINAL:
            now = time.monotonic()
            if now >= deadline:
                break
            timeout = min(poll, deadline - now)
            if event is None:
                await asyncio.sleep(timeout)
            else:
                try:
                    await asyncio.wait_for(event.wait(), timeout)
                except TimeoutError:
                    pass
            if ((event is not None and event.is_set()) or svc.rt.store.is_done(job_id)
                    or time.monotonic() - last_read >= TABLE_POLL):
                if event is not None:
                    event.clear()
                job = svc.get(job_id) if on_loop else await run_in_threadpool(svc.get, job_id)
                last_read = time.monotonic()
    finally:
        if event is not None:
            waiters.unregister(job_id, event)
    return job


def submit_job(op_name: str, domain_id: str | None, body, svc, rt,
               idempotency_key: str | None = None):
    """Shared by every operation route (sync part)."""
    route = f"POST {op_name}" + (f" on {domain_id}" if domain_id else "")
    idempotency = for_request(rt, svc.tenant.id, idempotency_key, route,
                              body.model_dump(mode="json"))
    return svc.create(op_name, domain_id, body, idempotency)


async def submit(op_name: str, domain_id: str | None, body, wait: float, svc, rt,
                 idempotency_key: str | None = None):
    """The created (or replayed) job: ``submit_job`` in the thread pool, or on the event loop
    for a small bounded submission without an ``Idempotency-Key``
    (``JobService.submits_on_loop``; only the INSERT goes to the pool when another process
    holds the job table's write lock)."""
    if wait > rt.settings.wait_max:
        raise InvalidInput(f"wait must be at most {rt.settings.wait_max:g} seconds",
                           field="wait")
    if idempotency_key is None and svc.submits_on_loop(op_name, domain_id, body):
        try:
            return svc.create(op_name, domain_id, body, nowait=True)
        except PendingJob as pending:
            return await run_in_threadpool(svc.record, pending.job)
    return await run_in_threadpool(submit_job, op_name, domain_id, body, svc, rt,
                                   idempotency_key)


async def finish_submission(op_name: str, domain_id: str | None, body, wait: float,
                            response: Response, svc, rt,
                            idempotency_key: str | None = None) -> JobOut:
    """Create the job (or, for a repeated ``Idempotency-Key``, find the first one), wait up to
    ``wait`` seconds, set 200/202 and ``Location``; also for families with their own routes
    (``Operation(route=False)``)."""
    job = await submit(op_name, domain_id, body, wait, svc, rt, idempotency_key)
    if getattr(job, "replayed", False):
        response.headers[REPLAYED] = "true"
    if wait > 0 and job.state not in TERMINAL:
        job = await wait_for(svc, job.id, wait, job)
    if job.state == QUEUED:  # read by JobOut.from_row; a local SQLite read as in wait_for
        repo = svc.rt.repo
        job.queue_position = (repo.queue_position(job) if repo.local
                              else await run_in_threadpool(repo.queue_position, job))
    response.status_code = 200 if job.state in TERMINAL else 202
    response.headers["Location"] = f"/v1/jobs/{job.id}"
    out = JobOut.from_row(job, rt.operations)
    if job.state not in TERMINAL:  # poll, at the pace the job suggests
        response.headers["Retry-After"] = str(retry_after(out))
    return out


def _is_json(content_type: str) -> bool:
    media = content_type.split(";")[0].strip().lower()
    return media in ("", "application/json") or \
        (media.startswith("application/") and media.endswith("+json"))


class JsonBodyRoute(APIRoute):
    """An operation route whose JSON body is parsed before FastAPI validates it: off the
    event loop (service.api.bodies.parse_json: a child process for large bodies) and with the
    ``invalid_json`` error naming the field ``body`` for anything that is not one JSON
    document (invalid UTF-8, a syntax error, nesting too deep, a multipart or other non-JSON
    body). FastAPI then reads the parsed object from the request's JSON cache."""

    def get_route_handler(self):
        handler = super().get_route_handler()

        async def parse_then_handle(request: Request):
            content_type = request.headers.get("content-type", "")
            if not _is_json(content_type):
                media = content_type.split(";")[0].strip()
                raise InvalidInput(f"body is {media}, not JSON: send application/json",
                                   field="body", code="invalid_json")
            request._json = await parse_json(await request.body())
            return await handler(request)

        return parse_then_handle


ROUTE_RESPONSES = {200: {"model": JobOut, "description": "the job finished within `wait`"},
                   202: {"description": "the job, not finished (yet): poll `Location` after "
                         "`Retry-After` seconds", "headers": RETRY_AFTER_HEADERS},
                   **responses(400, 401, 404, 413, 422, 429)}


def _domain_route(router: APIRouter, op: Operation) -> None:
    model = op.request_model

    async def create_job(domain_id: str, body: model, response: Response, svc: JobSvc,
                         rt: RuntimeDep, idempotency_key: IdempotencyKeyDep,
                         wait: float = Query(0.0, ge=0, description=WAIT_DESCRIPTION)):
        return await finish_submission(op.name, domain_id, body, wait, response, svc, rt,
                                       idempotency_key)

    create_job.__name__ = op.operation_id
    router.add_api_route(
        f"/domains/{{domain_id}}/{op.name}", create_job, methods=["POST"],
        operation_id=op.operation_id, summary=op.summary, status_code=202,
        response_model=JobOut, responses=ROUTE_RESPONSES,
        # x-domain-kinds: the kinds of domain it runs on (others get a 422): what the viewer
        # offers on the domain shown
        openapi_extra={**(openapi_extra(op.name) or {}), "x-domain-kinds": list(op.kinds)},
        route_class_override=JsonBodyRoute)


def _global_route(router: APIRouter, op: Operation) -> None:
    model = op.request_model

    async def create_job(body: model, response: Response, svc: JobSvc, rt: RuntimeDep,
                         idempotency_key: IdempotencyKeyDep,
                         wait: float = Query(0.0, ge=0, description=WAIT_DESCRIPTION)):
        return await finish_submission(op.name, None, body, wait, response, svc, rt,
                                       idempotency_key)

    create_job.__name__ = op.operation_id
    router.add_api_route(
        f"/{op.name}", create_job, methods=["POST"], operation_id=op.operation_id,
        summary=op.summary, status_code=202, response_model=JobOut,
        responses=ROUTE_RESPONSES, openapi_extra=openapi_extra(op.name),
        route_class_override=JsonBodyRoute)


def build_router(registry: Registry) -> APIRouter:
    """The operation routes of ``registry`` (under /v1)."""
    router = APIRouter(prefix="/v1", tags=["operations"])
    for op in registry.values():
        if not op.route:
            continue
        (_domain_route if op.scope == "domain" else _global_route)(router, op)
    return router
