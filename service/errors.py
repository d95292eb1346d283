"""One error hierarchy for the API, rendered as ``{"error": {"code", "message", "field"}}``.

Library errors (``solvers.errors``) and request validation errors are mapped to
the same shape, so bad input always gets a 4xx naming the field, never a 500. The web
framework's side (the exception handlers) is in :mod:`service.api.errors`: workers and
operations raise these without importing FastAPI.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel

from solvers.errors import (
    CancelledError,
    ConvergenceError,
    MeshFormatError,
    OTGeoError,
    UnsupportedDomainError,
)


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
    headers: dict[str, str] | None = None  # sent with the error response (e.g. Retry-After)

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


class RequestTimeout(ApiError):
    status_code = 408
    code = "request_timeout"


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
    """``{"code", "message", "field"}`` for any exception (used for failed jobs).

    Errors raised on purpose (``ApiError``, the library's ``OTGeoError``) keep their
    message and field. Anything else never shows its text (it may name internals or server
    paths): numerical breakdowns and memory exhaustion get a fixed message of their own,
    the rest a generic one; the caller logs the exception with its traceback.
    """
    if isinstance(exc, OTGeoError):
        exc = from_library(exc)
    if isinstance(exc, ApiError):
        return exc.body()["error"]
    if isinstance(exc, MemoryError):
        return {"code": "out_of_memory", "field": None,
                "message": "the job ran out of memory; use fewer points or columns"}
    if isinstance(exc, (ArithmeticError, np.linalg.LinAlgError)) or (
            isinstance(exc, RuntimeError) and "positive definite" in str(exc)):
        return {"code": "numerical_error", "field": None,
                "message": "the computation broke down numerically (a factorization or "
                "iteration failed); a smaller gamma or better-conditioned input may help"}
    return {"code": "internal_error", "field": None,
            "message": "internal error while running the job (logged on the server)"}


def _is_union_tag(part) -> bool:
    """A pydantic union member in an error location ('list[float]', 'BumpDistribution',
    'tuple[int, int]', 'function-after[...]', 'constrained-float'), not a field name."""
    return isinstance(part, str) and ("[" in part or part[:1].isupper()
                                      or part.startswith("constrained-"))


def most_relevant_error(errors: list[dict]) -> dict:
    """The error to report: for a value matching no member of a union, the member it came
    closest to (errors that only say "not this member's type" are skipped, then the member
    with the fewest problems wins), so ``{"vertex": 0, "radius": Infinity}`` is reported at
    ``radius``, not as "not a list"."""
    def member(err):
        loc = tuple(err.get("loc", ()))
        for i, part in enumerate(loc):
            if _is_union_tag(part):
                return loc[:i + 1]
        return None

    tagged = [(member(e), e) for e in errors]
    if not any(m is not None for m, _ in tagged):
        return errors[0]
    shape_only = {m for m, e in tagged if m is not None and tuple(e.get("loc", ())) == m
                  and str(e.get("type", "")).endswith("_type")}
    candidates = [(m, e) for m, e in tagged if m not in shape_only] or tagged
    counts: dict = {}
    for m, _ in candidates:
        counts[m] = counts.get(m, 0) + 1
    return min(candidates, key=lambda me: counts[me[0]])[1]


def field_from_loc(loc, elements: bool = False) -> str | None:
    """The request field of an error location (``fixed[0].node``); trailing list indices
    are dropped (``points[3][1]`` -> ``points``) unless ``elements`` (for messages)."""
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "header", "form")
             and not _is_union_tag(p)]
    while parts and not elements and len(parts) > 1 and parts[-1].isdigit():
        parts.pop()
    if not parts:
        return None
    out = parts[0]
    for p in parts[1:]:
        out += f"[{p}]" if p.isdigit() else f".{p}"
    return out


ERROR_RESPONSES = {
    400: {"model": ErrorResponse, "description": "malformed request body (not parseable)"},
    401: {"model": ErrorResponse, "description": "missing or wrong X-API-Key"},
    404: {"model": ErrorResponse, "description": "unknown domain or job"},
    413: {"model": ErrorResponse, "description": "upload or domain too large"},
    422: {"model": ErrorResponse, "description": "invalid input (the field is named)"},
    429: {"model": ErrorResponse, "description": "a quota of the caller's tenant is reached "
          "(`quota_exceeded`: queued jobs or stored bytes); retry after `Retry-After` seconds",
          "headers": {"Retry-After": {"description": "seconds to wait before retrying",
                                      "schema": {"type": "integer"}}}},
}


def responses(*codes: int) -> dict:
    return {c: ERROR_RESPONSES.get(c, {"model": ErrorResponse}) for c in codes}
