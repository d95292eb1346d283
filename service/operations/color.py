"""Color transfer between uploaded images (thesis §3.7; :func:`solvers.color.color_transfer`).

``POST /v1/color-transfers`` (multipart, :mod:`service.api.images`) stores each image as a
blob and creates a job over their ids.  Everything that can be refused is decided at
submission (:func:`validate`): each blob must decode completely (no truncated or corrupt
files, no decompression bombs) within the per-image and per-job pixel limits
(``OTGEO_COLOR_MAX_PIXELS``, ``OTGEO_COLOR_MAX_JOB_PIXELS``; 413 beyond), and the weights,
``bins`` and ``gamma`` pass the library's validators, so an accepted job can fail only for
numerical reasons.

``mode`` picks the transfer: ``split`` (default; exact plan, pixels split in its
proportions, guided-filter regularization of strength ``regularization``, a second split
to the target's histogram, each colour moved inside its histogram node to the target's
colours there, a smooth L* shift into the sRGB gamut whose slope along the input's L* is
limited) or
``barycentric`` (the thesis' map, Fig. 3.12); ``luminance=false`` transfers chrominance
only.

Result: ``values`` (solver metrics, per-output chrominance statistics, the exact plans'
costs in split mode, file names), arrays ``histograms`` ``(k, bins²)`` and
``barycenters`` ``(B, bins²)``, and files ``image-{b}-{i}.png`` (or ``.jpg``; input ``i``
recolored for weight vector ``b``), ``barycenter-{b}.png`` (the histogram the inputs go
to, as a picture, Fig. 3.12), ``histogram-{i}.png`` (input ``i``'s ab histogram) and
``histogram-{b}-{i}.png`` (the output's), so inputs, outputs and target can be compared.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, Field, field_validator

from service.errors import InvalidInput, PayloadTooLarge
from service.operations.base import Int, Operation, OperationOutput, OperationRequest, ResultFile
from service.operations.examples import EXAMPLE_ID, example
from solvers.color import (
    ab_histogram,
    color_transfer,
    histogram_picture,
    probe_image,
    read_image,
    rgb_to_lab,
    write_image,
)
from solvers.color.transfer import (
    DEFAULT_BINS,
    DEFAULT_GAMMA,
    DEFAULT_LUMINANCE_SLOPE,
    DEFAULT_REGULARIZATION,
    DEFAULT_RESPLIT,
    MAX_IMAGES,
    check_alphas,
    resolve_bins,
    resolve_gamma,
)

MAX_ALPHAS = 32
MEDIA = {"png": "image/png", "jpeg": "image/jpeg"}
EXT = {"png": "png", "jpeg": "jpg"}


class ColorTransferRequest(OperationRequest):
    model_config = example({"images": [EXAMPLE_ID, EXAMPLE_ID], "weights": [0.5, 0.5],
                            "mode": "split", "regularization": DEFAULT_REGULARIZATION})
    images: list[str] = Field(min_length=2, max_length=MAX_IMAGES,
                              description="blob ids of the uploaded images (2 to 16)")
    weights: list[float] | None = Field(None, description="one barycentric weight per image "
                                        "(normalized); default uniform")
    alphas: list[list[float]] | None = Field(
        None, min_length=1, max_length=MAX_ALPHAS, description="several weight vectors "
        "(e.g. (1 - s, s) for a sequence of s, thesis Fig. 3.12); exclusive with weights")
    mode: Literal["split", "barycentric"] = Field(
        "split", description="split: exact plan between the ab histograms, each color's "
        "pixels split among its targets in the plan's proportions (spatially coherent), "
        "then a guided filter on the color shift, a second split to the target's histogram, "
        "each color moved inside its histogram node to the target's colors there (towards "
        "an input), and a smooth L* shift into the sRGB gamut; barycentric: the thesis' "
        "barycentric projection of the entropic plans (Fig. 3.12)")
    bins: Int | None = Field(None, ge=8, le=512, description="nodes per axis of the ab "
                             "histogram grid over [-128, 128]^2 (default "
                             f"{DEFAULT_BINS['split']} for split, "
                             f"{DEFAULT_BINS['barycentric']} for barycentric)")
    gamma: float | None = Field(None, gt=0, description="entropic regularization in "
                                "squared ab units (blur of standard deviation sqrt(gamma/2)) "
                                "of the entropic barycenters (barycentric mode; split mode "
                                f"with 3+ images); default {DEFAULT_GAMMA:g}, or on grids "
                                "below 17 nodes twice the smallest the grid resolves")
    regularization: float = Field(
        DEFAULT_REGULARIZATION, ge=0, le=1, description="split mode: strength (epsilon) of "
        "the edge-aware guided filter of the color shift, guided by the input's Lab; "
        "0 turns it off (exact histogram, possible banding)")
    luminance: bool = Field(True, description="also transfer L* (1-D optimal transport); "
                            "false transfers chrominance only")
    resplit: float = Field(
        DEFAULT_RESPLIT, ge=0, le=1, description="split mode: fraction of the second split "
        "(filtered colours to the target's histogram) that is applied, after a guided "
        "filter of radius 1 cell; 1 (default): the target's histogram up to the binning")
    luminance_slope: float = Field(
        DEFAULT_LUMINANCE_SLOPE, ge=0, le=1000, description="split mode: contrast limit c >= 1 "
        "of the L* map (its slope kept within [1/c, c] times its mean slope, which keeps the "
        "input's local contrast); 0: no limit, the exact 1-D optimal map")
    sharpen: bool = Field(False, description="entropic sharpening of the barycenters")
    debiased: bool = Field(False, description="debiased barycenters (less entropic blur)")
    recolor: list[Int] | None = Field(None, description="indices of the images to recolor "
                                      "(default all)")
    format: Literal["png", "jpeg"] = Field("png", description="format of the output images")
    tol: float = Field(1e-4, gt=0, lt=1, description="largest L1 marginal violation")
    max_iter: Int = Field(3000, ge=1, le=100_000)

    @field_validator("luminance_slope")
    @classmethod
    def _slope(cls, v: float) -> float:
        if 0 < v < 1:
            raise ValueError("must be 0 (exact map) or at least 1")
        return v


class ColorOutputInfo(BaseModel):
    file: str
    alpha_index: Int
    image_index: Int
    width: Int
    height: Int
    mean_ab_before: list[float]
    mean_ab_after: list[float]


class ColorPlanInfo(BaseModel):
    image_index: int
    target: str = Field(description="index of the target image, or b<k> for barycenter k")
    cost: float = Field(description="squared W2 of the plan (ab units²)")
    residual: float = Field(description="L1 violation of the plan's marginals")
    converged: bool


class ColorTransferValues(BaseModel):
    """``values`` of a color-transfer result."""

    n_images: Int
    alphas: list[list[float]]
    mode: str
    regularization: float
    bins: Int
    gamma: float
    iterations: Int = Field(description="iterations of the entropic barycenter (0 if none ran)")
    residual: float = Field(description="largest L1 marginal violation over all plans")
    plans: list[ColorPlanInfo] = Field(description="split mode: the exact plans used")
    converged: bool
    window: list[list[Int]] = Field(description="[[a_start, a_stop], [b_start, b_stop]]: "
                                    "grid nodes the barycenter was computed on")
    timings: dict[str, float]
    outputs: list[ColorOutputInfo]
    barycenter_pictures: list[str]
    histogram_pictures: list[str] = Field(description="histogram-{i}.png: input i's ab "
                                          "histogram; histogram-{b}-{i}.png: output's")
    arrays: list[str]


def _alphas(req: ColorTransferRequest) -> np.ndarray:
    k = len(req.images)
    if req.weights is not None and req.alphas is not None:
        raise InvalidInput("give weights or alphas, not both", field="alphas")
    if req.alphas is not None:
        return check_alphas(req.alphas, k)
    if req.weights is not None:
        try:
            return check_alphas(req.weights, k)
        except Exception as exc:
            raise InvalidInput(str(exc).replace("alphas[0]: ", ""), field="weights") from exc
    return check_alphas(None, k)


def _recolor(req: ColorTransferRequest) -> list[int] | None:
    if req.recolor is None:
        return None
    bad = [i for i in req.recolor if not 0 <= i < len(req.images)]
    if bad or not req.recolor:
        raise InvalidInput(f"recolor indices must lie in [0, {len(req.images)})",
                           field="recolor")
    return sorted(set(req.recolor))


def check_header(data: bytes, field: str, settings):
    """Decode the header only and enforce the per-image pixel limit (413 beyond); files that
    are not images are 422 naming ``field``."""
    info = probe_image(data, field)
    if info.pixels > settings.color_max_pixels:
        raise PayloadTooLarge(f"{field} has {info.pixels} pixels, more than the limit of "
                              f"{settings.color_max_pixels}", field=field)
    return info


def validate(ctx, req: ColorTransferRequest) -> list[dict]:
    A = _alphas(req)
    resolve_gamma(req.gamma, resolve_bins(req.bins, req.mode))
    _recolor(req)
    blobs = [ctx.blob(blob_id, f"images[{i}]") for i, blob_id in enumerate(req.images)]
    total = 0
    for i, data in enumerate(blobs):
        total += check_header(data, f"images[{i}]", ctx.settings).pixels
    if total > ctx.settings.color_max_job_pixels:
        raise PayloadTooLarge(f"the images hold {total} pixels, more than the limit of "
                              f"{ctx.settings.color_max_job_pixels} per job", field="images")
    for i, data in enumerate(blobs):
        read_image(data, f"images[{i}]")  # decodes completely: truncated files fail here
    return [{"alphas": A.tolist()}]


def exact_if_zero(slope: float) -> float:
    """``luminance_slope`` of a request: 0 asks for the exact map (no limit)."""
    return float("inf") if slope == 0 else slope


def run(ctx, req: ColorTransferRequest, progress, should_cancel) -> OperationOutput:
    images = [read_image(ctx.blob(b, f"images[{i}]"), f"images[{i}]")
              for i, b in enumerate(req.images)]
    A = _alphas(req)
    r = color_transfer(images, A, mode=req.mode, bins=req.bins, gamma=req.gamma,
                       luminance=req.luminance, regularization=req.regularization,
                       luminance_slope=exact_if_zero(req.luminance_slope),
                       resplit=req.resplit,
                       sharpen=req.sharpen, debiased=req.debiased, recolor=_recolor(req),
                       tol=req.tol, max_iter=req.max_iter, progress=progress,
                       should_cancel=should_cancel)
    files: dict[str, ResultFile] = {}
    outputs = []
    pictures = []

    def picture(name, masses):
        files[name] = ResultFile("image/png", write_image(histogram_picture(masses)))
        pictures.append(name)

    for i in range(len(images)):
        picture(f"histogram-{i}.png", r.histograms[i])
    before = [rgb_to_lab(img)[..., 1:].reshape(-1, 2).mean(axis=0) for img in images]
    for b in range(A.shape[0]):
        for i, out in enumerate(r.images[b]):
            if out is None:
                continue
            name = f"image-{b}-{i}.{EXT[req.format]}"
            files[name] = ResultFile(MEDIA[req.format], write_image(out, req.format))
            ab = rgb_to_lab(out)[..., 1:]
            after = ab.reshape(-1, 2).mean(axis=0)
            picture(f"histogram-{b}-{i}.png", ab_histogram(ab, r.bins))
            outputs.append(ColorOutputInfo(
                file=name, alpha_index=b, image_index=i, width=int(out.shape[1]),
                height=int(out.shape[0]), mean_ab_before=[float(x) for x in before[i]],
                mean_ab_after=[float(x) for x in after]).model_dump())
        pic = f"barycenter-{b}.png"
        files[pic] = ResultFile("image/png", write_image(histogram_picture(r.barycenters[b])))
    rows, cols = r.window
    plans = [ColorPlanInfo(image_index=int(i), target=str(t), cost=p.cost,
                           residual=p.residual, converged=p.converged).model_dump()
             for (i, t), p in r.plans.items()]
    values = ColorTransferValues(
        n_images=len(images), alphas=A.tolist(), mode=r.mode,
        regularization=r.regularization, bins=r.bins, gamma=r.gamma,
        iterations=r.iterations, residual=r.residual, converged=r.converged, plans=plans,
        window=[[int(rows.start), int(rows.stop)], [int(cols.start), int(cols.stop)]],
        timings={k: float(v) for k, v in r.timings.items()}, outputs=outputs,
        barycenter_pictures=[f"barycenter-{b}.png" for b in range(A.shape[0])],
        histogram_pictures=pictures,
        arrays=["histograms", "barycenters"]).model_dump()
    arrays = {"histograms": r.histograms.reshape(len(images), -1).astype(np.float32),
              "barycenters": r.barycenters.reshape(A.shape[0], -1).astype(np.float32)}
    return OperationOutput(values=values, arrays=arrays, files=files)


def _job_sizes(ctx, req: ColorTransferRequest) -> tuple[int, int, int]:
    """(ab grid nodes per axis, pixels over every image, largest product of two images'
    histogram supports: at most bins^2 or the image's pixels each) of a request."""
    bins = resolve_bins(req.bins, req.mode)
    each = sorted(check_header(ctx.blob(b, f"images[{i}]"), f"images[{i}]",
                               ctx.settings).pixels for i, b in enumerate(req.images))
    supports = [min(bins * bins, p) for p in each[-2:]]
    return bins, sum(each), supports[0] * supports[-1]


def estimate_bytes(ctx, req: ColorTransferRequest) -> int:
    """Per pixel ~440 bytes (Lab planes, guided filter, outputs); the split mode's exact
    plan between two histograms' supports (float64), the barycentric mode's ~12 float64
    per grid node and histogram (measured: bench/results/operation_memory.md)."""
    bins, pixels, plan = _job_sizes(ctx, req)
    grid = 8 * plan if req.mode == "split" else 8 * 12 * bins**2 * (len(req.images) + 1)
    return 440 * pixels + grid


def estimate_cost(n: int, req: ColorTransferRequest, context=None) -> float:
    """Per pixel ~100 cost units; the split mode's plans ~3 per entry, the barycentric
    mode's grid x iterations x histograms (measured: bench/results/operation_memory.md)."""
    if context is None:
        return float(n)
    bins, pixels, plan = _job_sizes(context, req)
    grid = (3.0 * plan if req.mode == "split"
            else float(bins**2) * req.max_iter * (len(req.images) + 1))
    return 100.0 * pixels + grid


class _WarmContext:
    """What ``run`` reads of a job's context: the images' bytes by blob id."""

    def __init__(self, blobs: dict[str, bytes]):
        self.blobs = blobs

    def blob(self, blob_id: str, field: str) -> bytes:
        return self.blobs[blob_id]


def warm() -> None:
    """A job's run on two tiny images in each mode, 8-bit (PNG) and 16-bit (TIFF): kernels
    are compiled per pixel type. It compiles (or loads from numba's cache) the kernels a
    first color transfer needs."""
    y, x = np.mgrid[0:24, 0:32]
    pictures = (np.stack([200 + 0 * x, 60 + x, 40 + y], -1),
                np.stack([30 + 0 * x, 80 + y, 150 + x], -1))
    for dtype, scale, fmt in ((np.uint8, 1, "png"), (np.uint16, 257, "tiff")):
        ctx = _WarmContext({f"{i:032x}": write_image((p * scale).astype(dtype), fmt)
                            for i, p in enumerate(pictures)})
        for mode in ("split", "barycentric"):
            req = ColorTransferRequest(images=list(ctx.blobs), mode=mode, bins=16)
            run(ctx, req, lambda *progress: None, lambda: False)
        # a split onto one input exactly (alphas [[0, 1]]) remaps within the nodes too
        req = ColorTransferRequest(images=list(ctx.blobs), alphas=[[0.0, 1.0]], bins=16)
        run(ctx, req, lambda *progress: None, lambda: False)


OPERATIONS = [
    Operation(
        name="color-transfers",
        operation_id="createColorTransfer",
        summary="Color transfer between 2-16 uploaded images by optimal transport of their "
                "chrominance histograms (exact split plans, or the thesis' barycentric "
                "map, §3.7)",
        request_model=ColorTransferRequest,
        run=run,
        validate=validate,
        scope="global",
        route=False,
        result_model=ColorTransferValues,
        estimate_bytes=estimate_bytes,
        estimate_cost=estimate_cost,
        warm=warm,
    ),
]
