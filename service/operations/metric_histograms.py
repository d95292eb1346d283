"""Histograms over the circle S¹ or a small metric space propagated by the exact LP of
thesis §5.4: ``POST /v1/domains/{id}/metric-histogram-propagations``.

The histograms live on ``B`` points: a user metric space given by its ``(B, B)`` ground
cost matrix, or ``B`` equally spaced points of a circle (cost: wrapped distance to the
``power``).  Labeled nodes of the domain's graph (graph edges; mesh and point-cloud
Laplacian weights) carry histograms; the others get those minimizing
:math:`\\sum_e w_e\\, OT_C(\\mu_u, \\mu_v)`, solved exactly with its certificate
(:func:`solvers.histograms.propagate_circular`, ``method="lp"``).  Results: the
histograms (``nodes x B``), the optimum, its dual lower bound, and per node the mode, the
entropy and the ``spread`` :math:`\\min_i \\sum_j \\mu_j C_{ij}` (circle: also the circular
mean and standard deviation), drawn on the domain.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.errors import InvalidInput
from service.operations.base import (
    REQUEST_CONFIG,
    DomainView,
    Int,
    Operation,
    OperationOutput,
    OperationRequest,
    given,
)
from service.operations.histograms import LP_TIME_LIMIT, MAX_LP_VARIABLES, _edge_count
from solvers.validation import check_anchored_components, check_cost_matrix, check_node_indices

MAX_POINTS = 512


class CircleSpace(BaseModel):
    """``points`` equally spaced points on a circle of circumference ``period``."""

    model_config = REQUEST_CONFIG
    points: Int = Field(ge=2, le=MAX_POINTS, description="points B (bin centers)")
    period: float = Field(2 * np.pi, gt=0, description="circumference (2 pi: angles)")
    power: Literal[1, 2] = Field(2, description="cost: wrapped distance to this power "
                                 "(2: W2^2 as in the thesis)")


class LabeledHistogram(BaseModel):
    model_config = REQUEST_CONFIG
    node: Int = Field(ge=0, description="node (vertex, point) index")
    histogram: list[float] = Field(min_length=2, max_length=MAX_POINTS, description="one "
                                   "non-negative mass per point (normalized by the server)")


class MetricHistogramRequest(OperationRequest):
    model_config = ConfigDict(json_schema_extra={"examples": [
        {"cost": [[0, 1, 2], [1, 0, 1], [2, 1, 0]],
         "labeled": [{"node": 0, "histogram": [1, 0, 0]},
                     {"node": 2, "histogram": [0, 0, 1]}]}], **given("cost", "circle")})
    labeled: list[LabeledHistogram] = Field(min_length=1, max_length=100_000,
                                            description="at least one per connected "
                                            "component")
    cost: list[list[float]] | None = Field(None, min_length=2, max_length=MAX_POINTS,
                                           description="(B, B) ground cost between the "
                                           "points: symmetric, zero diagonal, >= 0; exactly "
                                           "one of cost and circle")
    circle: CircleSpace | None = Field(None, description="points on S¹")
    lp_method: Literal["auto", "hybrid", "simplex"] = Field(
        "auto", description="start of the LP's column generation (same optimum and "
        "certificate): auto, hybrid (interior point), simplex")


class MetricHistogramValues(BaseModel):
    """Values of a metric-histogram-propagation job."""

    space: Literal["metric", "circle"]
    points: Int
    n_nodes: Int
    n_labeled: Int
    value: float = Field(description="sum_e w_e OT_C(mu_u, mu_v) of the result (LP optimum)")
    lower_bound: float = Field(description="dual bound over all plan entries")
    certified: bool = Field(description="value - lower_bound <= 1e-7 max(1, |value|)")
    plan_entries: Int
    lp_method: str
    iterations: Int = Field(description="column-generation rounds")
    residual: float = Field(description="largest constraint violation")
    converged: bool
    arrays: list[str]


def _space(req: MetricHistogramRequest):
    """``(bins, cost)`` of the request's space."""
    from solvers.histograms import circle_cost, make_bins

    if (req.cost is None) == (req.circle is None):
        raise InvalidInput("give exactly one of cost and circle", field="cost")
    if req.circle is not None:
        c = req.circle
        bins = make_bins(lo=0.0, hi=c.period, count=c.points, periodic=True, field="circle")
        return bins, circle_cost(bins, float(c.power))
    if any(len(row) != len(req.cost) for row in req.cost):
        raise InvalidInput("cost must be a square matrix", field="cost")
    cost = check_cost_matrix(req.cost, "cost", max_size=MAX_POINTS)
    return make_bins(lo=0.0, hi=float(len(cost)), count=len(cost), field="cost"), cost


def _inputs(view: DomainView, req: MetricHistogramRequest):
    from solvers.histograms import check_histograms

    bins, cost = _space(req)
    nodes = check_node_indices([item.node for item in req.labeled], view.n, "labeled")
    check_anchored_components(view.component_labels, nodes, "labeled")
    hists = np.vstack([check_histograms(item.histogram, bins.count,
                                        f"labeled[{i}].histogram")
                       for i, item in enumerate(req.labeled)])
    m = _edge_count(view)
    if m is not None and m * bins.count**2 > MAX_LP_VARIABLES:
        raise InvalidInput(f"the LP would have {m} x {bins.count}^2 variables (at most "
                           f"{MAX_LP_VARIABLES}); use fewer points",
                           field="cost" if req.cost is not None else "circle.points")
    return bins, cost, nodes, hists


def validate(view: DomainView, req: MetricHistogramRequest) -> list[dict]:
    _inputs(view, req)
    return []


LP_ENTRY_COST = 20_000.0


def estimate_cost(n: int, req: MetricHistogramRequest, context=None) -> float:
    """Nodes x B^2 plan entries per edge (about 3 edges per node) x ``LP_ENTRY_COST`` (the LP
    solver's work per entry, measured: bench/results/operation_memory.md)."""
    b = len(req.cost) if req.cost is not None else req.circle.points if req.circle else 2
    return LP_ENTRY_COST * float(max(n, 1)) * float(b) ** 2


def estimate_bytes(view: DomainView, req: MetricHistogramRequest) -> int:
    b = len(req.cost) if req.cost is not None else req.circle.points if req.circle else 2
    m = _edge_count(view) or 3 * view.n
    # the LP's matrix, factors and solver state per plan entry (measured up to ~115 float64
    # each, the most on the smaller mesh's harder LP: bench/results/operation_memory.md),
    # the histograms
    return 8 * 120 * int(m) * b * b + 8 * 8 * int(view.n) * b


def _node_summaries(H: np.ndarray, cost: np.ndarray, bins, circle: bool) -> dict:
    p = H / H.sum(axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        entropy = -np.sum(np.where(p > 0, p * np.log(p), 0.0), axis=1)
    out = {"mode": np.argmax(p, axis=1).astype(np.float64), "entropy": entropy,
           "spread": (p @ cost.T).min(axis=1)}
    if circle:
        from solvers.histograms import summarize

        s = summarize(H, bins)
        out.update(circular_mean=np.asarray(s["mean"]), circular_std=np.asarray(s["std"]))
    return out


def run(domain, req: MetricHistogramRequest, progress, should_cancel) -> OperationOutput:
    from service.operations.base import view_of_domain
    from solvers.histograms import propagate_circular

    bins, cost, nodes, hists = _inputs(view_of_domain(domain), req)
    res = propagate_circular(domain, nodes, hists, bins=bins, cost=cost, method="lp",
                             lp_method=req.lp_method, time_limit=req.time_limit or LP_TIME_LIMIT,
                             progress=progress, should_cancel=should_cancel)
    H = np.asarray(res.histograms, dtype=np.float64)
    circle = req.circle is not None
    arrays = {"histograms": H, **_node_summaries(H, cost, bins, circle), "labeled": nodes,
              "cost": cost}
    values = MetricHistogramValues(
        space="circle" if circle else "metric", points=int(bins.count), n_nodes=int(len(H)),
        n_labeled=int(len(nodes)), value=float(res.value), lower_bound=float(res.lower_bound),
        certified=bool(res.certified), plan_entries=int(res.plan_entries),
        lp_method=str(res.lp_method), iterations=int(res.iterations), residual=float(res.residual),
        converged=bool(res.converged), arrays=sorted(arrays)).model_dump()
    fields = ["circular_mean", "circular_std"] if circle else ["spread", "mode", "entropy"]
    return OperationOutput(values, arrays, {"fields": fields, "color": fields[0]})


OPERATIONS = [
    Operation("metric-histogram-propagations", "createMetricHistogramPropagationJob",
              "Propagate histograms over S¹ or a small metric space (user cost matrix) from "
              "labeled nodes by the exact LP of thesis §5.4, certified",
              MetricHistogramRequest, run, validate,
              "histogram_propagation",
              result_model=MetricHistogramValues, estimate_bytes=estimate_bytes,
              estimate_cost=estimate_cost),
]
