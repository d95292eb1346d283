"""/healthz and /metrics (Prometheus text format)."""

from __future__ import annotations

import time
from typing import Annotated

from fastapi import APIRouter, Depends
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, PlainTextResponse, Response

from service import __version__
from service.api.deps import RuntimeDep, metrics_scope
from service.errors import ErrorResponse
from service.jobs.db import QUEUED, RUNNING, STATES
from service.jobs.queue import QUEUES
from service.schemas import Health

router = APIRouter(tags=["health"])


@router.get("/healthz", operation_id="health", response_model=Health,
            responses={503: {"model": Health, "description": "storage cannot take writes "
                             "(or is nearly full), or the queue's broker is unreachable: "
                             "`storage` and `broker` say why"}})
async def healthz(rt: RuntimeDep):
    """Liveness plus storage (the data directory takes writes: a probe file is written and
    removed, at most once a second) and the queue's broker (reachable; probed at most once a
    second): up or down per component, without counts. Unauthenticated, so it shows nothing
    of other tenants (queue depths, messages) nor free bytes: those are on /metrics."""
    storage = await run_in_threadpool(rt.storage_status)
    broker = await run_in_threadpool(rt.broker_status)
    ok = storage["writable"] and not storage["low_space"] and broker["reachable"]
    health = Health(status="ok" if ok else "degraded", queue=rt.settings.queue,
                    version=__version__, storage=storage, broker=broker)
    if ok:
        return health
    return JSONResponse(health.model_dump(mode="json"), status_code=503)


def _labels(**kv) -> str:
    inner = ",".join(f'{k}="{str(v)}"' for k, v in kv.items())
    return "{" + inner + "}" if inner else ""


class _Exposition:
    """Lines of the Prometheus text format."""

    def __init__(self):
        self.lines: list[str] = []

    def metric(self, name: str, kind: str, help_: str, samples: list[tuple[dict, float]]):
        self.lines.append(f"# HELP {name} {help_}")
        self.lines.append(f"# TYPE {name} {kind}")
        for labels, value in samples:
            self.lines.append(f"{name}{_labels(**labels)} {value:g}")


@router.get("/metrics", operation_id="getMetrics", response_class=Response,
            responses={200: {"content": {"text/plain": {"schema": {"type": "string"}}},
                             "description": "Prometheus text exposition format"},
                       401: {"model": ErrorResponse, "description": "missing or wrong "
                             "X-API-Key (unless OTGEO_METRICS_OPEN)"}})
def metrics(rt: RuntimeDep, tenant: Annotated[str | None, Depends(metrics_scope)]):
    """Job counts and durations and queue depth (from the job table). A tenant's key sees
    its own jobs only; an admin key (or the open service, or OTGEO_METRICS_OPEN) sees every
    tenant's, and the processes: cache hits/misses and sizes (this process and every live
    worker), live workers, broker messages, reachability and restarts, the data directory's
    free bytes."""
    out = _Exposition()
    if tenant is None:
        _process_metrics(rt, out)
    _job_metrics(rt, out, tenant)
    return PlainTextResponse("\n".join(out.lines) + "\n",
                             media_type="text/plain; version=0.0.4; charset=utf-8")


def _process_metrics(rt, out: _Exposition) -> None:
    """Caches and workers of every process (global: admin scope only)."""
    caches = [({"process": f"{rt.role}:{rt.process_id}"}, rt.cache.stats())]
    since = time.time() - rt.settings.stale_after
    workers = rt.repo.live_workers(since)
    for w in workers:
        if w.id != rt.process_id:
            caches.append(({"process": f"worker:{w.id}"}, w.cache or {}))
    for key, name, kind, help_ in [
        ("hits", "otgeo_cache_hits_total", "counter", "operator cache hits"),
        ("misses", "otgeo_cache_misses_total", "counter", "operator cache misses (builds)"),
        ("evictions", "otgeo_cache_evictions_total", "counter", "operator cache evictions"),
        ("entries", "otgeo_cache_entries", "gauge", "domains with operators in the cache"),
        ("operators", "otgeo_cache_operators", "gauge", "prefactored heat kernels in the cache"),
        ("operator_builds", "otgeo_operator_builds_total", "counter",
         "heat kernels built (factorizations); a warm cache stops counting"),
        ("bytes", "otgeo_cache_bytes", "gauge", "estimated bytes held by the cache"),
        ("max_bytes", "otgeo_cache_max_bytes", "gauge", "cache bound in bytes"),
    ]:
        out.metric(name, kind, help_, [(lab, float(st.get(key, 0))) for lab, st in caches])
    for key, name, help_ in [("hits", "otgeo_cache_hits_all_total", "cache hits, all "
                              "processes"), ("misses", "otgeo_cache_misses_all_total",
                                             "cache misses, all processes")]:
        out.metric(name, "counter", help_,
                   [({}, float(sum(st.get(key, 0) for _, st in caches)))])
    out.metric("otgeo_workers_alive", "gauge", "worker processes with a recent heartbeat",
               [({}, float(len(workers)))])
    pending = rt.pending_messages()
    if pending is not None:
        out.metric("otgeo_queue_messages", "gauge", "messages in the Huey queue",
                   [({}, float(pending))])
    broker = rt.broker_status()
    out.metric("otgeo_broker_reachable", "gauge", "the queue's broker answers (1) or not (0)",
               [({}, float(broker["reachable"]))])
    out.metric("otgeo_broker_restarts_total", "counter", "broker restarts this process has "
               "seen (its queued jobs were re-sent from the job table at once)",
               [({}, float(broker.get("restarts", 0)))])
    storage = rt.storage_status()
    out.metric("otgeo_storage_writable", "gauge", "the data directory takes writes (1) or "
               "not (0)", [({}, float(storage["writable"]))])
    if storage.get("free_bytes") is not None:
        out.metric("otgeo_storage_free_bytes", "gauge", "free bytes in the data directory",
                   [({}, float(storage["free_bytes"]))])


def _job_metrics(rt, out: _Exposition, tenant: str | None) -> None:
    """Jobs by operation and state, queue depth, durations: ``tenant``'s, or every job."""
    counts = rt.repo.counts(tenant=tenant)
    by_state = {s: sum(n for (_, st), n in counts.items() if st == s) for s in STATES}
    out.metric("otgeo_queue_depth", "gauge", "jobs waiting for a worker",
               [({}, by_state[QUEUED])])
    out.metric("otgeo_jobs_running", "gauge", "jobs being run", [({}, by_state[RUNNING])])
    per_queue = rt.repo.queued_by_queue(tenant=tenant)
    out.metric("otgeo_queue_depth_by_queue", "gauge", "jobs waiting, per queue (short, long)",
               [({"queue": q}, float(per_queue.get(q, 0))) for q in QUEUES])
    out.metric("otgeo_jobs", "gauge", "jobs in the job table by operation and state",
               [({"operation": op, "state": st}, float(counts.get((op, st), 0)))
                for op in rt.operations for st in STATES])
    durations = rt.repo.durations(tenant=tenant)
    for idx, (suffix, kind, help_) in enumerate([
            ("count", "counter", "finished jobs"),
            ("sum", "counter", "total run time of finished jobs (seconds)"),
            ("max", "gauge", "longest run time (seconds)")]):
        out.metric(f"otgeo_job_duration_seconds_{suffix}", kind, help_,
                   [({"operation": op, "state": st}, v[idx]) for (op, st), v in
                    sorted(durations.items())])
