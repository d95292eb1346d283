"""3-D shape interpolation of uploaded meshes (thesis §3.7): ``POST /v1/shape-interpolations``.

Two or more closed mesh domains are voxelized onto one grid framing them all; every frame is
the convolutional Wasserstein barycenter of their indicator volumes for one weight vector,
and its surface the iso-surface enclosing the interpolated volume
(:func:`solvers.convolutional.shapes.shape_interpolations`).  With two shapes the frames are
``times`` (weights ``(1 - t, t)``); with more, ``weights`` rows.  Results: per-frame values,
``result.glb`` with one node (mesh) per frame, side by side in the shapes' input
coordinates, and ``frames.png`` (each frame's surface, depth-shaded, seen along
``view_axis``).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.errors import InvalidInput, PayloadTooLarge, UnsupportedOperation
from service.operations.base import (
    Int,
    Operation,
    OperationOutput,
    OperationRequest,
    ResultFile,
    rules,
)
from service.operations.examples import EXAMPLE_ID
from service.schemas import DomainId

MAX_SHAPES = 8
MAX_FRAMES = 16
DEFAULT_TIMES = [0.0, 0.25, 0.5, 0.75, 1.0]
VOLUME_ARRAYS = 24  # grid-sized float64 arrays of one job: inputs, barycenter scalings, ...
# cost units (see service.operations.cost.estimate_cost) per grid node, iteration and shape: the
# grid's separable Gaussian is ~10x cheaper than a mesh kernel's triangular solves (measured
# ~25 ns per node, iteration and shape at 64^3)
GRID_NODE_COST = 0.1


class ShapeInterpolationRequest(OperationRequest):
    model_config = ConfigDict(json_schema_extra={"examples": [
        {"shapes": [EXAMPLE_ID, EXAMPLE_ID], "times": [0.0, 0.5, 1.0], "resolution": 16}],
        **rules(({"times": {"not": {"type": "null"}}},  # times: two shapes, no weights
                 {"properties": {"shapes": {"maxItems": 2}, "weights": {"type": "null"}}}))})
    shapes: list[DomainId] = Field(min_length=2, max_length=MAX_SHAPES, description="closed mesh "
                              "domain ids (voxelized in their uploaded coordinates)")
    times: list[float] | None = Field(None, min_length=1, max_length=MAX_FRAMES,
                                      description="two shapes: frame times t in [0, 1] "
                                      "(weights (1 - t, t)); default 0, 1/4, ..., 1")
    weights: list[list[float]] | None = Field(None, min_length=1, max_length=MAX_FRAMES,
                                              description="one weight vector per frame, one "
                                              "non-negative weight per shape (normalized); "
                                              "default with more than two shapes: each "
                                              "shape, then the uniform barycenter")
    resolution: Int = Field(40, ge=12, le=96, description="grid nodes along the longest "
                            "side of the box framing every shape")
    gamma: float | None = Field(None, gt=0, le=1, description="regularization on the grid "
                                "(longest side 1); default (2h)^2, h the grid spacing")
    sharpen: bool = Field(False, description="entropic sharpening (thesis Alg. 3)")
    tol: float = Field(1e-5, gt=0, lt=1, description="barycenter stopping tolerance")
    max_iter: Int | None = Field(None, ge=1, le=20_000, description="barycenter iterations "
                                 "per frame (default: the solver's)")
    view_axis: Literal["x", "y", "z"] = Field("z", description="frames.png looks along it")


class ShapeFrameValues(BaseModel):
    """One frame of a shape interpolation."""

    weights: list[float]
    time: float | None = Field(None, description="two shapes: t of weights (1 - t, t)")
    vertices: Int
    faces: Int
    level: float = Field(description="iso value of the barycenter density")
    target_volume: float = Field(description="sum_i w_i |S_i| (input units)")
    enclosed_volume: float = Field(description="volume enclosed by the frame's surface")
    centroid: list[float] = Field(description="centroid of the enclosed solid (input units)")
    iterations: Int
    residual: float
    converged: bool


class ShapeInterpolationValues(BaseModel):
    """Values of a shape-interpolation job."""

    frames: list[ShapeFrameValues]
    grid: list[Int] = Field(description="grid shape")
    gamma: float
    cell: float = Field(description="grid spacing in input units")
    iterations: Int = Field(description="summed over the frames")
    residual: float = Field(description="largest over the frames")
    converged: bool
    glb: str = Field("result.glb", description="one node (mesh) per frame")
    image: str = Field("frames.png", description="result file: the frames, depth-shaded")


def _frame_weights(req: ShapeInterpolationRequest) -> tuple[np.ndarray, list | None]:
    k = len(req.shapes)
    if req.times is not None and req.weights is not None:
        raise InvalidInput("give times or weights, not both", field="weights")
    if req.times is not None:
        if k != 2:
            raise InvalidInput("times need exactly two shapes; give weights", field="times")
        for i, t in enumerate(req.times):
            if not 0.0 <= t <= 1.0:
                raise InvalidInput(f"times[{i}] = {t} is outside [0, 1]", field=f"times[{i}]")
        return np.array([[1.0 - t, t] for t in req.times]), list(req.times)
    if req.weights is None:
        if k == 2:
            return np.array([[1.0 - t, t] for t in DEFAULT_TIMES]), list(DEFAULT_TIMES)
        return np.vstack([np.eye(k), np.full((1, k), 1.0 / k)]), None
    from solvers.validation import check_weights

    rows = [check_weights(row, k, f"weights[{i}]") for i, row in enumerate(req.weights)]
    return np.asarray(rows), None


def validate(ctx, req: ShapeInterpolationRequest) -> list[dict]:
    for i, shape_id in enumerate(req.shapes):
        view = ctx.view(shape_id, f"shapes[{i}]")
        if not view.supports("faces"):
            raise UnsupportedOperation(f"shapes[{i}] is a {view.kind} domain; shape "
                                       "interpolation needs meshes", field=f"shapes[{i}]")
        if not view.summary.get("closed", False):
            raise UnsupportedOperation(f"shapes[{i}] is not closed: a solid needs a watertight "
                                       "surface to be voxelized", field=f"shapes[{i}]")
    rows, _ = _frame_weights(req)
    if len(rows) > MAX_FRAMES:
        raise InvalidInput(f"at most {MAX_FRAMES} frames", field="weights")
    need = estimate_bytes(req)
    limit = int(ctx.settings.job_memory_bytes)
    if need > limit:
        raise PayloadTooLarge(f"a {req.resolution}^3 grid with {len(req.shapes)} shapes needs "
                              f"about {need / 2**30:.3g} GiB, more than the limit of "
                              f"{limit / 2**30:.3g} GiB: use a lower resolution",
                              field="resolution")
    return []


def estimate_bytes(req: ShapeInterpolationRequest) -> int:
    return 8 * req.resolution**3 * (VOLUME_ARRAYS + len(req.shapes))


def job_bytes(ctx, req: ShapeInterpolationRequest) -> int:
    return estimate_bytes(req)


def estimate_cost(n: int, req: ShapeInterpolationRequest, context=None) -> float:
    """Grid nodes x iterations x shapes x frames x ``GRID_NODE_COST``: one separable
    convolution per shape and iteration; ``n`` (the first shape's vertices) does not enter."""
    frames = len(req.times or req.weights or ([0] * (5 if len(req.shapes) == 2
                                                       else len(req.shapes) + 1)))
    return GRID_NODE_COST * float(req.resolution**3) * float(req.max_iter or 1000) * float(
        len(req.shapes) * frames)


def _picture(results, axis: str) -> bytes:
    """The frames' shaded views in a grid of about square shape, row by row."""
    from solvers.convolutional.brdf import png_bytes
    from solvers.convolutional.shapes import shaded_view

    images = [shaded_view(r.volume, r.level, axis="xyz".index(axis)) for r in results]
    h = max(i.shape[0] for i in images) + 6
    w = max(i.shape[1] for i in images) + 6
    cols = int(np.ceil(np.sqrt(len(images) * h / w)))
    rows = int(np.ceil(len(images) / cols))
    sheet = np.ones((rows * h, cols * w))
    for j, image in enumerate(images):
        r, c = divmod(j, cols)
        sheet[r * h:r * h + image.shape[0], c * w:c * w + image.shape[1]] = image
    return png_bytes(np.repeat(np.clip(255 * sheet, 0, 255).round()[..., None], 3, axis=2))


def run(ctx, req: ShapeInterpolationRequest, progress, should_cancel) -> OperationOutput:
    import trimesh

    from service.export import meshes_glb
    from solvers.convolutional.shapes import shape_interpolations

    rows, times = _frame_weights(req)
    meshes = [ctx.domain(s, f"shapes[{i}]") for i, s in enumerate(req.shapes)]
    results = shape_interpolations(meshes, rows, gamma=req.gamma, resolution=req.resolution,
                                   sharpen=req.sharpen, tol=req.tol, max_iter=req.max_iter,
                                   progress=progress, should_cancel=should_cancel)
    frames, parts = [], []
    width = 1.15 * float(np.ptp(results[0].grid.points[:, 0])) * results[0].scale
    for j, (r, w) in enumerate(zip(results, rows, strict=True)):
        solid = trimesh.Trimesh(r.vertices, r.faces, process=False)
        centroid = solid.center_mass if len(r.faces) and solid.volume > 0 else \
            r.vertices.mean(axis=0)
        label = f"t={times[j]:g}" if times is not None else f"frame {j}"
        frames.append(ShapeFrameValues(
            weights=w.tolist(), time=None if times is None else float(times[j]),
            vertices=int(len(r.vertices)), faces=int(len(r.faces)), level=float(r.level),
            target_volume=float(r.target_volume), enclosed_volume=float(r.enclosed_volume),
            centroid=np.asarray(centroid, dtype=float).tolist(), iterations=int(r.iterations),
            residual=float(r.residual), converged=bool(r.converged)))
        parts.append({"name": label, "vertices": r.vertices, "faces": r.faces,
                      "colors": np.tile([0.8, 0.78, 0.72, 1.0], (len(r.vertices), 1)),
                      "translation": [j * width, 0.0, 0.0]})
    first = results[0]
    values = ShapeInterpolationValues(
        frames=frames, grid=list(first.grid.shape), gamma=float(first.gamma),
        cell=float(first.scale * first.grid.spacing[0]),
        iterations=int(sum(r.iterations for r in results)),
        residual=float(max(r.residual for r in results)),
        converged=all(r.converged for r in results)).model_dump()
    glb = meshes_glb(parts, metadata={"operation": "shape-interpolations",
                                      "frames": [p["name"] for p in parts]})
    arrays = {"weights": rows, "levels": np.array([r.level for r in results]),
              "centroids": np.array([f.centroid for f in frames])}
    files = {"result.glb": ResultFile("model/gltf-binary", glb),
             "frames.png": ResultFile("image/png", _picture(results, req.view_axis))}
    return OperationOutput(values=values, arrays=arrays, files=files)


OPERATIONS = [
    Operation("shape-interpolations", "createShapeInterpolationJob",
              "Interpolate two or more closed meshes as Wasserstein barycenters of their "
              "volumes (thesis §3.7): one mesh per frame in a GLB, and a PNG",
              ShapeInterpolationRequest, run, validate, "faces", scope="global",
              result_model=ShapeInterpolationValues, estimate_cost=estimate_cost,
              estimate_bytes=job_bytes, writes_glb=True),
]
