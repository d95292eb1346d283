"""W1 barycenters and path planning on a mesh (thesis §2.7): ``POST
/v1/domains/{id}/w1-barycenters`` and ``POST /v1/domains/{id}/path-plans``.

* ``w1-barycenters``: eq. 2.7, :math:`\\min_\\rho \\sum_i \\alpha_i W_1(\\rho_i, \\rho)^2`
  (:func:`solvers.emd.w1_barycenter`): by default the vertex-sized interior point, refused at
  submission (413 naming the field) when its modelled run time
  (:func:`solvers.emd.interior_point_barycenter.estimated_cost`) exceeds
  ``MAX_ESTIMATED_SECONDS`` or its memory the job limit; ``method="socp"`` (Clarabel on
  the whole program) keeps that solver's caps, ``MAX_VERTICES`` vertices and
  ``MAX_BLOCK_UNKNOWNS`` vertices x (inputs + 1).
* ``path-plans``: eq. 2.6, occupants ``rho0`` leave through the ``targets`` with congestion
  weight ``epsilon`` (:func:`solvers.emd.path_planning.w1_path_planning`): arrivals, the
  flow, its potential and Hodge parts (Fig. 2.12).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

from service.errors import PayloadTooLarge
from service.operations.anisotropy import IPM_SOLVE_COST
from service.operations.base import (
    Distribution,
    DomainView,
    Int,
    Operation,
    OperationOutput,
    OperationRequest,
    resolve_distribution,
    resolve_weighted,
    view_of_domain,
)
from service.operations.examples import BUMP_A, BUMP_B, example
from solvers.emd.exact import MAX_BLOCK_UNKNOWNS, MAX_VERTICES
from solvers.emd.interior_point_barycenter import MAX_ESTIMATED_SECONDS, estimated_cost
from solvers.emd.path_planning import check_targets
from solvers.validation import check_indices

MAX_TARGETS = 1_000_000


# -- W1 barycenters (eq. 2.7) ---------------------------------------------------------------
class W1BarycenterRequest(OperationRequest):
    model_config = example({"distributions": [BUMP_A, BUMP_B], "weights": [0.5, 0.5]})
    distributions: list[Distribution] = Field(
        min_length=1, max_length=64, description="the inputs rho_i (ipm: modelled run time at "
        f"most {MAX_ESTIMATED_SECONDS:.0f} s; socp: vertices x (inputs + 1) at most "
        f"{MAX_BLOCK_UNKNOWNS})")
    weights: list[float] | None = Field(None, description="barycentric weights alpha_i, one "
                                        "per distribution, non-negative with a positive sum "
                                        "(default uniform); normalized to sum 1")
    method: Literal["auto", "ipm", "socp"] = Field(
        "auto", description="auto/ipm: interior point with vertex-sized Newton systems, "
        f"certified duality gap (meshes up to a modelled {MAX_ESTIMATED_SECONDS:.0f} s); "
        f"socp: Clarabel on the whole program (at most {MAX_VERTICES} vertices)")
    tol: float | None = Field(None, gt=0, lt=1, description="ipm: certified relative gap "
                              "(default 1e-6); socp: conic tolerance (default 1e-8)")
    max_iter: Int | None = Field(None, ge=1, le=1000, description="iteration cap (default "
                                 "100 for ipm, 200 for socp)")


class W1BarycenterValues(BaseModel):
    """Values of a W1-barycenter job."""

    value: float = Field(description="sum_i alpha_i W1(rho_i, rho)^2 at the returned rho")
    distances: list[float] = Field(description="W1 from the barycenter to each input")
    weights: list[float] = Field(description="the normalized barycentric weights")
    method: Literal["ipm", "socp"] = Field(description="the solver that ran")
    lower_bound: float | None = Field(description="ipm: certified lower bound of the "
                                      "objective (null for socp)")
    gap: float | None = Field(description="ipm: certified relative gap (value - lower_bound) "
                              "/ value (null for socp)")
    iterations: int
    residual: float = Field(description="max violation of the flows' divergence constraints")
    converged: bool
    status: str = Field(description="the solver's status")
    normalization: list[dict]


def _check_conic_size(view: DomainView, blocks: int, field: str) -> None:
    """The exact solver's caps (``solvers.emd.exact``), as 413s at submission."""
    if view.n > MAX_VERTICES:
        raise PayloadTooLarge(f"the mesh has {view.n} vertices; the exact conic solver takes "
                              f"at most {MAX_VERTICES}", field="domain_id")
    if blocks > 1 and view.n * blocks > MAX_BLOCK_UNKNOWNS:
        raise PayloadTooLarge(f"{blocks - 1} distributions on {view.n} vertices: vertices x "
                              f"(distributions + 1) = {view.n * blocks} exceeds "
                              f"{MAX_BLOCK_UNKNOWNS}; use fewer distributions or a coarser "
                              "mesh", field=field)


def _ipm_estimate(view: DomainView, req: W1BarycenterRequest):
    """The interior point's modelled cost for the request's inputs of positive weight."""
    k = len(req.distributions) if req.weights is None else \
        sum(1 for w in req.weights if w > 0)
    return estimated_cost(view.n, view.faces_or_typical, max(k, 1))


def _check_ipm_size(view: DomainView, req: W1BarycenterRequest) -> None:
    seconds = _ipm_estimate(view, req).seconds
    if seconds > MAX_ESTIMATED_SECONDS:
        alone = estimated_cost(view.n, view.faces_or_typical, 2).seconds > MAX_ESTIMATED_SECONDS
        raise PayloadTooLarge(
            f"the interior point's modelled run time on {view.n} vertices with these inputs "
            f"is {seconds:.0f} s, above {MAX_ESTIMATED_SECONDS:.0f} s: use "
            + ("a coarser mesh" if alone else "fewer distributions or a coarser mesh"),
            field="domain_id" if alone else "distributions")


def _barycenter_inputs(view: DomainView, req: W1BarycenterRequest):
    if req.method == "socp":
        _check_conic_size(view, len(req.distributions) + 1, "distributions")
    else:
        _check_ipm_size(view, req)
    return resolve_weighted(view, req.distributions, req.weights, req.input)


def validate_barycenter(view: DomainView, req: W1BarycenterRequest) -> list[dict]:
    return _barycenter_inputs(view, req)[2]


# Cost units (service.operations.cost.estimate_cost: points x iterations) per modelled second:
# one W1 interior-point solve, IPM_SOLVE_COST per vertex, took 8.3 s at 50k vertices
# (bench/results/w1_applications.md).
COST_PER_SECOND = IPM_SOLVE_COST * 50_000 / 8.3


def barycenter_cost(n: int, req: W1BarycenterRequest, context=None) -> float:
    """ipm: the modelled run time in queue-cost units; socp: one coupled conic solve over
    all inputs' flow blocks."""
    if req.method == "socp":
        return float(IPM_SOLVE_COST) * float(max(n, 1)) * float(len(req.distributions) + 1)
    k = len(req.distributions)
    return COST_PER_SECOND * estimated_cost(n, 2 * max(n, 1), k).seconds


def barycenter_bytes(view: DomainView, req: W1BarycenterRequest) -> int:
    """ipm: the modelled memory (factor of the coupled normal matrix, per-face cones); socp:
    per flow block, cones and scalings per face and the KKT factor's share per vertex, ~200
    and ~300 float64 (measured: bench/results/operation_memory.md; 40 and 60 missed three
    quarters)."""
    if req.method != "socp":
        return _ipm_estimate(view, req).bytes
    blocks = len(req.distributions) + 1
    return 8 * blocks * (200 * view.faces_or_typical + 300 * int(view.n))


def run_barycenter(mesh, req: W1BarycenterRequest, progress, should_cancel) -> OperationOutput:
    from solvers.emd import w1_barycenter

    mus, weights, reports = _barycenter_inputs(view_of_domain(mesh), req)
    res = w1_barycenter(mesh, mus, weights, method=req.method, tol=req.tol,
                        max_iter=req.max_iter, progress=progress, should_cancel=should_cancel)
    masses = np.asarray(res.masses, dtype=np.float64)
    values = W1BarycenterValues(
        value=float(res.value), distances=[float(d) for d in res.distances],
        weights=weights.tolist(), method=res.method,
        lower_bound=_finite_or_none(res.lower_bound), gap=_finite_or_none(res.gap),
        iterations=int(res.iterations),
        residual=float(res.residual), converged=bool(res.converged), status=str(res.status),
        normalization=reports).model_dump()
    arrays = {"masses": masses, "density": masses / np.asarray(mesh.areas)}
    return OperationOutput(values, arrays, {"fields": ["masses", "density"],
                                            "color": "density"})


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


# -- path planning (eq. 2.6) ------------------------------------------------------------------
class PathPlanRequest(OperationRequest):
    model_config = example({"rho0": BUMP_A, "targets": [100, 200], "epsilon": 0.001})
    rho0: Distribution = Field(description="the occupants' distribution")
    targets: list[Int] = Field(min_length=1, max_length=MAX_TARGETS, description="exit "
                               "vertices S (at least one on every connected component where "
                               "rho0 has mass)")
    epsilon: float = Field(0.0, ge=0, le=1e6, description="congestion weight of the term "
                           "epsilon * integral of rho1^2 (0: every occupant takes its nearest "
                           "exit)")
    method: Literal["auto", "ipm", "socp"] = Field(
        "auto", description="auto/ipm: interior point with vertex-sized Newton systems (any "
        f"mesh size); socp: Clarabel on the whole program (at most {MAX_VERTICES} vertices)")
    tol: float | None = Field(None, gt=0, lt=1, description="ipm: certified relative gap "
                              "(default 1e-6); socp: conic tolerance (default 1e-8)")
    max_iter: Int | None = Field(None, ge=1, le=1000, description="iteration cap (default "
                                 "100 for ipm, 200 for socp)")


class PathPlanValues(BaseModel):
    """Values of a path-planning job."""

    value: float = Field(description="W1(rho0, rho1): cost of the returned flow")
    objective: float = Field(description="value + epsilon * integral of rho1^2 (eq. 2.6)")
    epsilon: float
    n_targets: int = Field(description="distinct exit vertices")
    method: Literal["ipm", "socp"] = Field(description="the solver that ran")
    hodge_residual: float = Field(description="relative size of the harmonic part of the "
                                  "flow, J - grad f - R grad g (0 on simply connected "
                                  "surfaces)")
    iterations: int
    residual: float = Field(description="max violation of div J = m0 - m1")
    converged: bool
    status: str
    normalization: list[dict]


def _path_inputs(view: DomainView, req: PathPlanRequest):
    if req.method == "socp":
        if view.n > MAX_VERTICES:  # named after the choice the client can change
            raise PayloadTooLarge(f"method 'socp' takes at most {MAX_VERTICES} vertices; "
                                  f"the mesh has {view.n} (use 'ipm')", field="method")
    rho0, report = resolve_distribution(view, req.rho0, "rho0", req.input)
    targets = check_indices(req.targets, view.n, field="targets")
    mask = check_targets(targets, view.n, view.component_labels, rho0)
    return rho0, mask, [report]


def validate_path_plan(view: DomainView, req: PathPlanRequest) -> list[dict]:
    return _path_inputs(view, req)[2]


def path_plan_cost(n: int, req: PathPlanRequest, context=None) -> float:
    """One interior-point solve (the exits' program is about one W1 solve)."""
    return float(IPM_SOLVE_COST) * float(max(n, 1))


def path_plan_bytes(view: DomainView, req: PathPlanRequest) -> int:
    """Per face: the flow, its Hodge parts and the solver's cones (~50 floats); per vertex
    and edge: the Newton systems' factors and the Hodge solves (~80 floats)."""
    faces = view.faces_or_typical
    return 8 * (50 * faces + 80 * int(view.n) + 40 * (faces * 3 // 2))


def run_path_plan(mesh, req: PathPlanRequest, progress, should_cancel) -> OperationOutput:
    from solvers.emd.path_planning import w1_path_planning

    rho0, mask, reports = _path_inputs(view_of_domain(mesh), req)
    res = w1_path_planning(mesh, rho0, mask, epsilon=req.epsilon, method=req.method,
                           tol=req.tol, max_iter=req.max_iter, progress=progress,
                           should_cancel=should_cancel)
    hodge = res.hodge
    flow = np.asarray(res.flow, dtype=np.float64)
    values = PathPlanValues(
        value=float(res.value), objective=float(res.objective), epsilon=float(req.epsilon),
        n_targets=int(mask.sum()), method=res.method,
        hodge_residual=float(hodge.residual), iterations=int(res.iterations),
        residual=float(res.residual), converged=bool(res.converged), status=str(res.status),
        normalization=reports).model_dump()
    arrays = {"arrivals": np.asarray(res.target_masses, dtype=np.float64), "flow": flow,
              "flow_magnitude": np.linalg.norm(flow, axis=1),
              "potential": np.asarray(res.potential, dtype=np.float64),
              "hodge_f": np.asarray(hodge.f, dtype=np.float64),
              "hodge_g": np.asarray(hodge.g, dtype=np.float64),
              "hodge_g_vertices": np.asarray(hodge.g_vertices, dtype=np.float64),
              "targets": np.flatnonzero(mask)}
    return OperationOutput(values, arrays, {
        "fields": ["potential", "arrivals", "hodge_f", "hodge_g_vertices"], "flow": "flow",
        "color": "potential"})


FACES = "faces"  # what these operations require of a domain (Domain.supports)
OPERATIONS = [
    Operation("w1-barycenters", "createW1BarycenterJob",
              "W1 barycenter, the minimizer of the weighted sum of squared W1 distances to "
              "the inputs (thesis eq. 2.7; interior point with a certified duality gap)",
              W1BarycenterRequest, run_barycenter, validate_barycenter, FACES,
              result_model=W1BarycenterValues, estimate_bytes=barycenter_bytes,
              estimate_cost=barycenter_cost),
    Operation("path-plans", "createPathPlanJob",
              "Path planning by W1: occupants leave through exit vertices, with optional "
              "congestion (thesis eq. 2.6, Fig. 2.12): arrivals, flow, potential, Hodge parts",
              PathPlanRequest, run_path_plan, validate_path_plan, FACES,
              result_model=PathPlanValues, estimate_bytes=path_plan_bytes,
              estimate_cost=path_plan_cost),
]
