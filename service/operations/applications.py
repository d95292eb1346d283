"""The §3.7 applications: BRDF interpolation and skeleton layout.

``POST /v1/brdf-interpolations`` (global: no stored domain): 2-4 closed-form materials as
request parameters, barycenters of their slices on a hemisphere grid
(:mod:`solvers.convolutional.brdf`), per incoming direction, for each weight vector.
Results: values (convergence, entropies), arrays ``slices`` / ``linear`` (one row per
``(incoming direction, weight vector)``, row ``i * B + b``; masses on the grid points),
``inputs``, ``directions``, ``areas``, ``scale``; files ``spheres.png`` (a grid of spheres
shaded with the interpolated BRDFs under one light) and ``linear.png`` (the same with the
linear mix, for comparison).

``POST /v1/domains/{id}/skeleton-layouts`` (closed meshes): a skeleton graph and the
positions of some of its nodes inside the surface; the free nodes are placed by
Wasserstein propagation of mean-value-coordinate distributions
(:mod:`solvers.convolutional.skeleton`).  Results: positions (JSON and array), the linear
layout for comparison, winding numbers, and ``result.glb``: the mesh and the skeleton as
lines (the propagated layout, and the linear one beside it).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.errors import InvalidInput, PayloadTooLarge, UnsupportedOperation
from service.operations.base import (
    REQUEST_CONFIG,
    DomainView,
    Int,
    NodePair,
    Operation,
    OperationOutput,
    OperationRequest,
    ResultFile,
    needs,
    rules,
)
from service.operations.examples import example
from solvers.convolutional.hemisphere import EXTENT as HEMISPHERE_EXTENT
from solvers.validation import GAMMA_MIN, gamma_max

MAX_COLUMNS_X_POINTS = 4_000_000  # barycenter columns x hemisphere points of one job
MAX_HEMISPHERE_POINTS = 4096  # dense kernel: 128 MB
# Below every allowed hemisphere grid's point-mass entropy (log of its smallest cell's area
# weight; the lowest, -12.27, on 64 x 64 cells): no entropy bound under it is reachable on
# any grid, so the spec states it; the grid's own bound depends on n_theta and n_phi
ENTROPY_BOUND_MIN = -12.5
MAX_SKELETON_NODES = 10_000


# -- BRDF interpolation -------------------------------------------------------------------
def reflects_light(specular: str, diffuse: str) -> ConfigDict:
    """The request config stating, as the library checks (check_material), that a material's
    coefficients are not all 0 (the diffuse one defaults to 0: a specular 0 needs it)."""
    zero = {"const": 0}
    return ConfigDict(**REQUEST_CONFIG, json_schema_extra={"not": {
        "required": [specular], "properties": {specular: zero, diffuse: zero}}})


class BlinnPhong(BaseModel):
    model_config = reflects_light("ks", "kd")
    model: Literal["blinn-phong"]
    exponent: float = Field(50.0, ge=0, le=1e5, description="specular exponent e")
    ks: float = Field(1.0, ge=0, le=1e3, description="specular coefficient")
    kd: float = Field(0.0, ge=0, le=1e3, description="diffuse coefficient")


class AshikhminShirley(BaseModel):
    model_config = reflects_light("rs", "rd")
    model: Literal["ashikhmin-shirley"]
    nu: float = Field(100.0, ge=0, le=1e5, description="exponent along the tangent u")
    nv: float = Field(100.0, ge=0, le=1e5, description="exponent along v")
    rs: float = Field(0.05, ge=0, le=1, description="specular reflectance at normal incidence")
    rd: float = Field(0.0, ge=0, le=1, description="diffuse reflectance")


Material = Annotated[BlinnPhong | AshikhminShirley, Field(discriminator="model")]


class BRDFInterpolationRequest(OperationRequest):
    model_config = example({
        "materials": [{"model": "blinn-phong", "exponent": 100.0},
                      {"model": "blinn-phong", "exponent": 5.0, "ks": 0.6, "kd": 0.4}],
        "rows": 1, "cols": 3, "incoming_theta": [30.0]},
        **rules(({"materials": {"minItems": 3, "maxItems": 3}}, needs("weights"))))
    materials: list[Material] = Field(min_length=2, max_length=4, description="the corner "
                                      "materials; with 4, bilinear weights over the parameter "
                                      "square (corners (0,0), (0,1), (1,0), (1,1))")
    weights: list[list[float]] | None = Field(None, min_length=1, max_length=256,
                                              description="(B, k) barycentric weights, row-"
                                              "major over rows x cols; default: bilinear "
                                              "(4 materials) or linear (2) over the grid")
    rows: Int = Field(3, ge=1, le=16, description="rows of spheres (B = rows * cols)")
    cols: Int = Field(3, ge=1, le=16, description="columns of spheres")
    incoming_theta: list[Annotated[float, Field(ge=0, lt=90)]] = Field(
        [0.0, 20.0, 40.0, 60.0, 80.0], min_length=1, max_length=32,
        description="polar angles of the incoming directions, degrees in [0, 90), increasing")
    n_theta: Int = Field(12, ge=4, le=64, description="hemisphere grid: polar cells")
    n_phi: Int = Field(48, ge=8, le=256, description="hemisphere grid: azimuth cells")
    method: Literal["geodesic", "separable"] = Field(
        "geodesic", description="hemisphere kernel: exact great-circle Gaussian, or the "
        "thesis' latitude-modulated separable product (spurious mass near the pole)")
    # the hemisphere's extent is fixed, so its domain bound on gamma is part of the spec
    gamma: float | None = Field(None, ge=GAMMA_MIN, le=gamma_max(HEMISPHERE_EXTENT),
                                description="regularization (unit hemisphere area); default "
                                "(2 h)^2, h the polar cell size")
    entropy_bound: Annotated[float, Field(ge=ENTROPY_BOUND_MIN)] | Literal["inputs"] | None = \
        Field(None, description="Alg. 3: a bound H0, or 'inputs' (the largest input entropy "
              "of each incoming direction); null: plain barycenters. At least the entropy of "
              "a point mass on the requested grid (log of its smallest cell's area weight)")
    tol: float = Field(1e-4, gt=0, lt=1, description="largest L1 marginal violation")
    max_iter: Int = Field(500, ge=1, le=20_000)
    size: Int = Field(96, ge=16, le=256, description="pixels per sphere")
    light: list[float] = Field([0.6, 0.5, 0.62], min_length=3, max_length=3,
                               description="direction towards the light (view: +z)")


class BRDFInterpolationValues(BaseModel):
    """Values of a BRDF interpolation job."""

    iterations: Int
    residual: float
    converged: bool
    gamma: float
    method: str
    grid: list[Int] = Field(description="[n_theta, n_phi]; point i * n_phi + j")
    incoming_theta: list[float] = Field(description="degrees")
    weights: list[list[float]]
    entropy: list[list[float]] = Field(description="per incoming direction and weight vector")
    entropy_bound: list[list[float]] | None = None
    peak_theta: list[list[float]] = Field(description="polar angle (degrees) of each "
                                          "interpolated slice's largest density")
    rows: Int
    cols: Int
    image: str = Field("spheres.png", description="result file: the sphere grid")


def _brdf_weights(req: BRDFInterpolationRequest) -> np.ndarray:
    from solvers.convolutional.brdf import bilinear_weights

    k = len(req.materials)
    if req.weights is not None:
        W = np.asarray(req.weights, dtype=np.float64) if all(
            len(r) == k for r in req.weights) else None
        if W is None:
            raise InvalidInput(f"every row of weights needs {k} values", field="weights")
        if len(W) != req.rows * req.cols:
            raise InvalidInput(f"weights has {len(W)} rows, not rows * cols = "
                               f"{req.rows * req.cols}", field="weights")
        return W
    if k == 4:
        return bilinear_weights(req.rows, req.cols)
    if k == 2:
        lam = np.linspace(0.0, 1.0, req.rows * req.cols)
        return np.stack([1.0 - lam, lam], axis=1)
    raise InvalidInput("with 3 materials give the weights", field="weights")


def _brdf_setup(req: BRDFInterpolationRequest):
    from solvers.convolutional.brdf import check_incoming, check_material
    from solvers.convolutional.hemisphere import RADIUS, HemisphereGrid
    from solvers.validation import check_weights

    mats = [check_material(m.model_dump(), f"materials[{i}]")
            for i, m in enumerate(req.materials)]
    W = _brdf_weights(req)
    for b, row in enumerate(W):
        check_weights(row, len(mats), f"weights[{b}]")
    th = check_incoming(np.radians(req.incoming_theta), "incoming_theta")
    if np.degrees(th[-1]) >= 90.0:
        raise InvalidInput("incoming_theta must be below 90 degrees", field="incoming_theta")
    n = req.n_theta * req.n_phi
    if n > MAX_HEMISPHERE_POINTS:
        raise PayloadTooLarge(f"n_theta * n_phi = {n} exceeds {MAX_HEMISPHERE_POINTS} (the "
                              "dense hemisphere kernel holds n^2 floats)", field="n_phi")
    columns = len(th) * len(W) * len(mats)
    if columns * n > MAX_COLUMNS_X_POINTS:
        raise PayloadTooLarge(f"{columns} barycenter columns on {n} hemisphere points exceed "
                              f"{MAX_COLUMNS_X_POINTS}: use fewer incoming directions, "
                              "spheres or cells", field="incoming_theta")
    light = np.asarray(req.light, dtype=np.float64)
    if not np.linalg.norm(light) > 0:
        raise InvalidInput("light must be a non-zero direction", field="light")
    gamma = req.gamma
    if gamma is None:
        gamma = (2.0 * RADIUS * 0.5 * np.pi / req.n_theta) ** 2
    grid = HemisphereGrid(req.n_theta, req.n_phi, method=req.method)
    from solvers.validation import check_gamma

    check_gamma(gamma, grid.extent, "gamma")
    bound = req.entropy_bound
    if bound is not None and bound != "inputs":
        from solvers.validation import check_entropy_bound

        check_entropy_bound(bound, grid.areas, "entropy_bound")
    return grid, mats, W, th, float(gamma)


def validate_brdf(ctx, req: BRDFInterpolationRequest) -> list[dict]:
    _brdf_setup(req)
    return []


def run_brdf(ctx, req: BRDFInterpolationRequest, progress, should_cancel) -> OperationOutput:
    from solvers.convolutional.brdf import (
        interpolate_brdfs,
        peak_direction,
        png_bytes,
        render_spheres,
    )

    grid, mats, W, th, gamma = _brdf_setup(req)
    r = interpolate_brdfs(grid, mats, W, th, gamma=gamma, entropy_bound=req.entropy_bound,
                          tol=req.tol, max_iter=req.max_iter, progress=progress,
                          should_cancel=should_cancel)
    n_in, B = len(th), len(W)
    img = render_spheres(grid, r.masses, r.scale, th, req.rows, req.cols, size=req.size,
                         light=req.light)
    lin = render_spheres(grid, r.linear, r.scale, th, req.rows, req.cols, size=req.size,
                         light=req.light)
    peaks = [[float(np.degrees(peak_direction(grid, r.masses[i, b])[0])) for b in range(B)]
             for i in range(n_in)]
    values = BRDFInterpolationValues(
        iterations=r.iterations, residual=r.residual, converged=r.converged, gamma=gamma,
        method=grid.method, grid=list(grid.shape), incoming_theta=np.degrees(th).tolist(),
        weights=W.tolist(),
        entropy=r.entropy.tolist(),
        entropy_bound=None if r.entropy_bound is None else r.entropy_bound.tolist(),
        peak_theta=peaks, rows=req.rows, cols=req.cols).model_dump()
    arrays = {"slices": r.masses.reshape(n_in * B, grid.n),
              "linear": r.linear.reshape(n_in * B, grid.n),
              "inputs": r.inputs.reshape(n_in * len(mats), grid.n),
              "scale": r.scale, "directions": grid.directions, "areas": grid.areas}
    files = {"spheres.png": ResultFile("image/png", png_bytes(img)),
             "linear.png": ResultFile("image/png", png_bytes(lin))}
    return OperationOutput(values=values, arrays=arrays, files=files)


# -- skeleton layout ----------------------------------------------------------------------
class FixedPosition(BaseModel):
    """A skeleton node whose position is given."""

    model_config = REQUEST_CONFIG
    node: Int = Field(ge=0, description="skeleton node index")
    position: list[float] = Field(min_length=3, max_length=3, description="inside the mesh")


class SkeletonLayoutRequest(OperationRequest):
    model_config = example({
        "n_nodes": 3, "edges": [[0, 1], [1, 2]],
        "fixed": [{"node": 0, "position": [-0.1, 0.0, 0.0]},
                  {"node": 2, "position": [0.1, 0.0, 0.0]}]})
    n_nodes: Int = Field(ge=2, le=MAX_SKELETON_NODES, description="skeleton nodes")
    edges: list[NodePair] = Field(min_length=1, max_length=4 * MAX_SKELETON_NODES,
                                         description="skeleton bones (node pairs)")
    fixed: list[FixedPosition] = Field(min_length=1, max_length=MAX_SKELETON_NODES,
                                   description="nodes with known positions (at least one per "
                                   "piece of the graph)")
    units: Literal["mesh", "input"] = Field("mesh", description="positions in the stored "
                                            "unit-area frame, or in the uploaded file's")
    gamma: float | None = Field(None, ge=GAMMA_MIN, description="propagation regularization (unit "
                                "area); default (2 h)^2, h the mean edge length")
    substeps: Int = Field(1, ge=1, le=100)
    tol: float = Field(1e-5, gt=0, lt=1)
    max_iter: Int = Field(2000, ge=1, le=100_000)


class SkeletonLayoutValues(BaseModel):
    """Values of a skeleton layout job."""

    positions: list[list[float]] = Field(description="(n_nodes, 3), in the request's units")
    linear: list[list[float]] = Field(description="linear interpolation along the graph")
    inside: list[bool] = Field(description="winding number > 1/2 per node")
    linear_inside: list[bool]
    bones_inside: float = Field(description="fraction of points along the bones inside")
    linear_bones_inside: float
    clipped: list[float] = Field(description="per node: negative MVC weight clipped "
                                 "(fraction; 0 at free nodes)")
    iterations: Int
    residual: float
    converged: bool
    gamma: float


def _skeleton_inputs(req: SkeletonLayoutRequest):
    from solvers.convolutional.skeleton import check_skeleton

    fixed = {}
    for i, f in enumerate(req.fixed):
        if f.node in fixed:
            raise InvalidInput(f"fixed[{i}]: node {f.node} appears twice", field="fixed")
        fixed[f.node] = f.position
    check_skeleton(req.n_nodes, [list(e) for e in req.edges], fixed)
    return fixed


def validate_skeleton(view: DomainView, req: SkeletonLayoutRequest) -> list[dict]:
    if view.n_components > 1:
        raise UnsupportedOperation(f"this mesh has {view.n_components} connected components; "
                                   "skeleton layouts need one closed surface",
                                   field="domain_id")
    _skeleton_inputs(req)
    if req.gamma is not None:
        from service.operations.base import check_options

        check_options(view, req)
    return []


def run_skeleton(mesh, req: SkeletonLayoutRequest, progress, should_cancel) -> OperationOutput:
    from service.export import meshes_glb
    from solvers.convolutional.skeleton import segment_inside_fraction, skeleton_layout

    if not mesh.is_closed:
        raise UnsupportedOperation("skeleton layouts need a closed (watertight) mesh",
                                   field="domain_id")
    fixed = _skeleton_inputs(req)
    e = np.asarray(req.edges, dtype=np.int64)
    r = skeleton_layout(mesh, req.n_nodes, e, fixed, gamma=req.gamma, substeps=req.substeps,
                        units=req.units, tol=req.tol, max_iter=req.max_iter,
                        progress=progress, should_cancel=should_cancel)
    scale = mesh.length_scale if req.units == "input" else 1.0
    P, L = r.positions / scale, r.linear / scale  # mesh frame
    values = SkeletonLayoutValues(
        positions=r.positions.tolist(), linear=r.linear.tolist(),
        inside=(r.winding > 0.5).tolist(), linear_inside=(r.linear_winding > 0.5).tolist(),
        bones_inside=segment_inside_fraction(mesh, P, e),
        linear_bones_inside=segment_inside_fraction(mesh, L, e),
        clipped=r.clipped.tolist(), iterations=r.iterations, residual=r.residual,
        converged=r.converged, gamma=r.gamma).model_dump()
    v = mesh.vertices * mesh.length_scale  # the GLB in input units, like other exports
    shift = [1.2 * float(np.ptp(v[:, 0])), 0.0, 0.0]
    glb = meshes_glb([
        {"name": "mesh", "vertices": v, "faces": mesh.faces,
         "colors": np.tile([0.75, 0.75, 0.8, 0.35], (len(v), 1)),
         "lines": (P * mesh.length_scale)[e]},
        {"name": "linear", "vertices": v, "faces": mesh.faces,
         "colors": np.tile([0.8, 0.75, 0.75, 0.35], (len(v), 1)), "translation": shift,
         "lines": (L * mesh.length_scale)[e]},
    ], metadata={"operation": "skeleton-layouts", "skeleton": "mesh lines",
                 "linear": "second copy"})
    arrays = {"positions": r.positions, "linear": r.linear, "winding": r.winding,
              "linear_winding": r.linear_winding, "masses": r.masses.T.astype(np.float32)}
    return OperationOutput(values=values, arrays=arrays,
                           files={"result.glb": ResultFile("model/gltf-binary", glb)})


def brdf_bytes(ctx, req: BRDFInterpolationRequest) -> int:
    """The dense hemisphere kernel and its temporaries (~6 float64 per point pair), ~12
    vectors per barycenter column, the two rendered sphere grids (RGBA float64)."""
    n, columns = _brdf_sizes(req)
    pixels = req.rows * req.cols * req.size ** 2
    return 8 * 6 * n * n + 8 * 12 * n * columns + 2 * 8 * 4 * pixels


def brdf_cost(n_points: int, req: BRDFInterpolationRequest, context=None) -> float:
    """Dense kernel applications: hemisphere points^2 x barycenter columns x
    ``BRDF_PAIR_COST`` (measured: bench/results/operation_memory.md)."""
    n, columns = _brdf_sizes(req)
    return BRDF_PAIR_COST * float(n) ** 2 * float(columns)


BRDF_PAIR_COST = 4.0


def _brdf_sizes(req: BRDFInterpolationRequest) -> tuple[int, int]:
    """(hemisphere points, barycenter columns) of a request."""
    n = req.n_theta * req.n_phi
    spheres = len(req.weights) if req.weights else req.rows * req.cols
    return n, len(req.incoming_theta) * spheres * len(req.materials)


def skeleton_bytes(view: DomainView, req: SkeletonLayoutRequest) -> int:
    """Per vertex: ~1600 float64 (the mean value coordinates' per-face work and the
    propagation's operators, measured: bench/results/operation_memory.md) and 12 per
    column (a node's distribution, two per edge)."""
    columns = int(req.n_nodes) + 2 * len(req.edges)
    return 8 * int(view.n) * (1600 + 12 * columns)


OPERATIONS = [
    Operation(
        name="brdf-interpolations",
        operation_id="createBrdfInterpolationJob",
        summary="Interpolate closed-form BRDFs by Wasserstein barycenters on the hemisphere "
                "(thesis §3.7, Fig. 3.11): slices and a sphere-grid PNG",
        request_model=BRDFInterpolationRequest,
        run=run_brdf,
        validate=validate_brdf,
        scope="global",
        result_model=BRDFInterpolationValues,
        estimate_bytes=brdf_bytes,
        estimate_cost=brdf_cost,
    ),
    Operation(
        name="skeleton-layouts",
        operation_id="createSkeletonLayoutJob",
        summary="Embed a skeleton graph in a closed mesh by Wasserstein propagation of mean "
                "value coordinates (thesis §3.7, Fig. 3.13)",
        request_model=SkeletonLayoutRequest,
        run=run_skeleton,
        validate=validate_skeleton,
        requires="faces",
        result_model=SkeletonLayoutValues,
        estimate_bytes=skeleton_bytes,
    ),
]
