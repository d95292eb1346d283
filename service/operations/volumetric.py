"""Volumetric earth mover's distances and descent paths inside closed meshes (thesis §2.6).

``POST /v1/domains/{id}/volumetric-distances``: the W1 distance between points of space,
each represented on the closed boundary by its mean value coordinates
(:func:`solvers.emd.volumetric_distances`), from a ``source`` to listed ``points`` and/or to
the nodes of a planar ``slice`` through the mesh's bounding box.  Results: distances (and
Euclidean distances, a lower bound), ``slice.png`` (the slice colored by distance, the
outside of the surface faded) and ``result.glb`` (the surface, translucent, and the slice
as a colored plane).

``POST /v1/domains/{id}/volumetric-paths``: gradient descent of the volumetric distance to a
``target`` (:func:`solvers.emd.volumetric_path`); ``result.glb`` draws the path as lines
inside the translucent surface, ``path.png`` over the mesh's silhouette.

Points are in the stored unit-area frame (``units="mesh"``, the default) or in the uploaded
file's coordinates (``units="input"``); distances are in unit-area units either way.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.errors import InvalidInput, UnsupportedOperation
from service.operations.anisotropy import IPM_SOLVE_COST
from service.operations.base import (
    REQUEST_CONFIG,
    DomainView,
    Int,
    Operation,
    OperationOutput,
    OperationRequest,
    ResultFile,
    given,
)
from service.schemas import Point
from solvers.emd.exact import MAX_VERTICES

MAX_POINTS = 4096  # W1 solves of one job (listed points + slice nodes)
MVC_CHUNK_ENTRIES = 4_000_000  # points x faces of one block of mean value coordinates
MVC_TEMPORARIES = 30  # (points, faces) float64 temporaries of a block

Point3 = Point  # (x, y, z)


def _point_field(description: str):
    return Field(min_length=3, max_length=3, description=description)


class VolumetricOptions(OperationRequest):
    units: Literal["mesh", "input"] = Field(
        "mesh", description="coordinates of the points: the stored unit-area frame, or the "
        "uploaded file's")
    method: Literal["exact", "admm"] = Field(
        "exact", description="W1 solver of each distance: exact (conic program over all "
        f"flows, meshes up to {MAX_VERTICES} vertices) or admm (all flows, looser)")
    tol: float | None = Field(None, gt=0, lt=1, description="solver tolerance (default: the "
                              "solver's)")


class SlicePlane(BaseModel):
    """A plane through the mesh's bounding box, sampled on a regular grid."""

    model_config = REQUEST_CONFIG
    axis: Literal["x", "y", "z"] = Field("z", description="the plane's normal axis")
    offset: float = Field(0.5, ge=0, le=1, description="position along the axis, as a "
                          "fraction of the bounding box")
    resolution: Int = Field(24, ge=2, le=64, description="grid nodes along the longer side "
                            "of the slice")
    margin: float = Field(0.05, ge=0, le=1, description="box padding, as a fraction of its "
                          "size")


class VolumetricDistanceRequest(VolumetricOptions):
    model_config = ConfigDict(json_schema_extra={"examples": [
        {"source": [0.0, 0.0, 0.0], "points": [[0.1, 0.0, 0.0], [0.0, 0.2, 0.0]],
         "slice": {"axis": "z", "offset": 0.5, "resolution": 6}}],
        **given("points", "slice", exactly=False)})
    source: Point3 = _point_field("the source point (inside or outside the surface)")
    points: list[Point3] | None = Field(None, min_length=1, max_length=MAX_POINTS,
                                        description="points to measure the distance to")
    slice: SlicePlane | None = Field(None, description="a planar slice of distances "
                                     "(slice.png, result.glb)")


class VolumetricPathRequest(VolumetricOptions):
    model_config = ConfigDict(json_schema_extra={"examples": [
        {"start": [0.2, 0.0, 0.0], "target": [-0.2, 0.0, 0.0], "max_iter": 50}]})
    start: Point3 = _point_field("where the descent starts")
    target: Point3 = _point_field("the point whose distance is descended")
    step: float | None = Field(None, gt=0, description="step length in the request's units "
                               "(default: the mean edge length)")
    max_iter: Int = Field(100, ge=1, le=1000, description="steps at most")


class VolumetricSliceValues(BaseModel):
    """Where the slice of a volumetric-distance job lies, and its range."""

    axis: Literal["x", "y", "z"]
    coordinate: float = Field(description="the plane's coordinate along its axis (request "
                              "units)")
    shape: list[Int] = Field(description="[rows, columns] of the arrays slice_distances and "
                             "slice_inside")
    bounds: list[list[float]] = Field(description="[[lo, hi] of the row axis, [lo, hi] of "
                                      "the column axis] (request units)")
    axes: list[Literal["x", "y", "z"]] = Field(description="[row axis, column axis]")
    min: float
    max: float
    inside_fraction: float = Field(description="fraction of the slice nodes inside the "
                                   "surface (winding number > 1/2)")
    image: str = Field("slice.png", description="result file: the slice colored by distance")


class VolumetricDistanceValues(BaseModel):
    """Values of a volumetric-distance job (distances in unit-area units)."""

    source: list[float]
    units: Literal["mesh", "input"]
    method: Literal["exact", "admm"]
    distances: list[float] | None = Field(None, description="to each of `points`")
    euclidean: list[float] | None = Field(None, description="|source - point| in unit-area "
                                          "units: a lower bound of each distance")
    min_ratio: float | None = Field(None, description="smallest distance / euclidean over "
                                    "the points and slice nodes away from the source "
                                    "(>= 1 up to the solver's tolerance)")
    slice: VolumetricSliceValues | None = None
    solves: Int = Field(description="W1 problems solved")
    iterations: Int = Field(description="solver iterations, summed")
    residual: float = Field(description="largest solver residual")
    converged: bool


class VolumetricPathValues(BaseModel):
    """Values of a volumetric-path job."""

    units: Literal["mesh", "input"]
    method: Literal["exact", "admm"]
    steps: Int = Field(description="points of the path, start and end included")
    length: float = Field(description="polyline length (request units)")
    straight: float = Field(description="|start - target| (request units)")
    start_distance: float = Field(description="volumetric distance at the start")
    final_distance: float = Field(description="volumetric distance at the last point (0 at "
                                  "the target)")
    decreasing: bool = Field(description="the distance fell at every step")
    iterations: Int
    residual: float = Field(description="the final distance")
    converged: bool = Field(description="the target was reached within one step")
    image: str = Field("path.png", description="result file: the path over the mesh's "
                       "silhouette")


# -- validation -------------------------------------------------------------------------
FAR = 100.0  # points farther than this many bounding-box diagonals are refused


def _check_near(view: DomainView, points, field: str, units: str) -> None:
    """Points within ``FAR`` bounding-box diagonals of the mesh (mean value coordinates of
    farther points lose their precision)."""
    if view.points is None or (units == "input" and "length_scale" not in view.summary):
        return  # (a worker's view: checked at submission)
    scale = float(view.summary["length_scale"]) if units == "input" else 1.0
    lo, hi = view.points.min(axis=0), view.points.max(axis=0)
    center, diag = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3) / scale
    far = np.flatnonzero(np.linalg.norm(p - center, axis=1) > FAR * diag)
    if len(far):
        raise InvalidInput(f"{field} lies more than {FAR:g} mesh sizes away from the mesh",
                           field=field)


def _check_closed(view: DomainView, req: VolumetricOptions) -> None:
    if not view.summary.get("closed", True):
        raise UnsupportedOperation("volumetric distances need a closed (watertight) mesh: "
                                   "mean value coordinates live on a closed surface",
                                   field="domain_id")
    if req.method == "exact" and view.n > MAX_VERTICES:
        raise InvalidInput(f"method 'exact' handles meshes up to {MAX_VERTICES} vertices "
                           f"(this one has {view.n}); use method 'admm'", field="method")


def _slice_shape(spec: SlicePlane, extent: np.ndarray) -> tuple[int, int, int, int]:
    """(axis, row axis, column axis, ...) and the grid shape of a slice of ``extent``."""
    axis = "xyz".index(spec.axis)
    rows, cols = [a for a in range(3) if a != axis]
    longest = max(float(extent[rows]), float(extent[cols]), 1e-300)
    shape = tuple(max(2, int(round(spec.resolution * float(extent[a]) / longest)))
                  for a in (rows, cols))
    return axis, rows, cols, shape


def _slice_points(view: DomainView, spec: SlicePlane, scale: float):
    """Slice nodes (mesh frame), the grid shape and its bounds (request units)."""
    lo, hi = view.points.min(axis=0), view.points.max(axis=0)
    pad = spec.margin * (hi - lo)
    lo, hi = lo - pad, hi + pad
    axis, rows, cols, shape = _slice_shape(spec, hi - lo)
    r = np.linspace(lo[rows], hi[rows], shape[0])
    c = np.linspace(lo[cols], hi[cols], shape[1])
    pts = np.empty((shape[0] * shape[1], 3))
    rr, cc = np.meshgrid(r, c, indexing="ij")
    pts[:, rows], pts[:, cols] = rr.ravel(), cc.ravel()
    pts[:, axis] = lo[axis] + spec.offset * (hi[axis] - lo[axis])
    bounds = [[float(r[0]) * scale, float(r[-1]) * scale], [float(c[0]) * scale,
                                                           float(c[-1]) * scale]]
    return pts, shape, bounds, float(pts[0, axis]) * scale, ("xyz"[rows], "xyz"[cols])


def _slice_size(view: DomainView, spec: SlicePlane | None) -> int:
    if spec is None:
        return 0
    return int(np.prod(_slice_shape(spec, np.ptp(view.points, axis=0))[3]))


def validate_distances(view: DomainView, req: VolumetricDistanceRequest) -> list[dict]:
    _check_closed(view, req)
    _check_near(view, req.source, "source", req.units)
    if req.points is not None:
        _check_near(view, req.points, "points", req.units)
    if req.points is None and req.slice is None:
        raise InvalidInput("give points, a slice or both", field="points")
    total = len(req.points or ()) + _slice_size(view, req.slice)
    if total > MAX_POINTS:
        raise InvalidInput(f"{total} points (listed and slice nodes) exceed {MAX_POINTS}; use "
                           "a coarser slice or fewer points", field="slice")
    return []


def validate_path(view: DomainView, req: VolumetricPathRequest) -> list[dict]:
    _check_closed(view, req)
    _check_near(view, req.start, "start", req.units)
    _check_near(view, req.target, "target", req.units)
    return []


def _solves(view_n: int, req) -> int:
    if isinstance(req, VolumetricPathRequest):
        return int(req.max_iter) + 1
    slice_nodes = 0 if req.slice is None else req.slice.resolution ** 2
    return len(req.points or ()) + slice_nodes


def estimate_cost(n: int, req, context=None) -> float:
    """Each point (or path step) is one W1 problem on the mesh."""
    return float(IPM_SOLVE_COST) * float(max(n, 1)) * float(_solves(n, req))


def estimate_bytes(view: DomainView, req) -> int:
    """Mean value coordinates of every point (P x V, twice) plus the temporaries of one
    block of them (at most ``MVC_CHUNK_ENTRIES`` points x faces), and the conic program of
    one solve (``CONIC_FLOATS_PER_FACE``)."""
    n, faces = int(view.n), view.faces_or_typical
    points = 7 if isinstance(req, VolumetricPathRequest) else _solves(n, req)
    block = min(points * faces, MVC_CHUNK_ENTRIES)
    return 16 * points * n + 8 * MVC_TEMPORARIES * block + CONIC_FLOATS_PER_FACE * 8 * faces


# the conic program of one W1 solve, per face (measured with the coupled W1 barycenter:
# bench/results/operation_memory.md; 40 missed a third of a path's working memory)
CONIC_FLOATS_PER_FACE = 200


# -- run --------------------------------------------------------------------------------
def _srgb(linear: np.ndarray) -> np.ndarray:
    return np.where(linear <= 0.0031308, 12.92 * linear,
                    1.055 * np.power(np.clip(linear, 0, None), 1 / 2.4) - 0.055)


def _slice_png(distances: np.ndarray, inside: np.ndarray, pixels: int = 320) -> bytes:
    """The slice colored by distance (rows upwards), the outside of the surface faded."""
    from service.export import colormap
    from solvers.convolutional.brdf import png_bytes

    rgb = _srgb(colormap(distances.ravel())[:, :3]).reshape(*distances.shape, 3)
    rgb = np.where(inside[..., None], rgb, 0.45 * rgb + 0.55)
    zoom = max(1, pixels // max(distances.shape))
    image = np.kron(rgb[::-1], np.ones((zoom, zoom, 1)))
    return png_bytes(np.clip(255 * image, 0, 255).round())


def _translucent(mesh) -> dict:
    v = mesh.vertices * mesh.length_scale
    return {"name": "surface", "vertices": v, "faces": mesh.faces,
            "colors": np.tile([0.75, 0.75, 0.8, 0.3], (len(v), 1))}


def _slice_part(points_input: np.ndarray, shape, distances: np.ndarray) -> dict:
    rows, cols = shape
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), \
        idx[1:, :-1].ravel()
    return {"name": "slice", "vertices": points_input,
            "faces": np.r_[np.c_[a, b, c], np.c_[a, c, d]], "field": distances.ravel(),
            "field_name": "distance"}


def run_distances(mesh, req: VolumetricDistanceRequest, progress, should_cancel
                  ) -> OperationOutput:
    from service.export import meshes_glb
    from service.operations.base import view_of_domain
    from solvers.emd import volumetric_distances, winding_number

    view = view_of_domain(mesh)
    validate_distances(view, req)
    scale = mesh.length_scale if req.units == "input" else 1.0
    src = np.asarray(req.source, dtype=np.float64) / scale  # mesh frame
    listed = np.asarray(req.points if req.points is not None else np.zeros((0, 3))) / scale
    grid = None
    if req.slice is not None:
        grid = _slice_points(view, req.slice, scale)
    pts = listed if grid is None else np.vstack([listed, grid[0]])
    res = volumetric_distances(mesh, src, pts, method=req.method, tol=req.tol,
                               progress=progress, should_cancel=should_cancel)
    d = np.asarray(res.distances, dtype=np.float64)
    euclid = np.linalg.norm(pts - src, axis=1)
    away = euclid > 1e-9
    values = {"source": list(req.source), "units": req.units, "method": req.method,
              "min_ratio": float(np.min(d[away] / euclid[away])) if away.any() else None,
              "solves": int(len(pts)), "iterations": int(res.iterations),
              "residual": float(res.residual), "converged": bool(res.converged)}
    arrays, files = {"points": pts * scale, "distances": d}, {}
    if req.points is not None:
        values.update(distances=d[:len(listed)].tolist(), euclidean=euclid[:len(listed)].tolist())
    if grid is not None:
        nodes, shape, bounds, coordinate, axes = grid
        sd = d[len(listed):].reshape(shape)
        inside = (winding_number(mesh, nodes) > 0.5).reshape(shape)
        values["slice"] = VolumetricSliceValues(
            axis=req.slice.axis, coordinate=coordinate, shape=list(shape), bounds=bounds,
            axes=list(axes), min=float(sd.min()), max=float(sd.max()),
            inside_fraction=float(inside.mean())).model_dump()
        arrays.update(slice_distances=sd, slice_inside=inside.astype(np.int8))
        files["slice.png"] = ResultFile("image/png", _slice_png(sd, inside))
        parts = [_translucent(mesh), _slice_part(nodes * mesh.length_scale, shape, sd)]
        files["result.glb"] = ResultFile("model/gltf-binary", meshes_glb(
            parts, metadata={"operation": "volumetric-distances",
                             "slice": "plane colored by distance"}))
    values = VolumetricDistanceValues(**values).model_dump()
    return OperationOutput(values=values, arrays=arrays, files=files)


def _path_png(mesh, path: np.ndarray, pixels: int = 320) -> bytes:
    """The path (red; start green, target blue) over the mesh's silhouette (grey), seen
    along the mesh's shortest bounding-box axis, rows upwards."""
    from solvers.convolutional.brdf import png_bytes

    v = mesh.vertices
    drop = int(np.argmin(np.ptp(v, axis=0)))
    axes = [a for a in range(3) if a != drop]
    lo, hi = v[:, axes].min(axis=0), v[:, axes].max(axis=0)
    box = (hi - lo) + 0.1 * float(max(hi - lo))  # a margin around the mesh
    lo = 0.5 * (lo + hi) - 0.5 * box
    per_unit = (pixels - 1) / float(max(box))
    size = np.maximum(np.ceil(box * per_unit).astype(int) + 1, 2)

    def pix(points):
        ij = np.clip(np.rint((points[:, axes] - lo) * per_unit).astype(int), 0, size - 1)
        return size[1] - 1 - ij[:, 1], ij[:, 0]

    image = np.ones((size[1], size[0], 3))
    # the silhouette: faces below two pixels as their corners and centroid, larger ones
    # filled (at most image area / 4 of them)
    from skimage.draw import polygon

    f = v[mesh.faces]
    large = np.ptp(f[..., axes], axis=1).max(axis=1) * per_unit >= 2.0
    image[pix(np.concatenate([f[~large].reshape(-1, 3), f[~large].mean(axis=1)]))] = 0.82
    for tri in f[large]:
        r, c = pix(tri)
        image[polygon(r, c, shape=image.shape[:2])] = 0.82
    t = np.linspace(0.0, 1.0, 64)[:, None, None]
    segments = (path[:-1][None] * (1 - t) + path[1:][None] * t).reshape(-1, 3)
    r, c = pix(segments)
    for di in (-1, 0, 1):  # a 3-pixel wide line
        for dj in (-1, 0, 1):
            image[np.clip(r + di, 0, size[1] - 1), np.clip(c + dj, 0, size[0] - 1)] = (
                0.85, 0.1, 0.1)
    for point, color in ((path[0], (0.1, 0.6, 0.1)), (path[-1], (0.1, 0.2, 0.85))):
        r, c = pix(point[None])
        image[max(r[0] - 3, 0):r[0] + 4, max(c[0] - 3, 0):c[0] + 4] = color
    return png_bytes(np.clip(255 * image, 0, 255).round())


def run_path(mesh, req: VolumetricPathRequest, progress, should_cancel) -> OperationOutput:
    from service.export import meshes_glb
    from service.operations.base import view_of_domain
    from solvers.emd import volumetric_path

    validate_path(view_of_domain(mesh), req)
    res = volumetric_path(mesh, req.start, req.target, step=req.step, max_iter=req.max_iter,
                          method=req.method, units=req.units, tol=req.tol,
                          progress=progress, should_cancel=should_cancel)
    scale = mesh.length_scale if req.units == "input" else 1.0
    P = np.asarray(res.points) * scale  # request units
    d = np.asarray(res.distances, dtype=np.float64)
    values = VolumetricPathValues(
        units=req.units, method=req.method, steps=int(len(P)),
        length=float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum()),
        straight=float(np.linalg.norm(np.subtract(req.target, req.start))),
        start_distance=float(d[0]), final_distance=float(d[-1]),
        decreasing=bool(np.all(np.diff(d) < 0)), iterations=int(res.iterations),
        residual=float(res.residual), converged=bool(res.converged)).model_dump()
    path = P / scale * mesh.length_scale  # the GLB in input units, like other exports
    part = {**_translucent(mesh), "lines": np.stack([path[:-1], path[1:]], axis=1)}
    glb = meshes_glb([part], metadata={"operation": "volumetric-paths",
                                       "path": "surface lines"})
    files = {"result.glb": ResultFile("model/gltf-binary", glb),
             "path.png": ResultFile("image/png", _path_png(mesh, np.asarray(res.points)))}
    return OperationOutput(values=values, arrays={"points": P, "distances": d}, files=files)


FACES = "faces"  # what these operations require of a domain (Domain.supports)
OPERATIONS = [
    Operation("volumetric-distances", "createVolumetricDistanceJob",
              "Volumetric W1 distances inside a closed mesh from a source point to points or "
              "a planar slice (thesis §2.6): values, slice.png, GLB",
              VolumetricDistanceRequest, run_distances, validate_distances, FACES,
              result_model=VolumetricDistanceValues, estimate_bytes=estimate_bytes,
              estimate_cost=estimate_cost),
    Operation("volumetric-paths", "createVolumetricPathJob",
              "Descent path of the volumetric W1 distance towards a target point (thesis "
              "§2.6): points and a GLB",
              VolumetricPathRequest, run_path, validate_path, FACES,
              result_model=VolumetricPathValues, estimate_bytes=estimate_bytes,
              estimate_cost=estimate_cost),
]
