"""Soft maps between two uploaded meshes (thesis ch. 4, §3.7): ``POST /v1/soft-maps``.

A global operation over two stored mesh domains; thin over :func:`solvers.softmaps.soft_map`.
Results: energies and the extracted correspondence (JSON values); the soft map's rows, one
per source sample, at ``GET /v1/jobs/{id}/arrays/soft_map/rows/{i}`` (the distribution over
every target vertex; ``labels[x]`` is the row of source vertex ``x``).  Solved over a coarse
target (``target_points``, default ``"auto"``), the map is stored as ``soft_map_coarse``
(samples x coarse points, float32) with the prolongation ``prolongation_indices`` /
``prolongation_weights`` (target vertices x 3-4), and each row asked for is prolonged then
(:func:`result_row`); at full resolution it is stored as ``soft_map`` (samples x target
vertices).  Also ``samples``, ``labels``, ``correspondence``; the densities as
one-row arrays (``.../arrays/bijectivity_density/rows/0``: :math:`b(y)` per target vertex,
eq. 4.5; ``dirichlet_vertex_density``: the Dirichlet energy density per source vertex;
``dirichlet_density`` per sample); and ``result.glb``: the source colored by target
coordinates pulled back through the map, one copy of the target per requested source
vertex colored by its distribution, the first with momentum vectors (eq. 4.4) as lines, and
on request (``glb_densities``) the target colored by :math:`b` and the source by the
Dirichlet energy density.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

from service.errors import InvalidInput, PayloadTooLarge, UnsupportedOperation
from service.operations.base import (
    REQUEST_CONFIG,
    Int,
    Operation,
    OperationOutput,
    OperationRequest,
    ResultFile,
)
from service.operations.examples import EXAMPLE_ID, example
from service.schemas import DomainId


class LandmarkPair(BaseModel):
    model_config = REQUEST_CONFIG
    source: Int = Field(ge=0, description="vertex of the source mesh")
    target: Int = Field(ge=0, description="matching vertex of the target mesh")


class SoftMapRequest(OperationRequest):
    model_config = example({
        "source_id": EXAMPLE_ID, "target_id": EXAMPLE_ID,
        "landmarks": [{"source": 0, "target": 0}, {"source": 100, "target": 100}],
        "samples": 64, "k": 20, "max_iter": 50})
    source_id: DomainId = Field(description="source mesh domain id (the map goes source -> "
                                "target)")
    target_id: DomainId = Field(description="target mesh domain id")
    landmarks: list[LandmarkPair] = Field(min_length=1, max_length=256, description="known "
                                          "pairs: fixed nodes of the propagation and landmark "
                                          "descriptors")
    samples: Int = Field(1024, ge=2, le=100_000, description="farthest-point source samples "
                         "(>= source vertices: all of them)")
    target_points: Int | Literal["auto"] | None = Field(
        "auto", description="solve over the target decimated to about this many points, "
        "then prolong each row to every target vertex; 'auto': as many as the samples when "
        "that is at most 2/3 of the target's vertices; null: every target vertex")
    tau: float = Field(0.05, gt=0, le=1e6, description="compatibility weight (cost of mean 1)")
    gamma: float | None = Field(None, gt=0, le=100, description="entropic regularization on "
                                "the target (unit area); default: twice the squared sample "
                                "spacing, at least 4 h^2 of the target solved over, and at "
                                "least 0.01 over a coarse target")
    k: Int = Field(100, ge=10, le=500, description="Laplace-Beltrami eigenpairs (WKS, ZoomOut)")
    n_energies: Int = Field(100, ge=2, le=1000, description="WKS energies")
    wks_weight: float = Field(1.0, ge=0, description="weight of the WKS block of descriptors")
    landmark_weight: float = Field(1.0, ge=0, description="weight of the landmark block")
    landmark_method: Literal["geodesic", "heat"] = "geodesic"
    norm: Literal["l1", "l2"] = Field("l1", description="descriptor difference (thesis: L1)")
    tol: float = Field(1e-4, gt=0, lt=1, description="largest L1 marginal violation")
    max_iter: Int = Field(1000, ge=1, le=10_000, description="propagation sweeps")
    top_k: Int | None = Field(None, ge=1, description="store only the k largest masses per "
                              "row (arrays top_indices/top_masses, dropped_mass)")
    extraction: Literal["mode", "barycentric", "path"] = "mode"
    refine: Literal["symmetric-zoomout", "zoomout", "sinkhorn", "sinkhorn+zoomout",
                    "none"] = Field(
        "symmetric-zoomout", description="symmetric-zoomout: ZoomOut with the reverse map "
        "tied in (C of the reverse map = C^T); zoomout: spectral upsampling (ZoomOut) started "
        "from the soft map's own functional map; sinkhorn: "
        "project the soft map onto the doubly-stochastic set (source/target areas) before "
        "extraction; sinkhorn+zoomout: both; none")
    show_vertices: list[Int] = Field(default_factory=list, max_length=8, description="source "
                                     "vertices whose distributions color the target in the "
                                     "GLB (default: the first landmark's)")
    glb_densities: list[Literal["bijectivity", "dirichlet"]] = Field(
        default_factory=list, max_length=2, description="extra copies in result.glb: "
        "'bijectivity' the target colored by b(y) (eq. 4.5), 'dirichlet' the source colored "
        "by the Dirichlet energy density per vertex")


class DensitySummary(BaseModel):
    """A per-vertex density stored as a one-row array (``GET .../arrays/{array}/rows/0``)."""

    array: str = Field(description="name of the (1, n) result array holding it")
    min: float
    max: float
    mean: float = Field(description="area-weighted mean (its integral over the unit-area "
                        "surface)")
    area_below_half: float = Field(description="fraction of the area where density < 0.5 "
                                   "x mean")
    area_above_two: float = Field(description="fraction of the area where density > 2 x mean")


class SoftMapEnergies(BaseModel):
    dirichlet: float = Field(description="eq. 4.2 over the source edges, convolutional W2^2 "
                             "of the final edge plans")
    bijectivity: float = Field(description="eq. 4.5, 1 for a bijective isometry")
    descriptor: float = Field(description="eq. 4.6 with the normalized cost")
    bijectivity_density: DensitySummary = Field(description="b(y) = integral over the source "
                                                "of rho_x(y) (eq. 4.5) per target vertex; "
                                                "1 everywhere for a bijective isometry")
    dirichlet_density: DensitySummary = Field(description="Dirichlet energy density per "
                                              "source vertex (integrates to dirichlet)")


class SinkhornSummary(BaseModel):
    """The Sinkhorn projection of ``refine="sinkhorn"`` (marginal residuals in L1)."""

    iterations: Int
    residual: float = Field(description="target-marginal L1 violation after projection")
    initial_residual: float = Field(description="the same before: integral of |b - 1|")
    converged: bool


class SoftMapValues(BaseModel):
    """Values of a soft-map job."""

    source_id: str = Field(description="the source mesh domain (the request's source_id)")
    target_id: str = Field(description="the target mesh domain (the request's target_id)")
    energies: SoftMapEnergies
    correspondence: list[Int] = Field(description="target vertex of every source vertex")
    samples: Int
    target_points: Int | None = Field(description="coarse target points the map was solved "
                                      "over (null: every target vertex)")
    gamma: float
    tau: float
    iterations: Int
    residual: float
    converged: bool
    dropped_mass_max: float | None = Field(None, description="top_k: largest mass left out "
                                           "of a row")
    timings: dict[str, float]
    sinkhorn: SinkhornSummary | None = Field(None, description="refine sinkhorn: the "
                                             "projection's iterations and residuals")
    rows: str = Field("soft_map", description="array holding one distribution per source "
                      "sample; labels[x] is the row of source vertex x")


def _mesh_view(ctx, domain_id: str, field: str):
    view = ctx.view(domain_id, field)
    if not view.supports("faces"):
        raise UnsupportedOperation(f"soft maps need triangle meshes; {field} is a {view.kind} "
                                   "domain", field=field)
    if view.n_components > 1:
        raise UnsupportedOperation(f"{field} has {view.n_components} connected components: "
                                   "transport cannot cross them, upload a connected mesh",
                                   field=field)
    return view


def estimate_sizes(n_source: int, n_target: int, req: SoftMapRequest) -> dict:
    """``{"bytes", "cost"}`` of a soft map job from its sizes: the library's peak-memory
    model (``solvers.softmaps.propagation_map.estimated_bytes``) and the cost in the units of
    ``service.operations.cost.estimate_cost``: per propagation sweep (at most ``max_iter``) one
    log-domain step per source edge (about 3 per sample) over every solved target point,
    plus the prolongation of every row to the full target."""
    from solvers.softmaps.propagation_map import (
        EDGES_PER_SAMPLE,
        estimated_bytes,
        solved_points,
        wholly_prolonged,
    )

    n_samples = min(req.samples, n_source)
    solved = solved_points(req.target_points, n_samples, n_target)
    need = estimated_bytes(n_samples, n_target, target_points=solved, n_source=n_source,
                           k=req.k, n_energies=req.n_energies, landmarks=len(req.landmarks),
                           whole_rows=wholly_prolonged(req.extraction, req.refine))
    per_sweep = EDGES_PER_SAMPLE * n_samples * (n_target if solved is None else solved)
    steps = float(per_sweep) * float(req.max_iter) + float(n_samples) * float(n_target)
    return {"bytes": need, "cost": LOG_STEP_COST * steps}


# cost units (service.operations.base.COST_PER_SECOND) per log-domain step (an exp and a
# log-sum-exp per entry, not a kernel application): measured 56-87 (bench/results/
# operation_memory.md)
LOG_STEP_COST = 100.0


def estimate_cost(n: int, req: SoftMapRequest, context=None) -> float:
    """The job's cost (see :func:`estimate_sizes`) over its two stored meshes."""
    n_target = n
    if context is not None:
        n_target = context.view(req.target_id, "target_id").n
    return estimate_sizes(n, n_target, req)["cost"]


def job_bytes(ctx, req: SoftMapRequest) -> int:
    """The job's working memory (see :func:`estimate_sizes`) over its two stored meshes."""
    return estimate_sizes(ctx.view(req.source_id, "source_id").n,
                          ctx.view(req.target_id, "target_id").n, req)["bytes"]


def validate(ctx, req: SoftMapRequest) -> list[dict]:
    src = _mesh_view(ctx, req.source_id, "source_id")
    tgt = _mesh_view(ctx, req.target_id, "target_id")
    for i, pair in enumerate(req.landmarks):
        if pair.source >= src.n:
            raise InvalidInput(f"landmarks[{i}].source = {pair.source} is outside "
                               f"[0, {src.n - 1}]", field=f"landmarks[{i}].source")
        if pair.target >= tgt.n:
            raise InvalidInput(f"landmarks[{i}].target = {pair.target} is outside "
                               f"[0, {tgt.n - 1}]", field=f"landmarks[{i}].target")
    if len({p.source for p in req.landmarks}) != len(req.landmarks):
        raise InvalidInput("two landmarks share a source vertex", field="landmarks")
    for i, v in enumerate(req.show_vertices):
        if not 0 <= v < src.n:
            raise InvalidInput(f"show_vertices[{i}] = {v} is outside [0, {src.n - 1}]",
                               field=f"show_vertices[{i}]")
    if req.samples < len(req.landmarks):
        raise InvalidInput("samples must be at least the number of landmarks", field="samples")
    if req.k >= min(src.n, tgt.n) - 2:
        raise InvalidInput(f"k must be below {min(src.n, tgt.n) - 2}", field="k")
    if req.top_k is not None and req.top_k > tgt.n:
        raise InvalidInput(f"top_k must be at most {tgt.n}", field="top_k")
    if isinstance(req.target_points, int) and req.target_points < 4:
        raise InvalidInput("target_points must be at least 4 (or 'auto', or null)",
                           field="target_points")
    need = estimate_sizes(src.n, tgt.n, req)["bytes"]
    limit = int(ctx.settings.job_memory_bytes)
    if need > limit:
        raise PayloadTooLarge(f"{min(req.samples, src.n)} samples over {tgt.n} target "
                              f"vertices need about {need / 2**30:.3g} GiB of working memory, "
                              f"more than the limit of {limit / 2**30:.3g} GiB: use fewer "
                              "samples", field="samples")
    return []


def _summary(name: str, values: np.ndarray, areas: np.ndarray) -> DensitySummary:
    mean = float(areas @ values / areas.sum())
    frac = areas / areas.sum()
    return DensitySummary(array=name, min=float(values.min()), max=float(values.max()),
                          mean=mean, area_below_half=float(frac @ (values < 0.5 * mean)),
                          area_above_two=float(frac @ (values > 2.0 * mean)))


def _glb(source, target, res, show_rows, rows_of, densities) -> bytes:
    from service.export import meshes_glb
    from solvers.softmaps.energies import momentum, transportation_potential
    from solvers.softmaps.transfer import coordinate_colors, pull_back, pull_back_top_k

    colors = coordinate_colors(target)
    if res.soft_map is not None:
        on_rows = colors if res.prolongation is None else \
            res.prolongation.transpose_apply(colors)  # P^T: the rows stay coarse
        pulled = pull_back(res.soft_map, on_rows, res.labels)
    else:
        pulled = pull_back_top_k(res.top_indices, res.top_masses, colors, res.labels)
    width = float(np.ptp(source.vertices[:, 0]) + np.ptp(target.vertices[:, 0]))
    height = float(np.ptp(target.vertices[:, 1]))
    parts = [{"name": "source", "vertices": source.vertices, "faces": source.faces,
              "colors": pulled}]
    for j, (x, row) in enumerate(zip(show_rows, rows_of, strict=True)):
        density = row / target.areas
        part = {"name": f"target mu_x x={x}", "vertices": target.vertices,
                "faces": target.faces, "field": density, "field_name": "density",
                "translation": [0.6 * width, -1.1 * height * j, 0.0]}
        if j == 0:
            # Momentum (eq. 4.4) of mu_x towards its first neighbour on the source graph.
            u = int(res.labels[x])
            nbr = res.edges[np.any(res.edges == u, axis=1)]
            if len(nbr):
                v = int(nbr[0, 1] if nbr[0, 0] == u else nbr[0, 0])
                q = transportation_potential(target, row, res.row(v))
                mom = momentum(target, row, q)
                mag = np.linalg.norm(mom, axis=1)
                keep = np.argsort(-mag)[:2000]
                scale = 2.0 * target.mean_edge_length / max(float(mag.max()), 1e-300)
                c = target.vertices[target.faces[keep]].mean(axis=1)
                part["lines"] = np.stack([c, c + scale * mom[keep]], axis=1)
        parts.append(part)
    below = len(parts) - 1  # copies on request go under the last distribution
    for name, field_name, values, mesh, on_target in densities:
        parts.append({"name": name, "vertices": mesh.vertices, "faces": mesh.faces,
                      "field": values, "field_name": field_name,
                      "translation": [0.6 * width if on_target else 0.0,
                                      -1.1 * height * below, 0.0]})
        below += 1
    return meshes_glb(parts, metadata={"operation": "soft-maps"})


def run(ctx, req: SoftMapRequest, progress, should_cancel) -> OperationOutput:
    from solvers.softmaps import soft_map
    from solvers.softmaps.energies import soft_map_energies

    source = ctx.domain(req.source_id, "source_id")
    target = ctx.domain(req.target_id, "target_id")
    pairs = [[p.source, p.target] for p in req.landmarks]
    res = soft_map(source, target, pairs, samples=req.samples,
                   target_points=req.target_points, tau=req.tau, gamma=req.gamma,
                   k=req.k, n_energies=req.n_energies, wks_weight=req.wks_weight,
                   landmark_weight=req.landmark_weight, landmark_method=req.landmark_method,
                   norm=req.norm, tol=req.tol, max_iter=req.max_iter, top_k=req.top_k,
                   extraction=req.extraction, refine=req.refine, progress=progress,
                   should_cancel=should_cancel)
    energies = soft_map_energies(target, res)
    b, e_vertex = energies.bijectivity_density, energies.dirichlet_vertex_density
    sinkhorn = res.sinkhorn  # refine="sinkhorn...": the projection, else None
    values = SoftMapValues(
        source_id=req.source_id, target_id=req.target_id,
        energies=SoftMapEnergies(
            dirichlet=energies.dirichlet.total, bijectivity=energies.bijectivity,
            descriptor=energies.descriptor,
            bijectivity_density=_summary("bijectivity_density", b, target.areas),
            dirichlet_density=_summary("dirichlet_vertex_density", e_vertex, source.areas)),
        correspondence=res.correspondence.tolist(), samples=int(len(res.samples)),
        target_points=res.target_points,
        gamma=res.gamma, tau=res.tau, iterations=res.iterations, residual=res.residual,
        converged=res.converged,
        dropped_mass_max=None if res.dropped_mass is None else float(res.dropped_mass.max()),
        timings=res.timings,
        sinkhorn=None if sinkhorn is None else SinkhornSummary(
            iterations=sinkhorn.iterations, residual=sinkhorn.residual,
            initial_residual=sinkhorn.initial_residual, converged=sinkhorn.converged),
    ).model_dump()
    arrays = {"samples": res.samples, "labels": res.labels,
              "correspondence": res.correspondence, "cell_areas": res.cell_areas,
              "dirichlet_density": res.dirichlet.density,
              # One-row arrays: GET .../arrays/<name>/rows/0 returns them without the map.
              "bijectivity_density": b[None, :],
              "dirichlet_vertex_density": e_vertex[None, :]}
    if res.prolongation is not None:
        arrays.update(soft_map_coarse=res.soft_map,
                      prolongation_indices=res.prolongation.indices.astype(np.int32),
                      prolongation_weights=res.prolongation.weights.astype(np.float32))
    elif res.soft_map is not None:
        arrays["soft_map"] = res.soft_map
    else:
        arrays.update(top_indices=res.top_indices, top_masses=res.top_masses,
                      dropped_mass=res.dropped_mass)
        values["rows"] = "top_masses"
    show = req.show_vertices or [pairs[0][0]]
    rows_of = [res.row(int(res.labels[x])) for x in show]
    densities = []  # (node name, field name, values, mesh, drawn in the target's column)
    if "bijectivity" in req.glb_densities:
        densities.append(("target bijectivity density", "bijectivity_density", b, target,
                          True))
    if "dirichlet" in req.glb_densities:
        densities.append(("source dirichlet density", "dirichlet_density", e_vertex, source,
                          False))
    files = {"result.glb": ResultFile("model/gltf-binary",
                                      _glb(source, target, res, show, rows_of, densities))}
    return OperationOutput(values=values, arrays=arrays, files=files)


def result_row(array, name: str, row: int) -> np.ndarray | None:
    """Row ``row`` of ``soft_map`` prolonged from ``soft_map_coarse`` (a map solved over a
    coarse target), ``None`` for any other array or a full-resolution map."""
    from service.errors import NotFound
    from solvers.softmaps.coarse_target import Prolongation

    if name != "soft_map":
        return None
    try:
        coarse = array("soft_map_coarse")
    except NotFound:
        return None  # stored at full resolution
    if not 0 <= row < coarse.shape[0]:
        raise InvalidInput(f"row {row} out of range [0, {coarse.shape[0] - 1}]", field="row")
    p = Prolongation(array("prolongation_indices"), array("prolongation_weights"),
                     coarse.shape[1])
    return p.apply(coarse[row].astype(np.float64))


OPERATIONS = [
    Operation(
        name="soft-maps",
        operation_id="createSoftMapJob",
        summary="Soft map between two meshes by Wasserstein propagation with descriptor "
                "compatibility (thesis §3.7, ch. 4): energies, correspondence, distributions",
        request_model=SoftMapRequest,
        run=run,
        validate=validate,
        requires="faces",
        scope="global",
        domain_field="source_id",
        result_model=SoftMapValues,
        result_row=result_row,
        estimate_cost=estimate_cost,
        estimate_bytes=job_bytes,
    ),
]
