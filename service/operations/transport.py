"""Convolutional (entropic W2) and W1 transport operations: distances, barycenters,
interpolations, pointwise distances and flows — thin adapters over ``solvers``."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, Field

from service.errors import InvalidInput
from service.operations.base import (
    COST_PER_SECOND,
    REQUEST_CONFIG,
    Distribution,
    DomainView,
    Int,
    NodePair,
    Operation,
    OperationOutput,
    OperationRequest,
    check_options,
    check_same_components,
    estimate_job_bytes,
    resolve_all,
    resolve_weighted,
    view_of_domain,
)
from service.operations.cost import DEFAULT_ITERATIONS, estimate_cost
from service.operations.examples import BUMP_A, BUMP_B, example
from solvers.convolutional import (
    barycenter,
    displacement_interpolation,
    wasserstein_distance,
    wasserstein_propagation,
)
from solvers.domains.mesh import TriangleMesh
from solvers.emd import earth_movers_distance, pointwise_distances
from solvers.emd.beckmann import resolve_method
from solvers.emd.green import GREEN_MAX_VERTICES
from solvers.emd.pointwise import check_cost
from solvers.errors import InputError
from solvers.kernels import GEODESIC_KERNEL_VERTICES
from solvers.regularization import (
    Regularization as RegularizationChoice,
)
from solvers.regularization import (
    kernel_substeps,
    shape_method,
    shape_regularization,
)
from solvers.transport.decision import DistanceDecision as SolverDecision
from solvers.transport.decision import decide_distance
from solvers.transport.exact import EXACT_KINDS, MAX_SUPPORT_PRODUCT
from solvers.validation import (
    GAMMA_MIN,
    check_anchored,
    check_edge_weights,
    check_edges,
)


class SinkhornOptions(OperationRequest):
    gamma: float | None = Field(None, ge=GAMMA_MIN, description="entropic regularization "
                                "(cost d^2, "
                                "unit-area units); default: the regularization policy "
                                "(solvers.regularization), reported in the result")
    substeps: Int | None = Field(None, ge=1, le=512, description="implicit Euler heat "
                                 "substeps (default: the policy's; 1 when gamma is given)")
    tol: float | None = Field(None, gt=0, lt=1, description="stopping tolerance (marginal "
                              "violation; default: the solver's)")
    max_iter: Int | None = Field(None, ge=1, le=100_000, description="default: the solver's")

    def solver_gamma(self) -> float | str:
        """``gamma`` as the solvers take it: ``"auto"`` (the regularization policy) when the
        request leaves it out."""
        return "auto" if self.gamma is None else float(self.gamma)


class W1Options(OperationRequest):
    method: Literal["auto", "ipm", "admm", "weiszfeld"] = Field(
        "auto", description="W1 solver: auto (ipm over all flows, else admm), ipm "
        "(primal-dual interior point, all flows; stops at a certified relative gap tol), "
        "ADMM (thesis Fig. 2.5) or Weiszfeld (Fig. 2.4)")
    basis: Literal["auto", "flow", "full", "spectral"] = Field(
        "auto", description="W1 flow space: auto (all piecewise-constant flows; the thesis' "
        "curl basis 'full' with matrix weights), flow, full (curl basis: an overestimate), "
        "spectral (k eigenfunctions)")
    k: Int | None = Field(None, ge=1, description="spectral basis size")
    tol: float | None = Field(None, gt=0, lt=1, description="ipm: certified relative gap; "
                              "admm: relative primal/dual residual (default: the solver's)")
    max_iter: Int | None = Field(None, ge=1, le=100_000, description="default: the solver's")


class DistanceRequest(SinkhornOptions):
    model_config = example({"mu0": BUMP_A, "mu1": BUMP_B})
    mu0: Distribution
    mu1: Distribution
    metric: Literal["w2", "w1"] = Field(
        "w2", description="w2: squared 2-Wasserstein distance (geodesic cost d^2); w1: earth "
        "mover's distance (Beckmann problem, thesis ch. 2), meshes only")
    method: Literal["auto", "convolutional", "exact"] = Field(
        "auto", description="W2 only. exact: geodesic cost matrix between the supports and "
        "the transport LP (meshes, grids, point clouds; sparse supports); convolutional: "
        "entropic W2 with heat kernels (thesis Alg. 1); auto: exact when its modelled time "
        "fits its budget, else convolutional (always convolutional when gamma is given); "
        "decided at submission from the request and the stored domain alone, shown in the "
        "job's `decision`")
    debiased: bool | None = Field(None, description="W2 convolutional: Sinkhorn divergence "
                                  "(default: the policy's choice, true; false when gamma is "
                                  "given)")
    w1_method: Literal["auto", "ipm", "admm", "weiszfeld"] = Field(
        "auto", description="W1 only: the W1 method (as `method` for flows)")
    basis: Literal["auto", "flow", "full", "spectral"] = Field(
        "auto", description="W1 flow space (as for flows)")
    k: Int | None = Field(None, ge=1, description="W1 spectral basis size")


class Regularization(BaseModel):
    """The regularization a convolutional solver used and why."""

    gamma: float
    t: float
    substeps: Int | None = Field(description="implicit-Euler substeps; null when the kernel "
                                 "that ran has none (method 'geodesic')")
    debiased: bool
    purpose: Literal["values", "shapes"]
    h: float = Field(description="length scale (mean edge length / grid spacing)")
    distance: float | None = Field(None, description="estimated transport distance (values)")
    reason: str


class DistanceDecision(BaseModel):
    """What a distance job runs, decided at submission from the request and the stored
    domain alone (solvers.transport.decision) and executed by every attempt."""

    metric: Literal["w2", "w1"]
    method: Literal["convolutional", "exact", "beckmann"]
    reason: str
    gamma: float | None = Field(None, description="convolutional: entropic regularization")
    t: float | None = Field(None, description="convolutional: heat time")
    substeps: Int | None = Field(None, description="convolutional: implicit Euler substeps")
    debiased: bool | None = Field(None, description="convolutional: Sinkhorn divergence")
    estimated_seconds: float | None = Field(None, description="modelled run time of the "
                                            "method (one core, unloaded machine)")
    exact_seconds: float | None = Field(None, description="modelled run time of the exact "
                                        "method (null where it is not available)")
    regularization: Regularization | None = Field(None, description="the policy's choice "
                                                  "(convolutional, gamma left out)")
    w1_method: Literal["ipm", "admm", "weiszfeld"] | None = Field(None, description="w1: "
                                                                  "the W1 method")
    basis: Literal["flow", "full", "spectral"] | None = Field(None, description="w1: the "
                                                              "flow space")


class DistanceResult(BaseModel):
    """Values of a distance job."""

    value: float = Field(description="W2^2 (metric w2) or W1 (metric w1)")
    metric: Literal["w2", "w1"]
    method: Literal["convolutional", "exact", "beckmann"] = Field(description="what ran")
    gamma: float | None = None
    t: float | None = None
    substeps: Int | None = None
    debiased: bool | None = None
    regularization: Regularization | None = Field(None, description="the policy's choice "
                                                  "(when gamma was left out)")
    support_sizes: list[Int] | None = Field(None, description="exact method: support sizes")
    cost_seconds: float | None = Field(None, description="exact method: geodesic cost matrix")
    lp_seconds: float | None = Field(None, description="exact method: transport LP")
    w1_method: Literal["ipm", "admm", "weiszfeld"] | None = Field(
        None, description="W1: the W1 method that ran")
    decision: DistanceDecision | None = Field(None, description="the job's decision (taken "
                                              "at submission)")
    iterations: Int
    residual: float = Field(description="w2 convolutional: L1 marginal violation; exact: "
                            "marginal violation of the plan; w1: the solver's stopping "
                            "quantity (ipm: certified relative duality gap; admm: larger "
                            "relative primal/dual residual; weiszfeld: relative change)")
    converged: bool
    normalization: list[dict]


class ConvergenceValues(BaseModel):
    iterations: Int
    residual: float = Field(description="the solver's measured stopping quantity")
    converged: bool


class ShapeValues(ConvergenceValues):
    """Values shared by barycenter, interpolation and propagation jobs."""

    gamma: float
    substeps: Int | None = Field(description="implicit-Euler substeps that ran; null with "
                                 "method 'geodesic' (its kernel has none)")
    regularization: Regularization | None = Field(None, description="the policy's choice "
                                                  "(when gamma was left out)")
    normalization: list[dict]


class ShapeMethodValues(ShapeValues):
    method: Literal["convolutional", "geodesic"] = Field(
        description="the kernel that ran (the request's 'method', 'auto' resolved)")


class BarycenterValues(ShapeMethodValues):
    weights: list[float] = Field(description="the normalized barycentric weights")
    entropy: float | None = Field(None, description="entropy of the barycenter")


class InterpolationValues(ShapeMethodValues):
    times: list[float] = Field(description="frame times; arrays are (V, len(times))")


class PropagationValues(ShapeMethodValues):
    free_nodes: list[Int] = Field(description="nodes whose distributions were propagated")


class PointwiseDistanceValues(ConvergenceValues):
    source: Int
    k: Int
    max_distance: float | None
    unreachable: Int = Field(description="vertices on other components (null distances)")
    unconverged_targets: Int = Field(0, description="k > 0: targets whose certified relative "
                                     "gap (array 'residuals') is above the tolerance")


class FlowValues(ConvergenceValues):
    value: float = Field(description="W1 (cost of the flow)")
    primal_residual: float
    dual_residual: float
    max_flow: float
    normalization: list[dict]


class ShapeMethodOption(SinkhornOptions):
    method: Literal["auto", "convolutional", "geodesic"] = Field(
        "auto", description="kernel: auto (geodesic on triangle meshes of at most "
        f"{GEODESIC_KERNEL_VERTICES} vertices, else convolutional), geodesic (exp(-d^2/gamma) "
        "of heat-method geodesics, exact in the log domain: keeps shapes sharp) or "
        "convolutional (the thesis' implicit-Euler heat kernel, Alg. 2; substeps apply)")


class BarycenterRequest(ShapeMethodOption):
    model_config = example({"distributions": [BUMP_A, BUMP_B], "weights": [0.5, 0.5]})
    distributions: list[Distribution] = Field(min_length=1, max_length=64)
    weights: list[float] | None = Field(None, description="barycentric weights (default "
                                        "uniform); normalized to sum 1")
    sharpen: bool = Field(False, description="entropic sharpening (thesis Alg. 3)")
    entropy_bound: float | None = None
    debiased: bool = False


class InterpolationRequest(ShapeMethodOption):
    model_config = example({"mu0": BUMP_A, "mu1": BUMP_B, "times": [0.0, 0.5, 1.0]})
    mu0: Distribution
    mu1: Distribution
    times: list[Annotated[float, Field(ge=0, le=1)]] = Field(min_length=1, max_length=64,
                                                            description="in [0, 1]")
    sharpen: bool = Field(False, description="entropic sharpening of each frame")
    debiased: bool = False


class FixedDistribution(BaseModel):
    """A node of the propagation graph whose distribution is given."""

    model_config = REQUEST_CONFIG
    node: Int = Field(ge=0, description="graph node whose distribution is given")
    distribution: Distribution


class PropagationRequest(ShapeMethodOption):
    model_config = example({
        "n_nodes": 3, "edges": [[0, 1], [1, 2]],
        "fixed": [{"node": 0, "distribution": BUMP_A}, {"node": 2, "distribution": BUMP_B}]})
    n_nodes: Int = Field(ge=2, le=10_000, description="nodes of the propagation graph (each "
                         "carries one distribution over the domain)")
    edges: list[NodePair] = Field(min_length=1, description="(m, 2) node pairs")
    edge_weights: list[float] | None = Field(None, description="(m,) positive weights")
    fixed: list[FixedDistribution] = Field(min_length=1, description="nodes with known "
                                           "distributions (at least one per connected piece "
                                           "of the graph)")


class PointwiseDistanceRequest(OperationRequest):
    model_config = example({"source": 0})
    source: Int = Field(ge=0, description="source vertex")
    k: Int = Field(0, ge=0, description="spectral basis size (0: exact)")


class FlowRequest(W1Options):
    model_config = example({"mu0": BUMP_A, "mu1": BUMP_B})
    mu0: Distribution
    mu1: Distribution


# -- helpers ------------------------------------------------------------------
def _pair(view: DomainView, req) -> tuple[dict[str, np.ndarray], list[dict]]:
    check_options(view, req)
    masses, reports = resolve_all(view, {"mu0": req.mu0, "mu1": req.mu1}, req.input)
    check_same_components(view, masses)
    return masses, reports


def _validate_pair(view: DomainView, req) -> list[dict]:
    return _pair(view, req)[1]


def _optional(req) -> dict:
    """tol / max_iter only when given, so the solvers' own defaults apply otherwise."""
    return {k: getattr(req, k) for k in ("tol", "max_iter") if getattr(req, k) is not None}


def shape_kwargs(domain, req, progress, should_cancel
                 ) -> tuple[dict, RegularizationChoice | None]:
    """Solver arguments of the shape operations and the policy's choice (None when the
    request gave gamma): gamma/substeps left out go through the "shapes" policy."""
    reg, gamma, substeps = shape_regularization(domain, req.gamma, None, req.substeps)
    kwargs = {"gamma": float(gamma), "substeps": int(substeps), **_optional(req),
              "progress": progress, "should_cancel": should_cancel}
    return kwargs, reg


def _w1(domain, masses, req, progress, should_cancel):
    return earth_movers_distance(domain, masses["mu0"], masses["mu1"], method=req.method,
                                 basis=req.basis, k=req.k, progress=progress,
                                 should_cancel=should_cancel, **_optional(req))


def as_ran(kwargs: dict, reg: RegularizationChoice | None, method: str) -> dict:
    """``gamma``, ``substeps`` and ``regularization`` values of a shape job as its kernel
    ``method`` ran them (the library's rule: the geodesic kernel has no substeps)."""
    return {"gamma": kwargs["gamma"], "substeps": kernel_substeps(method, kwargs["substeps"]),
            "regularization": None if reg is None else reg.for_kernel(method).as_dict()}


def _convergence(result) -> dict:
    return {"iterations": int(result.iterations), "residual": float(result.residual),
            "converged": bool(result.converged)}


# -- distances ------------------------------------------------------------------
def _distance_inputs(view: DomainView, req: DistanceRequest
                     ) -> tuple[dict[str, np.ndarray], list[dict]]:
    """``mu0`` and ``mu1`` resolved (read-only) and their normalization reports, once per
    request on ``view``: validation, memory estimate and decision share them
    (:meth:`~service.operations.base.DomainView.per_request`)."""
    return view.per_request("distance inputs", req, lambda: _read_only(_pair(view, req)))


def _read_only(pair: tuple[dict[str, np.ndarray], list[dict]]):
    for masses in pair[0].values():
        masses.flags.writeable = False  # shared by every reader of the request's inputs
    return pair


def _validate_distance(view: DomainView, req: DistanceRequest) -> list[dict]:
    from service.errors import UnsupportedOperation

    if req.metric == "w1" and not view.supports("faces"):
        raise UnsupportedOperation("metric 'w1' is available on triangle meshes only",
                                   field="metric")
    if req.metric == "w2" and req.method == "exact" and not view.supports("exact_transport"):
        raise UnsupportedOperation(f"method 'exact' is available on {', '.join(EXACT_KINDS)} "
                                   "domains; use method 'convolutional'", field="method")
    masses, reports = _distance_inputs(view, req)
    if req.metric == "w2" and req.method == "exact":
        n0, n1 = (int(np.count_nonzero(masses[k])) for k in ("mu0", "mu1"))
        if n0 * n1 > MAX_SUPPORT_PRODUCT:
            raise InvalidInput(f"method 'exact' needs a {n0} x {n1} cost matrix, above its "
                               f"limit of {MAX_SUPPORT_PRODUCT} entries; use method "
                               "'convolutional' or 'auto'", field="method")
    return reports


def decide_distance_job(view: DomainView, req: DistanceRequest) -> dict:
    """The job's decision at submission (``Operation.decide``): the W2 method and
    regularization (:func:`solvers.transport.decision.decide_distance` on the stored
    domain's sketch), or the W1 solver and flow space; taken once per request on ``view``
    (the memory and cost estimates read the same decision)."""
    return view.per_request("distance decision", req, lambda: _decide_distance(view, req))


def _decide_distance(view: DomainView, req: DistanceRequest) -> dict:
    if req.metric == "w1":
        try:
            w1_method, basis = resolve_method(req.w1_method, req.basis)
        except InputError as exc:
            field = "w1_method" if exc.field in (None, "method") else exc.field
            raise InvalidInput(str(exc), field=field) from exc
        why = "requested" if req.w1_method != "auto" else (
            "auto: the interior point over all flows" if w1_method == "ipm" else
            f"auto: ADMM for the {basis} basis")
        return DistanceDecision(metric="w1", method="beckmann", reason=why,
                                w1_method=w1_method, basis=basis).model_dump(mode="json")
    masses, _ = _distance_inputs(view, req)
    decision = decide_distance(view.sketch(), masses["mu0"], masses["mu1"], method=req.method,
                               gamma=req.solver_gamma(),
                               substeps=req.substeps, debiased=req.debiased)
    return {"metric": "w2", **decision.as_dict()}


def distance_submission_bounded(view: DomainView, req: DistanceRequest) -> bool:
    """W2 with an explicit gamma off the exact method: the decision takes no automatic choice
    (no exact-method estimate, no regularization policy), so validating and deciding is
    resolving two distributions (``Operation.bounded_submission``)."""
    return req.metric == "w2" and req.gamma is not None and req.method != "exact"


def distance_bytes(view: DomainView, req: DistanceRequest) -> int:
    """The default estimate, plus on the exact method the LP's cost matrix, plan and the
    solver's copy (support x support, three float64 arrays; two missed a fifth of a
    measured peak: bench/results/operation_memory.md)."""
    total = estimate_job_bytes(view, req)
    if req.metric == "w2" and decide_distance_job(view, req)["method"] == "exact":
        masses, _ = _distance_inputs(view, req)
        n0, n1 = (int(np.count_nonzero(masses[k])) for k in ("mu0", "mu1"))
        total += 24 * n0 * n1
    return total


def distance_cost(n: int, req: DistanceRequest, context=None) -> float:
    """The decision's own time model (``estimated_seconds``) in cost units when it has
    one, else the default (points x iterations x distributions)."""
    default = estimate_cost(n, req)
    if context is None or req.metric != "w2":
        return default
    seconds = decide_distance_job(context, req).get("estimated_seconds")
    return default if seconds is None else max(default, float(seconds) * COST_PER_SECOND)


PROPAGATION_COST_FACTOR = 3  # measured: ~3 default units per point, iteration and column


def propagation_cost(n: int, req: PropagationRequest, context=None) -> float:
    """Points x iterations x (nodes + 2 x edges): every sweep updates each node's
    distribution and both ends of each edge."""
    columns = int(req.n_nodes) + 2 * len(req.edges)
    iterations = req.max_iter or DEFAULT_ITERATIONS
    return PROPAGATION_COST_FACTOR * float(max(n, 1)) * float(iterations) * columns


def run_distance(domain, req: DistanceRequest, progress, should_cancel,
                 decision: dict | None = None) -> OperationOutput:
    """Execute the job's stored ``decision`` (taken at submission; decided here only for a
    job recorded without one): explicit solver arguments, so every worker and every
    attempt runs the same thing."""
    view = view_of_domain(domain)
    masses, reports = _distance_inputs(view, req)
    if decision is None:
        decision = decide_distance_job(view, req)
    stored = DistanceDecision.model_validate(decision)
    if req.metric == "w1":
        res = earth_movers_distance(domain, masses["mu0"], masses["mu1"],
                                    method=stored.w1_method, basis=stored.basis, k=req.k,
                                    progress=progress, should_cancel=should_cancel,
                                    **_optional(req))
        values = {"value": float(res.value), "metric": "w1", "method": "beckmann",
                  "w1_method": res.method, **_convergence(res)}
        arrays = {"flow": np.asarray(res.flow), "potential": np.asarray(res.potential)}
        export = {"fields": ["potential"], "flow": "flow", "color": "potential"}
        return OperationOutput({**values, "decision": decision, "normalization": reports},
                               arrays, export)
    plan = SolverDecision.from_dict({k: v for k, v in decision.items()
                                     if k not in ("metric", "w1_method", "basis")})
    res = wasserstein_distance(domain, masses["mu0"], masses["mu1"], **plan.solver_arguments(),
                               **_optional(req), progress=progress,
                               should_cancel=should_cancel)
    values = {"value": float(res.value), "metric": "w2", "method": res.method}
    if res.method == "exact":
        values.update(support_sizes=[len(res.sources), len(res.targets)],
                      cost_seconds=float(res.cost_seconds), lp_seconds=float(res.lp_seconds))
    else:
        reg = plan.regularization
        values.update(gamma=float(res.gamma), t=float(res.t), substeps=int(res.substeps),
                      debiased=bool(res.debiased),
                      regularization=None if reg is None else reg.as_dict())
    return OperationOutput({**values, **_convergence(res), "decision": decision,
                            "normalization": reports})


# -- barycenters --------------------------------------------------------------
def check_shape_method(view: DomainView, req) -> str:
    """The request's kernel, 'auto' resolved from the stored domain (a 4xx on 'method' where
    the domain does not offer it)."""
    try:
        return shape_method(view.sketch(), req.method)
    except InputError as exc:
        raise InvalidInput(str(exc), field="method") from exc


def kernel_bytes(view: DomainView, req) -> int:
    """Memory of the request's kernel beyond the default estimate: the geodesic kernel's
    dense matrices (none for the heat kernel's factorization, counted by the default)."""
    if check_shape_method(view, req) != "geodesic":
        return 0
    return TriangleMesh.geodesic_kernel_bytes(int(view.n))


def shape_bytes(view: DomainView, req) -> int:
    """The default estimate plus the kernel's (:func:`kernel_bytes`)."""
    return estimate_job_bytes(view, req) + kernel_bytes(view, req)


def shape_size_field(view: DomainView, req) -> str | None:
    """``method`` where the kernel's matrices are the larger part of the estimate (a 413
    names it); None leaves the request's own size field (``check_job_memory``'s rule)."""
    return "method" if kernel_bytes(view, req) > estimate_job_bytes(view, req) else None


def _barycenter_inputs(view: DomainView, req: BarycenterRequest):
    check_options(view, req)
    check_shape_method(view, req)
    return resolve_weighted(view, req.distributions, req.weights, req.input)


def _validate_barycenter(view, req) -> list[dict]:
    return _barycenter_inputs(view, req)[2]


def run_barycenter(domain, req: BarycenterRequest, progress, should_cancel) -> OperationOutput:
    mus, weights, reports = _barycenter_inputs(view_of_domain(domain), req)
    kwargs, reg = shape_kwargs(domain, req, progress, should_cancel)
    res = barycenter(domain, mus, weights, sharpen=req.sharpen, entropy_bound=req.entropy_bound,
                     debiased=req.debiased, method=req.method, **kwargs)
    masses = np.asarray(res.masses, dtype=np.float64)
    values = {**as_ran(kwargs, reg, res.method), "method": res.method,
              "weights": weights.tolist(), **_convergence(res),
              "entropy": getattr(res, "entropy", None), "normalization": reports}
    arrays = {"masses": masses, "density": masses / np.asarray(domain.areas)}
    return OperationOutput(values, arrays, {"fields": ["masses", "density"],
                                            "color": "density"})


# -- interpolations -------------------------------------------------------------
def _interpolation_inputs(view: DomainView, req: InterpolationRequest
                          ) -> tuple[dict[str, np.ndarray], list[dict]]:
    for i, t in enumerate(req.times):
        if not 0.0 <= t <= 1.0:
            raise InvalidInput(f"times[{i}] = {t} is outside [0, 1]", field=f"times[{i}]")
    check_shape_method(view, req)
    return _pair(view, req)


def _validate_interpolation(view, req: InterpolationRequest) -> list[dict]:
    return _interpolation_inputs(view, req)[1]


def run_interpolation(domain, req: InterpolationRequest, progress, should_cancel
                      ) -> OperationOutput:
    masses, reports = _interpolation_inputs(view_of_domain(domain), req)
    kwargs, reg = shape_kwargs(domain, req, progress, should_cancel)
    res = displacement_interpolation(domain, masses["mu0"], masses["mu1"], list(req.times),
                                     sharpen=req.sharpen, debiased=req.debiased,
                                     method=req.method, **kwargs)
    m = np.asarray(res.masses, dtype=np.float64).reshape(domain.n, -1)
    values = {**as_ran(kwargs, reg, res.method), "method": res.method,
              "times": list(req.times), **_convergence(res),
              "normalization": reports}
    arrays = {"masses": m, "density": m / np.asarray(domain.areas)[:, None]}
    return OperationOutput(values, arrays, {"fields": ["masses", "density"],
                                            "frames": list(req.times), "color": "density"})


# -- propagation on a graph of distributions (thesis Alg. 4) -----------------------------
def _propagation_inputs(view: DomainView, req: PropagationRequest):
    check_options(view, req)
    check_shape_method(view, req)
    if req.n_nodes < 2:
        raise InvalidInput("propagation needs at least two nodes", field="n_nodes")
    e = check_edges(req.edges, req.n_nodes, "edges")
    if len(e) == 0:
        raise InvalidInput("edges must list at least one node pair", field="edges")
    check_edge_weights(req.edge_weights, len(e), "edge_weights")
    specs, seen = {}, set()
    for i, item in enumerate(req.fixed):
        if item.node >= req.n_nodes:
            raise InvalidInput(f"fixed[{i}].node {item.node} out of range "
                               f"[0, {req.n_nodes - 1}]", field=f"fixed[{i}].node")
        if item.node in seen:
            raise InvalidInput(f"node {item.node} is fixed twice", field=f"fixed[{i}].node")
        seen.add(item.node)
        specs[f"fixed[{i}].distribution"] = item.distribution
    check_anchored(req.n_nodes, e, seen, "edges")
    masses, reports = resolve_all(view, specs, req.input)
    check_same_components(view, masses)
    fixed = {item.node: m for item, m in zip(req.fixed, masses.values(), strict=True)}
    return e, fixed, reports


def _validate_propagation(view, req) -> list[dict]:
    return _propagation_inputs(view, req)[2]


def run_propagation(domain, req: PropagationRequest, progress, should_cancel
                    ) -> OperationOutput:
    edges, fixed, reports = _propagation_inputs(view_of_domain(domain), req)
    kwargs, reg = shape_kwargs(domain, req, progress, should_cancel)
    res = wasserstein_propagation(domain, req.n_nodes, edges, fixed,
                                  edge_weights=req.edge_weights, method=req.method, **kwargs)
    m = np.asarray(res.masses, dtype=np.float64).reshape(domain.n, req.n_nodes)
    values = {**as_ran(kwargs, reg, res.method), "method": res.method,
              **_convergence(res),
              "free_nodes": np.asarray(res.free_nodes).tolist(), "normalization": reports}
    arrays = {"masses": m, "density": m / np.asarray(domain.areas)[:, None]}
    return OperationOutput(values, arrays, {"fields": ["masses", "density"],
                                            "frames": list(range(req.n_nodes)),
                                            "color": "density"})


# -- W1 on meshes ---------------------------------------------------------------
def _validate_pointwise(view, req: PointwiseDistanceRequest) -> list[dict]:
    if req.source >= view.n:
        raise InvalidInput(f"source {req.source} out of range [0, {view.n - 1}]",
                           field="source")
    check_options(view, req)
    # Refuse at submission what the solver would refuse after minutes (cost estimate).
    labels = np.asarray(view.component_labels)
    n_targets = int(np.count_nonzero(labels == labels[req.source]))
    green = req.k == 0 and view.n <= GREEN_MAX_VERTICES and 4 * n_targets >= view.n
    try:
        check_cost(view.n, view.faces_or_typical, req.k, n_targets, green)
    except InputError as exc:  # the service has no 'targets' field: the choice is k
        raise InvalidInput(str(exc), field="k") from exc
    return []


def run_pointwise(domain, req: PointwiseDistanceRequest, progress, should_cancel
                  ) -> OperationOutput:
    """d_W^k from the source to every vertex; vertices on other components are unreachable
    (reported as null distances and counted)."""
    _validate_pointwise(view_of_domain(domain), req)
    labels = np.asarray(domain.component_labels)
    targets = np.flatnonzero(labels == labels[req.source])
    res = pointwise_distances(domain, req.source, k=req.k, targets=targets, progress=progress,
             should_cancel=should_cancel)
    d = np.full(domain.n, np.inf)
    d[targets] = np.asarray(res.distances, dtype=np.float64)
    gap = np.full(domain.n, np.inf)  # per target: certified relative gap (0 for k = 0)
    gap[targets] = res.residuals
    finite = d[np.isfinite(d)]
    values = {"source": req.source, "k": req.k,
              "max_distance": float(finite.max()) if finite.size else None,
              "unreachable": int((~np.isfinite(d)).sum()),
              "unconverged_targets": int((~res.converged_targets).sum()), **_convergence(res)}
    return OperationOutput(values, {"distances": d, "residuals": gap},
                           {"fields": ["distances"], "color": "distances"})


def run_flow(domain, req: FlowRequest, progress, should_cancel) -> OperationOutput:
    masses, reports = _pair(view_of_domain(domain), req)
    res = _w1(domain, masses, req, progress, should_cancel)
    flow = np.asarray(res.flow, dtype=np.float64)
    values = {"value": float(res.value), **_convergence(res),
              "primal_residual": float(res.primal_residual),
              "dual_residual": float(res.dual_residual),
              "max_flow": float(np.linalg.norm(flow, axis=1).max()) if len(flow) else 0.0,
              "normalization": reports}
    arrays = {"flow": flow, "flow_magnitude": np.linalg.norm(flow, axis=1),
              "potential": np.asarray(res.potential, dtype=np.float64)}
    return OperationOutput(values, arrays, {"fields": ["flow_magnitude", "potential"],
                                            "flow": "flow", "color": "potential"})


FACES = "faces"  # what these operations require of a domain (Domain.supports)
OPERATIONS = [
    Operation("distances", "createDistanceJob",
              "Transport distance between two distributions (W2^2: exact LP for sparse "
              "supports or convolutional; or W1)",
              DistanceRequest, run_distance, _validate_distance, result_model=DistanceResult,
              decide=decide_distance_job, estimate_bytes=distance_bytes,
              estimate_cost=distance_cost, bounded_submission=distance_submission_bounded),
    Operation("barycenters", "createBarycenterJob",
              "Wasserstein barycenter of distributions (geodesic or convolutional kernel, "
              "optional sharpening)",
              BarycenterRequest, run_barycenter, _validate_barycenter,
              result_model=BarycenterValues, estimate_bytes=shape_bytes,
              size_field=shape_size_field),
    Operation("interpolations", "createInterpolationJob",
              "Displacement interpolation between two distributions at given times",
              InterpolationRequest, run_interpolation, _validate_interpolation,
              result_model=InterpolationValues, estimate_bytes=shape_bytes,
              size_field=shape_size_field),
    Operation("propagations", "createPropagationJob",
              "Wasserstein propagation: distributions at the free nodes of a graph from the "
              "fixed ones (thesis Alg. 4)", PropagationRequest, run_propagation,
              _validate_propagation, result_model=PropagationValues,
              estimate_cost=propagation_cost, estimate_bytes=shape_bytes,
              size_field=shape_size_field),
    Operation("pointwise-distances", "createPointwiseDistanceJob",
              "Distances from a source vertex to every vertex (W1 between Diracs)",
              PointwiseDistanceRequest, run_pointwise, _validate_pointwise, FACES,
              result_model=PointwiseDistanceValues),
    Operation("flows", "createFlowJob", "W1 optimal flow field J between two distributions",
              FlowRequest, run_flow, _validate_pair, FACES, result_model=FlowValues),
]
