"""/v1/domains: upload (mesh file or JSON), list, get, delete."""

from __future__ import annotations

import json

from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import TypeAdapter, ValidationError

from service.api.deps import DomainSvc, get_runtime
from service.errors import (
    InvalidInput,
    PayloadTooLarge,
    UnsupportedMediaType,
    field_from_loc,
    responses,
)
from service.schemas import DomainList, DomainOut, DomainSpec

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
                "format": {"type": "string", "description": "file format when the file name "
                           "has no extension (obj, ply, stl, off, glb, gltf)"},
                "laplacian": {"type": "string", "enum": ["robust", "cotan"],
                              "default": "robust"},
            }}},
        "application/json": {"schema": {"$ref": "#/components/schemas/DomainSpec"}},
    },
}


async def _read_body(request: Request, limit: int) -> bytes:
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
    body = b"".join(chunks)
    request._body = body  # let request.form() parse the bytes already read
    return body


@router.post("", operation_id="createDomain", status_code=201, response_model=DomainOut,
             summary="Upload a domain (mesh file, or JSON grid/graph/point cloud/mesh)",
             openapi_extra={"requestBody": UPLOAD_BODY},
             responses={200: {"model": DomainOut, "description": "already stored (same id)"},
                        **responses(401, 413, 415, 422)})
async def create_domain(request: Request, response: Response,
                        svc: DomainSvc):
    limit = get_runtime(request).settings.max_upload_bytes
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    body = await _read_body(request, limit)
    if ctype == "multipart/form-data":
        try:
            form = await request.form(max_part_size=limit)
        except Exception as exc:  # malformed multipart body
            detail = getattr(exc, "detail", None) or str(exc)
            raise InvalidInput(f"malformed multipart upload: {detail}", field="file") from exc
        upload = form.get("file")
        if upload is None or isinstance(upload, str):
            raise InvalidInput("multipart upload needs a 'file' part", field="file")
        data = await upload.read()
        fmt = form.get("format")
        laplacian = form.get("laplacian") or "robust"
        meta, created = await run_in_threadpool(
            svc.from_file, data, upload.filename, fmt if isinstance(fmt, str) else None,
            str(laplacian))
    elif ctype in ("application/json", ""):
        if not body:
            raise InvalidInput("empty request body", field="body")
        try:
            raw = json.loads(body)
        except ValueError as exc:
            raise InvalidInput(f"body is not valid JSON: {exc}", field="body") from exc
        try:
            spec = SPEC.validate_python(raw)
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = list(err["loc"])
            if loc and isinstance(raw, dict) and loc[0] == raw.get("kind"):
                loc = loc[1:]  # drop the union tag
            tag_error = err["type"] in ("union_tag_invalid", "union_tag_not_found")
            field = "kind" if tag_error else (field_from_loc(loc) or "body")
            raise InvalidInput(f"{field}: {err['msg']}", field=field) from exc
        meta, created = await run_in_threadpool(svc.from_spec, spec)
    else:
        raise UnsupportedMediaType(f"content type {ctype!r}: send multipart/form-data with a "
                                   "mesh file, or application/json", field="content-type")
    if not created:
        response.status_code = 200
    response.headers["Location"] = f"/v1/domains/{meta['id']}"
    return DomainOut.from_meta(meta)


@router.get("", operation_id="listDomains", response_model=DomainList,
            responses=responses(401))
def list_domains(svc: DomainSvc):
    return DomainList(domains=[DomainOut.from_meta(m) for m in svc.list()])


@router.get("/{domain_id}", operation_id="getDomain", response_model=DomainOut,
            responses=responses(401, 404))
def get_domain(domain_id: str, svc: DomainSvc):
    return DomainOut.from_meta(svc.get(domain_id))


@router.delete("/{domain_id}", operation_id="deleteDomain", status_code=204,
               responses=responses(401, 404))
def delete_domain(domain_id: str, svc: DomainSvc):
    svc.delete(domain_id)
    return Response(status_code=204)
