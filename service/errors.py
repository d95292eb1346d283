"""One error hierarchy for the API, rendered as ``{"error": {"code", "message", "field"}}``.

Library errors (``solvers.errors``) and request validation errors are mapped to
the same shape, so bad input always gets a 4xx naming the field, never a 500.
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy.exc import DBAPIError
from starlette.exceptions import HTTPException as StarletteHTTPException

from solvers.errors import (
    CancelledError,
    ConvergenceError,
    MeshFormatError,
    OTGeoError,
    UnsupportedDomainError,
)

log = logging.getLogger("otgeo.service")


class ErrorBody(BaseModel):
    code: str
    message: str
    field: str | None = None


class ErrorResponse(BaseModel):
    error: ErrorBody


class ApiError(Exception):
    """Base of every error the API returns on purpose."""

    status_code = 400
    code = "bad_request"

    def __init__(self, message: str, *, field: str | None = None, code: str | None = None):
        super().__init__(message)
        self.message = message
        self.field = field
        if code is not None:
            self.code = code

    def body(self) -> dict:
        return {"error": {"code": self.code, "message": self.message, "field": self.field}}


class InvalidInput(ApiError):
    status_code = 422
    code = "invalid_input"


class UnsupportedOperation(InvalidInput):
    code = "unsupported_operation"


class NotFound(ApiError):
    status_code = 404
    code = "not_found"


class PayloadTooLarge(ApiError):
    status_code = 413
    code = "payload_too_large"


class Conflict(ApiError):
    status_code = 409
    code = "conflict"


class Unauthorized(ApiError):
    status_code = 401
    code = "unauthorized"


class ServiceUnavailable(ApiError):
    status_code = 503
    code = "unavailable"


class UnsupportedMediaType(ApiError):
    status_code = 415
    code = "unsupported_media_type"


def from_library(exc: OTGeoError) -> ApiError:
    """The API error for a ``solvers.errors`` exception."""
    if isinstance(exc, MeshFormatError):
        return InvalidInput(exc.message, field=exc.field or "file", code="invalid_mesh")
    if isinstance(exc, UnsupportedDomainError):
        return UnsupportedOperation(exc.message, field=exc.field)
    if isinstance(exc, ConvergenceError):
        return InvalidInput(exc.message, field=exc.field, code="no_convergence")
    if isinstance(exc, CancelledError):
        return Conflict(exc.message, field=exc.field, code="cancelled")
    return InvalidInput(exc.message, field=exc.field)


def error_dict(exc: BaseException) -> dict:
    """``{"code", "message", "field"}`` for any exception (used for failed jobs)."""
    if isinstance(exc, OTGeoError):
        exc = from_library(exc)
    if isinstance(exc, ApiError):
        return exc.body()["error"]
    return {"code": "internal_error", "message": f"{type(exc).__name__}: {exc}", "field": None}


def field_from_loc(loc) -> str | None:
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "header", "form")]
    if not parts:
        return None
    out = parts[0]
    for p in parts[1:]:
        out += f"[{p}]" if p.isdigit() else f".{p}"
    return out


ERROR_RESPONSES = {
    401: {"model": ErrorResponse, "description": "missing or wrong X-API-Key"},
    404: {"model": ErrorResponse, "description": "unknown domain or job"},
    413: {"model": ErrorResponse, "description": "upload or domain too large"},
    422: {"model": ErrorResponse, "description": "invalid input (the field is named)"},
}


def responses(*codes: int) -> dict:
    return {c: ERROR_RESPONSES.get(c, {"model": ErrorResponse}) for c in codes}


class _BodyLimit:
    """413 for a declared body over the upload limit (plain ASGI middleware: no extra task
    and body streaming per request, unlike ``@app.middleware("http")``)."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            headers = dict(scope["headers"])
            declared = headers.get(b"content-length", b"").decode("latin-1")
            limit = scope["app"].state.runtime.settings.max_upload_bytes
            if declared.isdigit() and int(declared) > limit:
                ctype = headers.get(b"content-type", b"").decode("latin-1")
                err = PayloadTooLarge(f"request body of {declared} bytes exceeds the limit of "
                                      f"{limit}",
                                      field="file" if ctype.startswith("multipart/") else "body")
                await JSONResponse(err.body(), status_code=413)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def install_handlers(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError):
        return JSONResponse(exc.body(), status_code=exc.status_code)

    @app.exception_handler(OTGeoError)
    async def _library_error(request: Request, exc: OTGeoError):
        err = from_library(exc)
        return JSONResponse(err.body(), status_code=err.status_code)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError):
        errors = exc.errors()
        first = errors[0] if errors else {"loc": (), "msg": "invalid request"}
        field = field_from_loc(first.get("loc", ()))
        msg = first.get("msg", "invalid request")
        message = f"{field}: {msg}" if field else msg
        if len(errors) > 1:
            message += f" (and {len(errors) - 1} more problems)"
        return JSONResponse(InvalidInput(message, field=field).body(), status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException):
        codes = {404: "not_found", 405: "method_not_allowed"}
        err = ApiError(str(exc.detail), code=codes.get(exc.status_code, "http_error"))
        return JSONResponse(err.body(), status_code=exc.status_code,
                            headers=getattr(exc, "headers", None))

    @app.exception_handler(DBAPIError)
    async def _database(request: Request, exc: DBAPIError):
        log.warning("job table unavailable: %s", exc)
        err = ServiceUnavailable("the job database is unavailable; retry shortly")
        return JSONResponse(err.body(), status_code=503, headers={"Retry-After": "2"})

    app.add_middleware(_BodyLimit)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse(
            {"error": {"code": "internal_error", "message": "internal server error",
                       "field": None}}, status_code=500)
