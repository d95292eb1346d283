"""Anisotropic W1 on meshes (thesis §2.7, Fig. 2.15): ``POST
/v1/domains/{id}/anisotropic-distances``.

The cost of a flow is :math:`\\sum_t A_t \\lVert M_t J_t\\rVert` with per-face weights given by
the request: ``face_weights`` (F scalars, or F 3×3 matrices acting on the flow vectors in the
stored unit-area frame) or ``curvature`` (scalars from the mean curvature,
:func:`solvers.emd.anisotropy.mean_curvature_weights`, Fig. 2.15b).  Solved by
:func:`solvers.emd.anisotropy.anisotropic_w1` (interior point over all flows by default).
Results: the value, its certified lower bound, the flow, the potential and the weights per
face (``weights``: the scalar, or each matrix's largest stretch) drawn on the domain.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.errors import InvalidInput
from service.operations.base import (
    REQUEST_CONFIG,
    Distribution,
    DomainView,
    Int,
    Operation,
    OperationOutput,
    OperationRequest,
    check_options,
    check_same_components,
    given,
    needs,
    resolve_all,
    rules,
    view_of_domain,
)

# One interior-point W1 solve in cost units (service.operations.base.COST_PER_SECOND) per
# vertex: about 30 iterations, each a factorization and its solves; measured, with margin
# (bench/results/operation_memory.md: 450 under-counted these solves 5-20 times).
IPM_SOLVE_COST = 4500


class CurvatureWeights(BaseModel):
    """Scalar weights ``1 + strength |H| / mean |H|`` from the mean curvature ``H``."""

    model_config = REQUEST_CONFIG
    strength: float = Field(1.0, ge=0, le=1e3, description="alpha: 1 doubles the cost where "
                            "the curvature is average; 0 is isotropic")


class AnisotropicDistanceRequest(OperationRequest):
    model_config = ConfigDict(json_schema_extra={"examples": [
        {"mu0": {"vertex": 0, "radius": 0.1}, "mu1": {"vertex": 40, "radius": 0.1},
         "curvature": {"strength": 2.0}}], **given("face_weights", "curvature"),
        **rules(({"basis": {"const": "spectral"}}, needs("k")),
                ({"method": {"const": "ipm"}},
                 {"properties": {"basis": {"enum": ["auto", "flow"]}}}))})
    mu0: Distribution
    mu1: Distribution
    face_weights: list[float] | list[list[list[float]]] | None = Field(
        None, description="per face: a positive scalar, or a 3x3 matrix M (row-major rows) "
        "applied to the flow vector (stored frame), injective on the face's plane; exactly "
        "one of face_weights and curvature")
    curvature: CurvatureWeights | None = Field(None, description="weights from the mean "
                                               "curvature (Fig. 2.15b)")
    method: Literal["auto", "ipm", "admm", "weiszfeld"] = Field(
        "auto", description="auto/ipm: interior point over all flows (certified gap tol); "
        "admm, weiszfeld: in the curl basis 'full' or a 'spectral' one (an overestimate)")
    basis: Literal["auto", "flow", "full", "spectral"] = Field(
        "auto", description="flow space (auto: all flows with ipm, else full)")
    k: Int | None = Field(None, ge=1, description="spectral basis size")
    tol: float | None = Field(None, gt=0, lt=1, description="ipm: certified relative gap "
                              "(default 1e-4); admm/weiszfeld: their stopping rule")
    max_iter: Int | None = Field(None, ge=1, le=100_000)


class AnisotropicDistanceValues(BaseModel):
    """Values of an anisotropic-distance job."""

    value: float = Field(description="anisotropic W1 (cost of the returned flow)")
    lower_bound: float | None = Field(None, description="certified lower bound (interior "
                                      "point; null otherwise)")
    weights: Literal["scalar", "matrix", "curvature"]
    weight_range: list[float] = Field(description="[min, max] of the per-face weight (a "
                                      "matrix's largest stretch)")
    method: str
    basis: str
    iterations: Int
    residual: float
    converged: bool
    normalization: list[dict]


def _weights(view: DomainView, req: AnisotropicDistanceRequest):
    """The request's face weights as an array (None for curvature), checked."""
    if (req.face_weights is None) == (req.curvature is None):
        raise InvalidInput("give exactly one of face_weights and curvature",
                           field="face_weights")
    if req.face_weights is None:
        return None
    from solvers.emd.beckmann import check_face_weights

    n_faces = int(view.n_faces or 0)
    if len(req.face_weights) != n_faces:
        raise InvalidInput(f"face_weights has {len(req.face_weights)} entries; the mesh has "
                           f"{n_faces} faces", field="face_weights")
    try:
        w = np.asarray(req.face_weights, dtype=np.float64)
    except ValueError as exc:  # ragged matrices
        raise InvalidInput("face_weights must be F numbers or F 3x3 matrices",
                           field="face_weights") from exc
    w = check_face_weights(w, n_faces)
    if w.ndim == 3 and view.load_faces is not None:
        from solvers.emd.anisotropy import check_face_matrices

        check_face_matrices(view.points, view.load_faces(), w)
    return w


def _inputs(view: DomainView, req: AnisotropicDistanceRequest):
    check_options(view, req)
    weights = _weights(view, req)
    if req.method == "ipm" and req.basis not in ("auto", "flow"):
        raise InvalidInput("method 'ipm' solves over all flows (basis 'auto' or 'flow')",
                           field="basis")
    if req.basis == "flow" and req.method in ("admm", "weiszfeld") and (
            weights is not None and weights.ndim == 3):
        raise InvalidInput("matrix weights with admm/weiszfeld need basis 'full' or "
                           "'spectral'", field="basis")
    masses, reports = resolve_all(view, {"mu0": req.mu0, "mu1": req.mu1}, req.input)
    check_same_components(view, masses)
    return masses, weights, reports


def validate(view: DomainView, req: AnisotropicDistanceRequest) -> list[dict]:
    return _inputs(view, req)[2]


def estimate_cost(n: int, req, context=None) -> float:
    """One W1 solve: the interior point's cost, or the ADMM/Weiszfeld iteration cap."""
    if req.method in ("auto", "ipm") and req.basis in ("auto", "flow"):
        return float(IPM_SOLVE_COST) * float(max(n, 1))
    return float(max(n, 1)) * float(req.max_iter or 20_000)


def estimate_bytes(view: DomainView, req: AnisotropicDistanceRequest) -> int:
    """Per face: the weights (9 floats), interior-point cones and scalings (~40 floats);
    per vertex: the normal matrix's Cholesky factor (~60 floats)."""
    faces = view.faces_or_typical
    k = int(req.k or 0) if req.basis == "spectral" else 0
    return 8 * (49 * faces + 60 * int(view.n) + k * (2 * int(view.n) + 3 * faces))


def run(mesh, req: AnisotropicDistanceRequest, progress, should_cancel) -> OperationOutput:
    from solvers.emd.anisotropy import anisotropic_w1, mean_curvature_weights

    masses, weights, reports = _inputs(view_of_domain(mesh), req)
    kind = "curvature" if weights is None else ("matrix" if weights.ndim == 3 else "scalar")
    if weights is None:
        weights = mean_curvature_weights(mesh, req.curvature.strength)
    res = anisotropic_w1(mesh, masses["mu0"], masses["mu1"], weights,
                         method=req.method, basis=req.basis, k=req.k, tol=req.tol,
                         max_iter=req.max_iter, progress=progress, should_cancel=should_cancel)
    per_face = np.linalg.norm(weights, ord=2, axis=(1, 2)) if weights.ndim == 3 else weights
    lower = float(res.lower_bound) if res.method == "ipm" else None
    values = AnisotropicDistanceValues(
        value=float(res.value), lower_bound=lower, weights=kind,
        weight_range=[float(per_face.min()), float(per_face.max())], method=res.method,
        basis=res.basis, iterations=int(res.iterations), residual=float(res.residual),
        converged=bool(res.converged), normalization=reports).model_dump()
    flow = np.asarray(res.flow, dtype=np.float64)
    arrays = {"flow": flow, "flow_magnitude": np.linalg.norm(flow, axis=1),
              "potential": np.asarray(res.potential, dtype=np.float64), "weights": per_face}
    return OperationOutput(values, arrays, {"fields": ["potential", "weights"], "flow": "flow",
                                            "color": "potential"})


OPERATIONS = [
    Operation("anisotropic-distances", "createAnisotropicDistanceJob",
              "Anisotropic W1 with per-face scalar or 3x3 weights, or weights from the mean "
              "curvature (thesis §2.7, Fig. 2.15): value, flow, potential",
              AnisotropicDistanceRequest, run, validate, "faces",
              result_model=AnisotropicDistanceValues, estimate_bytes=estimate_bytes,
              estimate_cost=estimate_cost),
]
