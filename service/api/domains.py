"""/v1/domains: upload (mesh file or JSON), list, get, delete."""

from __future__ import annotations

import asyncio
import hashlib
from typing import Annotated, Literal

from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import TypeAdapter

from service.api.bodies import parse_spec
from service.api.deps import DomainSvc, IdempotencyKeyDep, get_runtime
from service.api.paging import Cursor, decode_cursor, encode_cursor
from service.errors import (
    ApiError,
    ErrorResponse,
    InvalidInput,
    PayloadTooLarge,
    UnsupportedMediaType,
    responses,
)
from service.idempotency import REPLAYED, for_request
from service.schemas import PATH_SEGMENT, DomainList, DomainOut, DomainSpec
from solvers.domains.mesh import MESH_FORMATS

router = APIRouter(prefix="/v1/domains", tags=["domains"])
SPEC = TypeAdapter(DomainSpec)

UPLOAD_BODY = {
    "required": True,
    "content": {
        "multipart/form-data": {"schema": {
            "type": "object", "required": ["file"],
            "properties": {
                "file": {"type": "string", "format": "binary",
                         "description": "mesh file: OBJ, PLY, STL, OFF, GLB or glTF"},
                "format": {"type": "string", "enum": list(MESH_FORMATS),
                           "description": "file format when the file name has no extension"},
                "laplacian": {"type": "string", "enum": ["robust", "cotan"],
                              "default": "robust"},
                "weld": {"type": "boolean", "description": "merge vertices at equal "
                         "positions (seams); default: the format's usual behaviour"},
            }}},
    },
}
JSON_BODY = {
    "required": True,
    "content": {
        "application/json": {"schema": {"$ref": "#/components/schemas/DomainSpec"}},
    },
}


async def _read_chunks(request: Request, limit: int) -> list[bytes]:
    """The body as the server received it, in its chunks (an 80 MB upload joined or parsed
    in one piece would hold the GIL, and so the event loop, for tens of milliseconds)."""
    declared = request.headers.get("content-length")
    if declared and declared.isdigit() and int(declared) > limit:
        raise PayloadTooLarge(f"upload of {declared} bytes exceeds the limit of {limit}",
                              field="file")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise PayloadTooLarge(f"upload exceeds the limit of {limit} bytes", field="file")
        chunks.append(chunk)
    return chunks


async def _joined(chunks: list[bytes]) -> bytes:
    """``b"".join(chunks)``, off the event loop when large."""
    if sum(map(len, chunks)) < 2**20:
        return b"".join(chunks)
    return await run_in_threadpool(b"".join, chunks)


def _pieces(chunks: list[bytes], size: int = 2**20):
    """The chunks cut to at most ``size`` bytes each, so that no single parsing step of the
    multipart parser (a copy, a search for the boundary) holds the GIL for long."""
    for chunk in chunks:
        for start in range(0, len(chunk), size):
            yield chunk[start:start + size] if len(chunk) > size else chunk


def _parse_multipart(chunks: list[bytes], headers, limit: int) -> tuple:
    """``(file bytes, file name, format, laplacian, weld)`` of a multipart upload, parsed in
    the calling thread (the thread pool) on its own event loop."""
    from starlette.formparsers import MultiPartParser

    async def stream():
        for piece in _pieces(chunks):
            yield piece

    async def parse():
        form = await MultiPartParser(headers, stream(), max_part_size=limit).parse()
        try:
            upload = form.get("file")
            if upload is None or isinstance(upload, str):
                raise InvalidInput("multipart upload needs a 'file' part", field="file")
            data = await upload.read()
            fmt, laplacian = form.get("format"), form.get("laplacian") or "robust"
            weld = form.get("weld")
            return (data, upload.filename, fmt if isinstance(fmt, str) else None,
                    str(laplacian), weld if isinstance(weld, str) else None)
        finally:
            await form.close()

    try:
        return asyncio.run(parse())
    except ApiError:
        raise
    except Exception as exc:  # malformed multipart body
        detail = getattr(exc, "detail", None) or type(exc).__name__
        raise InvalidInput(f"malformed multipart upload: {detail}", field="file") from exc


async def _sha256(data: bytes) -> str:
    """Hex SHA-256 of ``data``, off the event loop when large (80 MB take 0.2 s or more)."""
    if len(data) < 2**20:
        return hashlib.sha256(data).hexdigest()
    return await run_in_threadpool(lambda: hashlib.sha256(data).hexdigest())


async def _create(request: Request, response: Response, svc, allow_json: bool,
                  allow_multipart: bool, idempotency_key: str | None = None):
    limit = get_runtime(request).settings.max_upload_bytes
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype == "multipart/form-data" and allow_multipart:
        chunks = await _read_chunks(request, limit)
        data, filename, fmt, laplacian, weld = await run_in_threadpool(
            _parse_multipart, chunks, request.headers, limit)
        del chunks  # the file's bytes are kept once, in data
        content = {"file_sha256": await _sha256(data), "filename": filename,
                   "format": fmt, "laplacian": laplacian, "weld": weld}

        async def build():
            return await svc.create_from_file(data, filename, fmt, laplacian, weld)
    elif ctype in ("application/json", "") and allow_json:
        body = await _joined(await _read_chunks(request, limit))
        content = {"json_sha256": await _sha256(body)}

        async def build():
            return await svc.create_from_spec(await parse_spec(body))
    elif allow_json:
        raise UnsupportedMediaType(f"content type {ctype!r}: send application/json (or a mesh "
                                   "file as multipart/form-data to /v1/domains/upload)",
                                   field="content-type")
    else:
        raise UnsupportedMediaType(f"content type {ctype!r}: send multipart/form-data with a "
                                   "'file' part (JSON domains go to POST /v1/domains)",
                                   field="content-type")
    idempotency = for_request(svc.rt, svc.tenant.id, idempotency_key,
                              f"POST {request.url.path}", content)
    earlier = None if idempotency is None else \
        await run_in_threadpool(idempotency.previous)
    if earlier is not None:  # the same request again: what it created then
        meta = await run_in_threadpool(svc.get, earlier.resource_id)
        response.status_code = earlier.status_code or 201
        response.headers[REPLAYED] = "true"
    else:
        meta, created = await build()
        if not created:
            response.status_code = 200
        if idempotency is not None:
            await run_in_threadpool(svc.rt.tenancy.put_key, idempotency.record(
                "domain", meta["id"], response.status_code or 201))
    response.headers["Location"] = f"/v1/domains/{meta['id']}"
    return DomainOut.from_meta(meta)


CREATED = {200: {"model": DomainOut, "description": "already stored (same id)"},
           503: {"model": ErrorResponse, "description": "storage cannot take writes "
                 "(`storage_unavailable`)"}}


@router.post("", operation_id="createDomain", status_code=201, response_model=DomainOut,
             summary="Create a domain from JSON (grid, graph, point cloud or mesh arrays)",
             openapi_extra={"requestBody": JSON_BODY},
             responses={**CREATED, **responses(400, 401, 413, 415, 422, 429)})
async def create_domain(request: Request, response: Response, svc: DomainSvc,
                        idempotency_key: IdempotencyKeyDep):
    """A JSON domain (``{"kind": "grid" | "graph" | "pointcloud" | "mesh", ...}``). A mesh
    file sent here as multipart/form-data is accepted too (as by ``/v1/domains/upload``)."""
    return await _create(request, response, svc, allow_json=True, allow_multipart=True,
                         idempotency_key=idempotency_key)


@router.post("/upload", operation_id="uploadDomain", status_code=201, response_model=DomainOut,
             summary="Upload a mesh file (OBJ, PLY, STL, OFF, GLB, glTF) as multipart/form-data",
             openapi_extra={"requestBody": UPLOAD_BODY},
             responses={**CREATED, **responses(401, 413, 415, 422, 429)})
async def upload_domain(request: Request, response: Response, svc: DomainSvc,
                        idempotency_key: IdempotencyKeyDep):
    return await _create(request, response, svc, allow_json=False, allow_multipart=True,
                         idempotency_key=idempotency_key)


@router.get("", operation_id="listDomains", response_model=DomainList,
            responses=responses(401, 422))
def list_domains(svc: DomainSvc,
                 limit: Annotated[int, Query(ge=1, le=1000, description="page size")] = 100,
                 cursor: Cursor = None,
                 kind: Annotated[Literal["mesh", "grid", "graph", "pointcloud"] | None,
                                 Query(description="only domains of this kind")] = None):
    """Stored domains, oldest first, a page at a time (follow `next_cursor` until null)."""
    after = decode_cursor(cursor)

    def key(meta):
        return (float(meta.get("created_at", 0.0)), meta["id"])

    metas = sorted((m for m in svc.list() if kind is None or m.get("kind") == kind), key=key)
    if after is not None:
        metas = [m for m in metas if key(m) > after]
    page = metas[:limit]
    more = len(metas) > limit
    return DomainList(domains=[DomainOut.from_meta(m) for m in page],
                      next_cursor=encode_cursor(*key(page[-1])) if more else None)


DomainPathId = Annotated[str, Path(pattern=PATH_SEGMENT)]


@router.get("/{domain_id}", operation_id="getDomain", response_model=DomainOut,
            responses=responses(401, 404))
def get_domain(domain_id: DomainPathId, svc: DomainSvc):
    return DomainOut.from_meta(svc.get(domain_id))


@router.delete("/{domain_id}", operation_id="deleteDomain", status_code=204,
               responses=responses(401, 404))
def delete_domain(domain_id: DomainPathId, svc: DomainSvc):
    svc.delete(domain_id)
    return Response(status_code=204)
