"""Parsing and validating JSON domain bodies without stalling the event loop.

``json.loads`` and pydantic validation of a 12 MB graph are single C calls that hold the GIL
for seconds, so a thread does not keep the loop answering: bodies above
``IN_PROCESS_BYTES`` are parsed in a child process, which sends back the large numeric
arrays as numpy arrays (a memory copy to unpickle, instead of rebuilding a million Python
lists). Smaller bodies are parsed in the thread pool. Either way the result is the same
validated ``DomainSpec`` (large array fields as numpy arrays when they convert losslessly).
"""

from __future__ import annotations

import asyncio
import json
import logging
from concurrent.futures.process import BrokenProcessPool

import numpy as np
from pydantic import TypeAdapter, ValidationError

from service.child_pool import ChildPool
from service.errors import ApiError, InvalidInput, field_from_loc
from service.schemas import DomainSpec, GraphSpec, GridSpec, MeshSpec, PointCloudSpec

log = logging.getLogger("otgeo.service")

SPEC = TypeAdapter(DomainSpec)
IN_PROCESS_BYTES = 1 << 20  # bodies from 1 MiB on are parsed in a child process
# bodies below this are parsed on the event loop (tens of microseconds): a thread hop costs
# more than the parse, and each hop waits for a core on a busy machine
ON_LOOP_BYTES = 16 << 10
KINDS = {"grid": GridSpec, "graph": GraphSpec, "pointcloud": PointCloudSpec, "mesh": MeshSpec}
ARRAY_FIELDS = {"edges": np.int64, "faces": np.int64, "points": np.float64,
                "vertices": np.float64, "positions": np.float64, "weights": np.float64}


def _too_deep() -> ApiError:
    return ApiError("body is nested too deeply to be a request", field="body",
                    code="invalid_json")


def load_json(body: bytes):
    """``json.loads(body)``; ApiError ``invalid_json`` naming the field ``body`` when the body
    is empty, not UTF-8, not JSON or nested too deeply."""
    if not body:
        raise InvalidInput("empty request body", field="body")
    try:
        return json.loads(body)
    except RecursionError as exc:
        raise _too_deep() from exc
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        where = (f" (line {exc.lineno}, column {exc.colno}, byte {exc.pos})"
                 if hasattr(exc, "lineno") else "")
        raise InvalidInput(f"body is not valid JSON{where}", field="body",
                           code="invalid_json") from exc


def spec_from_json(body: bytes):
    """The validated DomainSpec of a JSON body; ApiError naming the field otherwise."""
    raw = load_json(body)
    try:
        return SPEC.validate_python(raw)
    except RecursionError as exc:
        raise _too_deep() from exc
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = list(err["loc"])
        if loc and isinstance(raw, dict) and loc[0] == raw.get("kind"):
            loc = loc[1:]  # drop the union tag
        tag_error = err["type"] in ("union_tag_invalid", "union_tag_not_found")
        field = "kind" if tag_error else (field_from_loc(loc) or "body")
        raise InvalidInput(f"{field}: {err['msg']}", field=field) from exc


def compact_spec(body: bytes) -> tuple:
    """In the child: ``("ok", kind, fields)`` with large numeric lists as arrays, or
    ``("error", status, code, message, field)``."""
    try:
        spec = spec_from_json(body)
    except ApiError as exc:
        return ("error", exc.status_code, exc.code, exc.message, exc.field)
    fields = {}
    for name in type(spec).model_fields:
        value = getattr(spec, name)
        dtype = ARRAY_FIELDS.get(name)
        if dtype is not None and isinstance(value, list) and len(value) > 64:
            try:
                value = np.asarray(value, dtype=dtype)
            except (ValueError, OverflowError, TypeError):
                pass  # ragged or out of range: sent as it is, the domain builder reports it
        fields[name] = value
    return ("ok", spec.kind, fields)


def _numeric(value: list) -> bool:
    return all(type(x) is float or type(x) is int for x in value)


def compact_json(body: bytes) -> tuple:
    """In the child: ``("ok", obj)`` with flat numeric lists longer than 64 as numpy arrays
    (pickled as one buffer), or ``("error", status, code, message, field)``."""
    try:
        raw = load_json(body)
    except ApiError as exc:
        return ("error", exc.status_code, exc.code, exc.message, exc.field)

    def compact(value):
        if isinstance(value, dict):
            return {k: compact(v) for k, v in value.items()}
        if isinstance(value, list):
            if len(value) > 64 and _numeric(value):
                kind = np.float64 if any(type(x) is float for x in value) else np.int64
                try:
                    return np.asarray(value, dtype=kind)
                except OverflowError:  # an int beyond int64: sent as it is
                    return value
            return [compact(v) for v in value]
        return value

    return ("ok", compact(raw))


def expand_json(value):
    """The inverse of ``compact_json``'s array packing: the same JSON object (ints stay ints,
    floats floats)."""
    if isinstance(value, dict):
        return {k: expand_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [expand_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


PARSER = ChildPool()


def _executor():
    return PARSER.get()


def _discard_pool() -> None:
    PARSER.discard()


def _raise(out: tuple) -> None:
    _, status, code, message, field = out
    err = ApiError(message, field=field, code=code)
    err.status_code = status
    raise err


async def parse_json(body: bytes):
    """The JSON object of ``body``: a small one (``ON_LOOP_BYTES``) parsed on the event loop,
    larger ones off it (a child process from ``IN_PROCESS_BYTES`` on, else the thread pool);
    ApiError ``invalid_json`` otherwise."""
    from fastapi.concurrency import run_in_threadpool

    if len(body) < min(ON_LOOP_BYTES, IN_PROCESS_BYTES):
        return load_json(body)
    if len(body) < IN_PROCESS_BYTES:
        return await run_in_threadpool(load_json, body)
    out, parsed = await _in_parser_process(compact_json, body, load_json)
    return parsed if out is None else await run_in_threadpool(expand_json, out[1])


async def parse_spec(body: bytes):
    """The validated DomainSpec of ``body``, parsed off the event loop."""
    from fastapi.concurrency import run_in_threadpool

    if len(body) < IN_PROCESS_BYTES:
        return await run_in_threadpool(spec_from_json, body)
    out, parsed = await _in_parser_process(compact_spec, body, spec_from_json)
    if out is None:
        return parsed
    _, kind, fields = out
    return KINDS[kind].model_construct(**fields)


async def _in_parser_process(task, body: bytes, in_thread):
    """``(task(body), None)`` from the parser process (its ``("error", ...)`` raised as the
    API error), or ``(None, in_thread(body))`` parsed in a thread when that process is
    unavailable."""
    from fastapi.concurrency import run_in_threadpool

    try:
        out = await asyncio.wrap_future(_executor().submit(task, body))
    except (BrokenProcessPool, OSError, RuntimeError) as exc:  # child died: parse here
        log.warning("JSON parser process unavailable (%s); parsing in a thread", exc)
        _discard_pool()
        return None, await run_in_threadpool(in_thread, body)
    if out[0] == "error":
        _raise(out)
    return out, None
