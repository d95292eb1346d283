"""Routes taking images (multipart uploads): ``POST /v1/color-transfers``.

The images are stored as blobs (content-addressed) after a header check (format, pixel
limits) and the job is created over their ids by the same path as every other operation
(:func:`service.api.operations.finish_submission`), whose validation decodes them fully.
"""

import hashlib
from typing import Annotated, Literal

from fastapi import APIRouter, File, Form, Query, Response, UploadFile
from fastapi.concurrency import run_in_threadpool
from pydantic import ValidationError

from service.api.deps import IdempotencyKeyDep, JobSvc, RuntimeDep
from service.api.operations import ROUTE_RESPONSES, WAIT_DESCRIPTION, finish_submission
from service.errors import InvalidInput, PayloadTooLarge, responses
from service.operations.color import (
    DEFAULT_LUMINANCE_SLOPE,
    DEFAULT_REGULARIZATION,
    DEFAULT_RESPLIT,
    MAX_IMAGES,
    ColorTransferRequest,
    check_header,
)
from service.operations.guide_pages import openapi_extra
from service.schemas import JobOut
from service.tenants import check_bytes_quota

router = APIRouter(prefix="/v1", tags=["operations"])


def _json_list(text: str | None, field: str):
    import json

    if text is None or text == "":
        return None
    try:
        value = json.loads(text)
    except ValueError as exc:
        raise InvalidInput(f"{field} must be a JSON list", field=field) from exc
    if not isinstance(value, list):
        raise InvalidInput(f"{field} must be a JSON list", field=field)
    return value


def _store_images(rt, tenant, uploads: list[bytes], media: list[str]) -> list[str]:
    """Store the images as blobs (shared, content-addressed) held by ``tenant``, within its
    stored-bytes quota."""
    ids = []
    infos = [check_header(data, f"images[{i}]", rt.settings) for i, data in enumerate(uploads)]
    new = {hashlib.sha256(d).hexdigest(): len(d) for d in uploads}
    adding = sum(size for blob_id, size in new.items()
                 if rt.tenancy.holding(tenant.id, "blob", blob_id) is None)
    check_bytes_quota(rt.settings, tenant, rt.tenancy.stored_bytes(tenant.id), adding)
    for data, media_type, info in zip(uploads, media, infos, strict=True):
        meta, _ = rt.store.put_blob(data, media_type or "application/octet-stream",
                                    {"width": info.width, "height": info.height,
                                     "format": info.format})
        rt.tenancy.hold(tenant.id, "blob", meta["id"], meta["bytes"],
                        {"media_type": meta["media_type"]})
        ids.append(meta["id"])
    return ids


@router.post(
    "/color-transfers", operation_id="createColorTransfer", status_code=202,
    response_model=JobOut, responses={**ROUTE_RESPONSES, **responses(413)},
    openapi_extra=openapi_extra("color-transfers"),
    summary="Color transfer between 2-16 uploaded images by optimal transport of their "
            "chrominance histograms (exact split plans, or the thesis' barycentric map, §3.7)")
async def create_color_transfer(
    response: Response, svc: JobSvc, rt: RuntimeDep, idempotency_key: IdempotencyKeyDep,
    images: Annotated[list[UploadFile], File(min_length=2, max_length=MAX_IMAGES,
                                             description="2 to 16 image files (PNG, JPEG, "
                                             "TIFF, WebP; 8 or 16 bits; alpha kept)")],
    # optional fields are absent, never null, in the spec: a multipart field is text, and a
    # client sending null would write "null", which is neither a number nor a JSON list
    weights: str = Form(None, description="JSON list: one weight per image"),
    alphas: str = Form(None, description="JSON list of weight vectors (a sequence, "
                              "e.g. [[1,0],[0.5,0.5],[0,1]])"),
    mode: Literal["split", "barycentric"] = Form(
        "split", description="split: exact plan, each color's pixels split among its "
        "targets, guided filter, second split, colors moved inside their histogram node to "
        "the target's, smooth L* shift into the sRGB gamut; barycentric: the thesis' map "
        "(Fig. 3.12)"),
    bins: int = Form(None, ge=8, le=512, description="nodes per axis of the ab grid "
                            "(8..512; default 65 split, 256 barycentric)"),
    gamma: float = Form(None, gt=0, description="entropic regularization (squared ab "
                        "units); default 16, or on grids below 17 nodes twice the smallest "
                        "the grid resolves"),
    regularization: float = Form(DEFAULT_REGULARIZATION, ge=0, le=1, description="split mode: "
                                 "guided filter strength (0..1; 0 = off)"),
    luminance: bool = Form(True, description="also transfer L* (1-D OT); false: "
                           "chrominance only"),
    luminance_slope: float = Form(DEFAULT_LUMINANCE_SLOPE, ge=0, le=1000, description="split "
                                  "mode: contrast limit (>= 1) of the L* map; 0: exact map"),
    resplit: float = Form(DEFAULT_RESPLIT, ge=0, le=1, description="split mode: fraction of "
                          "the second split (filtered colours to the target's histogram) "
                          "that is applied, after a guided filter of radius 1 cell; 1 "
                          "(default): the target's histogram up to the binning"),
    sharpen: bool = Form(False, description="entropic sharpening of the barycenters"),
    debiased: bool = Form(False, description="debiased barycenters"),
    recolor: str = Form(None, description="JSON list of image indices to recolor"),
    format: Literal["png", "jpeg"] = Form("png", description="output image format"),
    time_limit: float = Form(None, gt=0, description="seconds (absent: no limit)"),
    wait: float = Query(0.0, ge=0, description=WAIT_DESCRIPTION),
):
    """Upload the images and create the job; results at `/v1/jobs/{id}/result`, images at
    `/v1/jobs/{id}/files/image-{b}-{i}.png`, `barycenter-{b}.png`, `histogram-{i}.png`
    and `histogram-{b}-{i}.png`."""
    if len(images) < 2:
        raise InvalidInput(f"color transfer needs at least 2 images, got {len(images)}",
                           field="images")
    if len(images) > 16:
        raise InvalidInput(f"color transfer takes at most 16 images, got {len(images)}",
                           field="images")
    limit = rt.settings.max_upload_bytes
    datas, media, total = [], [], 0
    for i, upload in enumerate(images):
        data = await upload.read()
        total += len(data)
        if total > limit:
            raise PayloadTooLarge(f"the images exceed the upload limit of {limit} bytes",
                                  field=f"images[{i}]")
        datas.append(data)
        media.append(upload.content_type or "")
    ids = await run_in_threadpool(_store_images, rt, svc.tenant, datas, media)
    try:
        body = ColorTransferRequest(
            images=ids, weights=_json_list(weights, "weights"),
            alphas=_json_list(alphas, "alphas"), mode=mode, bins=bins, gamma=gamma,
            regularization=regularization, luminance=luminance,
            luminance_slope=luminance_slope, resplit=resplit,
            sharpen=sharpen, debiased=debiased, recolor=_json_list(recolor, "recolor"),
            format=format, time_limit=time_limit)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(p) for p in err.get("loc", ())) or None
        raise InvalidInput(f"{field}: {err.get('msg')}", field=field) from None
    return await finish_submission("color-transfers", None, body, wait, response, svc, rt,
                                   idempotency_key)
