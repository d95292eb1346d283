"""The API's exception handlers: every error leaves as ``{"error": {"code", "message",
"field"}}`` (:mod:`service.errors`), a 405 with the ``Allow`` the OpenAPI document gives."""

from __future__ import annotations

import logging
import re

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import DBAPIError
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.errors import (
    ApiError,
    InvalidInput,
    ServiceUnavailable,
    field_from_loc,
    from_library,
    most_relevant_error,
)
from solvers.errors import OTGeoError

log = logging.getLogger("otgeo.service")

HTTP_METHODS = ("get", "put", "post", "delete", "options", "head", "patch", "trace")


def allowed_methods(app: FastAPI, path: str) -> str:
    """``Allow`` of a 405: the methods the app's OpenAPI document gives the request's path,
    over every path template it matches (Starlette names only the methods of the first
    route matching the path, e.g. GET of ``/v1/jobs/{id}`` without its DELETE)."""
    table = getattr(app.state, "allow_table", None)
    if table is None:
        table = []
        for template, ops in app.openapi().get("paths", {}).items():
            pattern = re.sub(r"\\\{[^}]*\\\}", "[^/]+", re.escape(template))
            table.append(("{" not in template, re.compile(f"^{pattern}$"),
                          {m.upper() for m in ops if m in HTTP_METHODS}))
        app.state.allow_table = table
    # a concrete path (/v1/domains/upload) before the templates it also matches, as OpenAPI
    # resolves them
    matches = [(literal, declared) for literal, regex, declared in table if regex.match(path)]
    chosen = [declared for literal, declared in matches if literal] or [d for _, d in matches]
    return ", ".join(sorted(set().union(*chosen)))


def install_handlers(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError):
        return JSONResponse(exc.body(), status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(OTGeoError)
    async def _library_error(request: Request, exc: OTGeoError):
        err = from_library(exc)
        return JSONResponse(err.body(), status_code=err.status_code)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError):
        errors = exc.errors()
        first = most_relevant_error(errors) if errors else {"loc": (), "msg": "invalid request"}
        field = field_from_loc(first.get("loc", ()))
        where = field_from_loc(first.get("loc", ()), elements=True)
        msg = first.get("msg", "invalid request")
        if first.get("type") == "json_invalid":  # loc is ("body", <byte offset>)
            offset = first.get("loc", (None, None))[-1]
            field = "body"
            msg = "body is not valid JSON" + (f" (at byte {offset})"
                                              if isinstance(offset, int) else "")
            return JSONResponse(InvalidInput(msg, field=field, code="invalid_json").body(),
                                status_code=422)
        message = f"{where}: {msg}" if where else msg
        if len(errors) > 1:
            message += f" (and {len(errors) - 1} more problems)"
        return JSONResponse(InvalidInput(message, field=field).body(), status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException):
        codes = {404: "not_found", 405: "method_not_allowed"}
        err = ApiError(str(exc.detail), code=codes.get(exc.status_code, "http_error"))
        headers = dict(getattr(exc, "headers", None) or {})
        if exc.status_code == 405:
            headers["Allow"] = (allowed_methods(app, request.url.path)
                                or headers.get("Allow", ""))
        return JSONResponse(err.body(), status_code=exc.status_code, headers=headers or None)

    @app.exception_handler(DBAPIError)
    async def _database(request: Request, exc: DBAPIError):
        log.warning("job table unavailable: %s", exc)
        err = ServiceUnavailable("the job database is unavailable; retry shortly")
        return JSONResponse(err.body(), status_code=503, headers={"Retry-After": "2"})

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse(
            {"error": {"code": "internal_error", "message": "internal server error",
                       "field": None}}, status_code=500)
