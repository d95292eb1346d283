"""Checks that run before a request is routed: the API key (before any body is read or
parsed), and storage failures turned into a 503 naming the cause.

``install(app)`` adds both; the ``require_api_key`` dependency (service.api.deps) stays on
the routers so the OpenAPI document declares the key.
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from service.errors import ServiceUnavailable, Unauthorized

log = logging.getLogger("otgeo.service")

PROTECTED_PREFIXES = ("/v1/", "/v1")


def needs_key(path: str, runtime) -> bool:
    if not runtime.tenants.enabled:
        return False
    if path == "/metrics":
        return not runtime.settings.metrics_open
    return path == "/v1" or path.startswith("/v1/")


class ApiKeyFirst:
    """401 for a protected path without a valid ``X-API-Key`` before the body is read (plain
    ASGI middleware: the request body of a refused request is never parsed). The key's tenant
    goes into the request state (``request.state.tenant``, read by service.api.deps)."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            runtime = scope["app"].state.runtime
            if needs_key(scope.get("path", ""), runtime):
                presented = None
                for name, value in scope["headers"]:
                    if name == b"x-api-key":
                        presented = value.decode("latin-1")
                        break
                tenant = runtime.tenants.resolve(presented)
                if tenant is None:
                    err = Unauthorized("missing or invalid X-API-Key header", field="X-API-Key")
                    await JSONResponse(err.body(), status_code=401)(scope, receive, send)
                    return
                scope.setdefault("state", {})["tenant"] = tenant
        await self.app(scope, receive, send)


class StorageUnavailable(ServiceUnavailable):
    code = "storage_unavailable"


def storage_error(exc: OSError) -> StorageUnavailable | None:
    """The 503 for an OSError of the data directory (read-only, full, ...), else None."""
    from service.storage_probe import STORAGE_ERRNOS, storage_reason

    if exc.errno not in STORAGE_ERRNOS:
        return None
    return StorageUnavailable(f"the service's storage cannot take writes ({storage_reason(exc)});"
                              " retry later or tell the operator", field=None)


def install(app: FastAPI) -> None:
    app.add_middleware(ApiKeyFirst)

    @app.exception_handler(OSError)
    async def _os_error(request: Request, exc: OSError):
        err = storage_error(exc)
        if err is not None:
            log.warning("storage unavailable on %s %s: %s", request.method, request.url.path,
                        exc)
            return JSONResponse(err.body(), status_code=503, headers={"Retry-After": "30"})
        log.error("unhandled OS error on %s %s", request.method, request.url.path,
                  exc_info=exc)
        return JSONResponse({"error": {"code": "internal_error",
                                       "message": "internal server error", "field": None}},
                            status_code=500)
