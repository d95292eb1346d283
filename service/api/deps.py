"""Shared dependencies: the process runtime, the caller's tenant, services scoped to it,
optional API-key auth and the ``Idempotency-Key`` header."""

from __future__ import annotations

import re
from typing import Annotated

from fastapi import Depends, Header, Request, Security
from fastapi.security import APIKeyHeader

from service.domains import DomainService
from service.errors import InvalidInput, Unauthorized
from service.idempotency import DESCRIPTION as IDEMPOTENCY_DESCRIPTION
from service.idempotency import HEADER as IDEMPOTENCY_HEADER
from service.idempotency import KEY_PATTERN
from service.job_service import JobService
from service.runtime import Runtime
from service.tenants import Tenant

api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False,
                              description="required when the server sets OTGEO_API_KEYS "
                              "(or tenant keys); the key names the caller's tenant")


def get_runtime(request: Request) -> Runtime:
    return request.app.state.runtime


def tenant_of(request: Request) -> Tenant:
    """The caller's tenant: resolved by the key guard (service.api.guards) before the body
    was read, else from the ``X-API-Key`` header now; 401 for a missing or unknown key."""
    state = request.scope.get("state") or {}
    tenant = state.get("tenant")
    if tenant is None:
        tenant = get_runtime(request).tenants.resolve(request.headers.get("x-api-key"))
    if tenant is None:
        raise Unauthorized("missing or invalid X-API-Key header", field="X-API-Key")
    return tenant


# The dependencies are ``async def`` although they never await: they are trivial, and FastAPI
# runs a plain ``def`` dependency in the thread pool (one thread hop per dependency and request).
async def runtime_dep(request: Request) -> Runtime:
    return get_runtime(request)


async def tenant_dep(request: Request) -> Tenant:
    return tenant_of(request)


async def domain_service(request: Request) -> DomainService:
    return DomainService(get_runtime(request), tenant_of(request))


async def job_service(request: Request) -> JobService:
    return JobService(get_runtime(request), tenant_of(request))


async def require_api_key(request: Request,
                          key: str | None = Security(api_key_header)) -> None:
    """The key check as the routers declare it (OpenAPI security); service.api.guards runs
    the same check before the body is read, so this one only backs it up."""
    tenant_of(request)


async def metrics_scope(request: Request,
                        key: str | None = Security(api_key_header)) -> str | None:
    """Whose jobs /metrics counts: None (every tenant's, plus the processes' host names and
    ids) for an admin key, the open service, or OTGEO_METRICS_OPEN; else the key's tenant.
    401 for a missing or unknown key unless OTGEO_METRICS_OPEN."""
    if get_runtime(request).settings.metrics_open:
        return None
    tenant = tenant_of(request)
    return None if tenant.admin else tenant.id


async def idempotency_key(key: Annotated[str | None, Header(
        alias=IDEMPOTENCY_HEADER, description=IDEMPOTENCY_DESCRIPTION,
        json_schema_extra={"pattern": KEY_PATTERN, "minLength": 1, "maxLength": 255})] = None
        ) -> str | None:
    # checked here, not by Header(pattern=...): the error names the header (the generic
    # handler takes a capitalized location part for a union member)
    if key is not None and not re.fullmatch(KEY_PATTERN, key):
        raise InvalidInput(f"{IDEMPOTENCY_HEADER} must be 1 to 255 printable ASCII characters",
                           field=IDEMPOTENCY_HEADER)
    return key


DomainSvc = Annotated[DomainService, Depends(domain_service)]
JobSvc = Annotated[JobService, Depends(job_service)]
RuntimeDep = Annotated[Runtime, Depends(runtime_dep)]
TenantDep = Annotated[Tenant, Depends(tenant_dep)]
IdempotencyKeyDep = Annotated[str | None, Depends(idempotency_key)]
