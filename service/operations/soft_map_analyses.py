"""Analysis of user-given point maps as soft maps (thesis ch. 4, §4.6): ``POST
/v1/soft-map-analyses``.

Each map sends every vertex of a source mesh to a vertex of the common target mesh; it is
turned into a soft map by heat blurring on ``samples`` farthest-point samples
(:func:`solvers.softmaps.point_maps.point_map_soft_map`), whose energies (Dirichlet eq. 4.2,
bijectivity eq. 4.5, descriptor eq. 4.6) and §4.6.1 SVD bases are reported; with two maps
or more, the §4.6.2 collection basis on the target shared by all of them.

Results: values per map; arrays ``bijectivity_density_{i}`` (per target vertex),
``target_basis_{i}`` (target vertices x rank), ``source_basis_{i}`` (samples x rank),
``samples_{i}`` and ``collection_basis`` (target vertices x rank), drawn on the target
(the job's domain; basis functions as frames); ``result.glb``: the target colored by the
first map's bijectivity density, then by the first ``show`` basis functions.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.errors import InvalidInput, PayloadTooLarge
from service.operations.base import (
    REQUEST_CONFIG,
    Int,
    Operation,
    OperationOutput,
    OperationRequest,
    ResultFile,
)
from service.operations.examples import EXAMPLE_ID
from service.operations.softmaps import _mesh_view  # meshes of one component
from service.schemas import DomainId

MAX_MAPS = 8
MAX_SINGULAR_VALUES = 64  # reported per map (all are in no array: the rank kept is)
# cost units (service.operations.base.COST_PER_SECOND) per (source edge x target vertex): a
# W2 or a potential solve per edge took ~20 ms on 7,207 target vertices (lion -> cat, 128
# samples), ~140 units per target vertex; with the rest of the job, measured ~400
# (bench/results/operation_memory.md)
DIRICHLET_COST = {"w2": 400, "potential": 400, "none": 0}
ROWS_COPIES = 8  # (samples x target) float64 arrays alive at once: rows, kernel input and
# output, descriptor cost, the weighted kernel and the SVD's work arrays


class PointMap(BaseModel):
    """A point map from a source mesh to the target: one target vertex per source vertex."""

    model_config = REQUEST_CONFIG
    source_id: DomainId = Field(description="source mesh domain id")
    correspondence: list[Int] = Field(min_length=1, description="target vertex of every "
                                      "source vertex, in the source's vertex order")


class SoftMapAnalysisRequest(OperationRequest):
    model_config = ConfigDict(json_schema_extra={"examples": [
        {"target_id": EXAMPLE_ID,
         "maps": [{"source_id": EXAMPLE_ID, "correspondence": [0, 2, 1, 3]}],
         "samples": 64, "rank": 6, "dirichlet_method": "potential"}]})
    target_id: DomainId = Field(description="target mesh domain id (the job's domain)")
    maps: list[PointMap] = Field(min_length=1, max_length=MAX_MAPS, description="point maps "
                                 "into the target; two or more give a collection basis")
    samples: Int = Field(128, ge=2, le=4096, description="farthest-point samples of each "
                         "source (>= its vertices: every vertex)")
    gamma: float | None = Field(None, gt=0, le=100, description="blur of the point maps and "
                                "regularization of the Dirichlet energy's W2 (unit area); "
                                "default: twice the squared sample spacing, at least 4 h^2")
    substeps: Int = Field(1, ge=1, le=16, description="implicit Euler steps of the heat "
                          "kernel")
    rank: Int = Field(8, ge=1, le=64, description="basis functions kept (the constant first)")
    dirichlet_method: Literal["w2", "potential", "none"] = Field(
        "w2", description="Dirichlet energy: w2 (eq. 4.2, convolutional W2^2 per source edge, "
        "debiased), potential (eq. 4.3, its linearization), none")
    descriptor_k: Int = Field(30, ge=0, le=300, description="eigenpairs of the WKS "
                              "descriptors of the descriptor energy (eq. 4.6); 0: not "
                              "computed")
    n_energies: Int = Field(100, ge=2, le=1000, description="WKS energies")
    norm: Literal["l1", "l2"] = Field("l1", description="descriptor difference")
    show: Int = Field(4, ge=0, le=8, description="basis functions drawn in result.glb")


class PointMapAnalysisValues(BaseModel):
    """One analysed point map."""

    source_id: str
    samples: Int
    gamma: float
    dirichlet: float | None = Field(description="eq. 4.2 (or its linearization, see "
                                    "dirichlet_method); null when not asked")
    dirichlet_method: str
    bijectivity: float = Field(description="eq. 4.5, E_B = integral of b^2; 1 for a "
                               "bijective isometry")
    bijectivity_range: list[float] = Field(description="[min, max] of b per target vertex")
    descriptor: float | None = Field(description="eq. 4.6 with the WKS cost of mean 1")
    singular_values: list[float] = Field(description="§4.6.1, the constant pair's 1 first "
                                         f"(at most {MAX_SINGULAR_VALUES})")
    low_rank_error: float = Field(description="relative weighted Frobenius error of the "
                                  "rank-`rank` map")
    captured: float = Field(description="share of the de-meaned map in its rank-`rank` basis")


class CollectionBasisValues(BaseModel):
    """§4.6.2: one target basis shared by the maps."""

    rank: Int
    array: str = Field("collection_basis", description="(target vertices, rank) array")
    captured: list[float] = Field(description="per map: share of its de-meaned weighted "
                                  "kernel in the collection basis")


class SoftMapAnalysisValues(BaseModel):
    """Values of a soft-map analysis job."""

    target_id: str
    rank: Int
    maps: list[PointMapAnalysisValues]
    collection: CollectionBasisValues | None = Field(None, description="with two maps or "
                                                     "more")


def estimated_bytes(req: SoftMapAnalysisRequest, n_target: int, sources: list[int]) -> int:
    rows = sum(min(req.samples, n) for n in sources)
    return 8 * n_target * rows * ROWS_COPIES


def job_bytes(ctx, req: SoftMapAnalysisRequest) -> int:
    """:func:`estimated_bytes` over the stored meshes."""
    sources = [ctx.view(m.source_id, f"maps[{i}].source_id").n for i, m in enumerate(req.maps)]
    return estimated_bytes(req, ctx.view(req.target_id, "target_id").n, sources)


def validate(ctx, req: SoftMapAnalysisRequest) -> list[dict]:
    from solvers.softmaps.point_maps import check_point_map

    target = _mesh_view(ctx, req.target_id, "target_id")
    sources = []
    for i, m in enumerate(req.maps):
        view = _mesh_view(ctx, m.source_id, f"maps[{i}].source_id")
        check_point_map(m.correspondence, view.n, target.n,
                        field=f"maps[{i}].correspondence")
        if req.rank > min(req.samples, view.n, target.n) + 1:
            raise InvalidInput(f"rank must be at most {min(req.samples, view.n, target.n) + 1} "
                               f"for maps[{i}] (samples and vertices bound it)", field="rank")
        if req.descriptor_k >= min(view.n, target.n) - 2:
            raise InvalidInput(f"descriptor_k must be below {min(view.n, target.n) - 2}",
                               field="descriptor_k")
        sources.append(view.n)
    if req.descriptor_k == 1:
        raise InvalidInput("descriptor_k must be 0 (none) or at least 2", field="descriptor_k")
    need, limit = estimated_bytes(req, target.n, sources), int(ctx.settings.job_memory_bytes)
    if need > limit:
        raise PayloadTooLarge(f"the soft maps need about {need / 2**30:.3g} GiB of working "
                              f"memory, more than the limit of {limit / 2**30:.3g} GiB: use "
                              "fewer samples or maps", field="samples")
    return []


def estimate_cost(n: int, req: SoftMapAnalysisRequest, context=None) -> float:
    """Target vertices x samples x maps x (3 source edges per sample x the Dirichlet
    method's cost per edge, plus the SVD)."""
    per = 3 * DIRICHLET_COST[req.dirichlet_method] + req.samples
    return float(max(n, 1)) * float(req.samples) * float(len(req.maps)) * float(per)


def _glb(target, densities: np.ndarray, basis: np.ndarray, show: int) -> bytes:
    from service.export import meshes_glb

    v = target.vertices * target.length_scale
    width = 1.2 * float(np.ptp(v[:, 0]))
    parts = [{"name": "bijectivity density", "vertices": v, "faces": target.faces,
              "field": densities, "field_name": "bijectivity"}]
    for j in range(1, min(show + 1, basis.shape[1])):
        parts.append({"name": f"basis {j}", "vertices": v, "faces": target.faces,
                      "field": basis[:, j], "field_name": "basis",
                      "translation": [j * width, 0.0, 0.0]})
    return meshes_glb(parts, metadata={"operation": "soft-map-analyses"})


def run(ctx, req: SoftMapAnalysisRequest, progress, should_cancel) -> OperationOutput:
    from solvers.monitor import Monitor
    from solvers.softmaps.point_maps import (
        analyze_point_map,
        captured_energy,
        point_maps_collection_basis,
    )

    monitor = Monitor(progress, should_cancel)  # between maps: cancellation and progress
    target = ctx.domain(req.target_id, "target_id")
    method = None if req.dirichlet_method == "none" else req.dirichlet_method
    analyses, values, arrays = [], [], {}
    for i, m in enumerate(req.maps):
        monitor.check_cancel(f"before maps[{i}]")
        source = ctx.domain(m.source_id, f"maps[{i}].source_id")
        a = analyze_point_map(source, target, m.correspondence, samples=req.samples,
                              gamma=req.gamma, substeps=req.substeps, rank=req.rank,
                              dirichlet_method=method, descriptor_k=req.descriptor_k or None,
                              n_energies=req.n_energies, norm=req.norm)
        analyses.append(a)
        monitor(i + 1, a.low_rank_error)
        b = a.bijectivity_density
        values.append(PointMapAnalysisValues(
            source_id=m.source_id, samples=int(a.soft_map.samples.n), gamma=a.soft_map.gamma,
            dirichlet=None if a.dirichlet is None else float(a.dirichlet.total),
            dirichlet_method=req.dirichlet_method, bijectivity=a.bijectivity,
            bijectivity_range=[float(b.min()), float(b.max())], descriptor=a.descriptor,
            singular_values=a.singular_values[:MAX_SINGULAR_VALUES].tolist(),
            low_rank_error=a.low_rank_error,
            captured=captured_energy(a.soft_map, target.areas, a.basis.target_basis)))
        arrays.update({f"bijectivity_density_{i}": b, f"target_basis_{i}": a.basis.target_basis,
                       f"source_basis_{i}": a.basis.source_basis,
                       f"samples_{i}": a.soft_map.samples.indices})
    collection = None
    shown = analyses[0].basis.target_basis
    if len(analyses) > 1:
        shown = point_maps_collection_basis(target, analyses, req.rank)
        arrays["collection_basis"] = shown
        collection = CollectionBasisValues(
            rank=req.rank, captured=[captured_energy(a.soft_map, target.areas, shown)
                                     for a in analyses])
    out = SoftMapAnalysisValues(target_id=req.target_id, rank=req.rank, maps=values,
                                collection=collection).model_dump()
    fields = ["bijectivity_density_0", "collection_basis" if collection else "target_basis_0"]
    glb = _glb(target, analyses[0].bijectivity_density, shown, req.show)
    return OperationOutput(values=out, arrays=arrays,
                           export={"fields": fields, "frames": list(range(req.rank))},
                           files={"result.glb": ResultFile("model/gltf-binary", glb)})


OPERATIONS = [
    Operation("soft-map-analyses", "createSoftMapAnalysisJob",
              "Energies and bases of point maps given as soft maps (thesis ch. 4: Dirichlet, "
              "bijectivity, descriptor energies; §4.6 SVD and collection bases)",
              SoftMapAnalysisRequest, run, validate, "faces", scope="global",
              domain_field="target_id", result_model=SoftMapAnalysisValues,
              estimate_cost=estimate_cost, estimate_bytes=job_bytes),
]
