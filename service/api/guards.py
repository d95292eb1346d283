"""Checks that run before a request is routed: the API key (before any body is read or
parsed), the body's size and pace (413 beyond its route's limit, declared or counted as it
arrives; 408 when a client stops sending), and storage failures turned into a 503 naming
the cause.

``install(app)`` adds them; the ``require_api_key`` dependency (service.api.deps) stays on
the routers so the OpenAPI document declares the key.
"""

from __future__ import annotations

import asyncio
import logging

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from service.errors import (
    ApiError,
    PayloadTooLarge,
    RequestTimeout,
    ServiceUnavailable,
    Unauthorized,
)

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


# routes whose bodies are uploads (max_upload_bytes); every other body is an operation's JSON
UPLOAD_PATHS = ("/v1/domains", "/v1/domains/upload", "/v1/color-transfers")


def body_limit(path: str, content_type: str, settings) -> tuple[int, str, str]:
    """``(bytes, field, setting)``: the largest body of a request to ``path``, the field a
    413 names and the setting that sets the limit."""
    upload = path.rstrip("/") in UPLOAD_PATHS
    field = "body"
    if content_type.startswith("multipart/"):
        field = "images" if path.rstrip("/") == "/v1/color-transfers" else "file"
    if upload or settings.max_upload_bytes <= settings.max_json_body_bytes:
        return settings.max_upload_bytes, field, "OTGEO_MAX_UPLOAD_BYTES"
    return settings.max_json_body_bytes, field, "OTGEO_MAX_JSON_BODY_BYTES"


class _Refused(Exception):
    """Raised into the app from ``receive`` when the body guard refuses the body."""


class BodyGuard:
    """413 for a body over its route's limit, whether declared (``Content-Length``, before
    anything is read) or counted as it arrives (chunked bodies); 408 when the next part of a
    body does not come within ``body_read_timeout`` seconds. Either way the connection is
    closed and the app's own answer (it sees the body end in an error) is dropped."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope["headers"])
        declared = headers.get(b"content-length", b"").decode("latin-1")
        if declared in ("", "0") and b"transfer-encoding" not in headers:
            await self.app(scope, receive, send)  # no body to guard (GET, /healthz, ...)
            return
        settings = scope["app"].state.runtime.settings
        ctype = headers.get(b"content-type", b"").decode("latin-1").lower()
        limit, field, setting = body_limit(scope.get("path", ""), ctype, settings)
        if declared.isdigit() and int(declared) > limit:
            await _refuse(scope, send, PayloadTooLarge(
                f"request body of {declared} bytes exceeds the limit of {limit} bytes "
                f"({setting})", field=field))
            return
        state = {"received": 0, "more": True, "error": None, "started": False}

        async def guarded_receive():
            if not state["more"]:  # the body is complete: e.g. waiting for a disconnect
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), settings.body_read_timeout)
            except TimeoutError:
                state["error"] = RequestTimeout(
                    f"no part of the request body came for {settings.body_read_timeout:g} s "
                    "(OTGEO_BODY_READ_TIMEOUT): send the whole body", field="body")
                raise _Refused() from None
            if message["type"] == "http.request":
                state["received"] += len(message.get("body", b""))
                state["more"] = message.get("more_body", False)
                if state["received"] > limit:
                    state["error"] = PayloadTooLarge(
                        f"request body exceeds the limit of {limit} bytes ({setting})",
                        field=field)
                    raise _Refused()
            else:
                state["more"] = False
            return message

        async def guarded_send(message):
            if state["error"] is None:
                state["started"] = True
                await send(message)

        try:
            await self.app(scope, guarded_receive, guarded_send)
        except _Refused:
            pass
        if state["error"] is not None and not state["started"]:
            await _refuse(scope, send, state["error"])


async def _refuse(scope, send, err: ApiError) -> None:
    """Send ``err`` as the response and close the connection (the rest of the body is not
    read)."""
    response = JSONResponse(err.body(), status_code=err.status_code,
                            headers={"Connection": "close"})
    await response(scope, _no_body, send)


async def _no_body():
    return {"type": "http.disconnect"}


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
    app.add_middleware(BodyGuard)
    app.add_middleware(ApiKeyFirst)  # outermost: a request without its key gets 401 first

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
