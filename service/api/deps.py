"""Shared dependencies: the process runtime, services and optional API-key auth."""

from __future__ import annotations

import hmac
from typing import Annotated

from fastapi import Depends, Request, Security
from fastapi.security import APIKeyHeader

from service.domains import DomainService
from service.errors import Unauthorized
from service.jobs.service import JobService
from service.runtime import Runtime

api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False,
                              description="required when the server sets OTGEO_API_KEYS")


def get_runtime(request: Request) -> Runtime:
    return request.app.state.runtime


# The dependencies are ``async def`` although they never await: they are trivial, and FastAPI
# runs a plain ``def`` dependency in the thread pool (one thread hop per dependency and request).
async def runtime_dep(request: Request) -> Runtime:
    return get_runtime(request)


async def domain_service(request: Request) -> DomainService:
    return DomainService(get_runtime(request))


async def job_service(request: Request) -> JobService:
    return JobService(get_runtime(request))


async def require_api_key(request: Request,
                          key: str | None = Security(api_key_header)) -> None:
    """The key check as the routers declare it (OpenAPI security); service.api.guards runs
    the same check before the body is read, so this one only backs it up."""
    keys = get_runtime(request).settings.api_keys
    if not keys:
        return
    if key is None or not any(hmac.compare_digest(key, k) for k in keys):
        raise Unauthorized("missing or invalid X-API-Key header", field="X-API-Key")


async def require_metrics_key(request: Request,
                              key: str | None = Security(api_key_header)) -> None:
    """/metrics (host names, process ids): behind the key unless OTGEO_METRICS_OPEN."""
    if get_runtime(request).settings.metrics_open:
        return
    await require_api_key(request, key)


DomainSvc = Annotated[DomainService, Depends(domain_service)]
JobSvc = Annotated[JobService, Depends(job_service)]
RuntimeDep = Annotated[Runtime, Depends(runtime_dep)]
