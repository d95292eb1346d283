"""Propagation of histograms along a graph, mesh or point cloud (thesis ch. 5).

``POST /v1/domains/{id}/histogram-propagations``: labeled nodes carry histograms over bins
(or raw samples); the other nodes get theirs by Wasserstein propagation (inverse CDFs,
Prop. 13), PDF propagation (bin by bin), or Wasserstein diffusion (Prop. 16) at given
times. Periodic bins (angles, S¹) go through the LP of §5.4 or its entropic version.
Validation at submission calls the same library validators the worker runs.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.errors import InvalidInput, PayloadTooLarge
from service.operations.base import (
    REQUEST_CONFIG,
    DomainView,
    Int,
    Operation,
    OperationOutput,
    OperationRequest,
    estimate_job_bytes,
    given,
)
from service.operations.examples import example
from solvers.histograms import (
    Bins,
    diffuse_histograms,
    histogram_of_samples,
    make_bins,
    propagate_circular,
    propagate_histograms,
    summarize,
)
from solvers.histograms.bins import check_histograms, check_samples
from solvers.validation import check_anchored_components, check_node_indices

MAX_BINS = 4096
MAX_OUTPUT_VALUES = 50_000_000  # nodes x bins (x times) of the returned histograms
MAX_LP_VARIABLES = 2_000_000  # edges x bins^2 of the S¹ linear program (before the
# column generation keeps a band of them): beyond, use the entropic algorithm
LP_TIME_LIMIT = 600.0  # seconds given to HiGHS when the request sets no time_limit


class BinsSpec(BaseModel):
    model_config = ConfigDict(**REQUEST_CONFIG,
                              json_schema_extra=given("edges", ("lo", "hi", "count")))
    edges: list[float] | None = Field(None, min_length=2, max_length=MAX_BINS + 1,
                                      description="strictly increasing bin edges (B + 1)")
    lo: float | None = Field(None, description="with hi and count: equal-width bins")
    hi: float | None = None
    count: Int | None = Field(None, ge=1, le=MAX_BINS)
    periodic: bool = Field(False, description="the axis is a circle of period hi - lo "
                           "(angles): propagation by the LP of §5.4 or its entropic version")


class LabeledNode(BaseModel):
    model_config = REQUEST_CONFIG
    node: Int = Field(ge=0, description="node (vertex, point) index")
    histogram: list[float] | None = Field(None, description="one non-negative value per bin "
                                          "(normalized by the server)")
    samples: list[float] | None = Field(None, min_length=1, description="raw values; the "
                                        "node's distribution is their empirical one")


class HistogramPropagationRequest(OperationRequest):
    model_config = example({
        "bins": {"lo": 0.0, "hi": 1.0, "count": 8},
        "labeled": [{"node": 0, "histogram": [4, 2, 1, 0, 0, 0, 0, 0]},
                    {"node": 100, "samples": [0.7, 0.8, 0.85, 0.9]}]})
    bins: BinsSpec
    labeled: list[LabeledNode] = Field(min_length=1, max_length=200_000, description="at "
                                       "least one per connected component")
    method: Literal["wasserstein", "pdf", "diffusion"] = Field(
        "wasserstein", description="wasserstein: inverse-CDF propagation (Prop. 13; on "
        "periodic bins the §5.4 problem); pdf: bin-by-bin harmonic propagation (baseline); "
        "diffusion: Wasserstein diffusion (Prop. 16) of the propagated histograms for each "
        "of `times`")
    times: list[float] | None = Field(None, min_length=1, max_length=32, description="heat "
                                      "times (method diffusion), >= 0")
    substeps: Int = Field(1, ge=1, le=100, description="implicit Euler steps per time")
    levels: Int = Field(100, ge=2, le=2000, description="quantile levels m")
    laplacian: Literal["auto", "robust", "cotan"] = Field(
        "auto", description="mesh weights: robust (intrinsic Delaunay) or cotangent")
    periodic_method: Literal["lp", "entropic"] = Field(
        "lp", description="periodic bins: exact LP (HiGHS) or entropic (thesis Alg. 4 on a "
        "periodic 1-D grid, with its exact objective reported)")
    gamma: float | None = Field(None, gt=0, description="entropic regularization (periodic "
                                "bins, periodic_method entropic); default (2 w)^2, w the bin width")
    tol: float | None = Field(None, gt=0, lt=1, description="entropic stopping tolerance")
    color: Literal["mean", "std"] = Field("mean", description="field coloring result.glb")
    max_iter: Int | None = Field(None, ge=1, le=100_000)


class HistogramPropagationValues(BaseModel):
    """``values`` of a histogram-propagation result."""

    method: str
    periodic_method: str | None = Field(None, description="lp | entropic (periodic bins)")
    bins: dict = Field(description="{edges, periodic}")
    n_nodes: Int
    n_labeled: Int
    levels: Int | None = None
    times: list[float] | None = None
    linear_method: str | None = Field(None, description="linear solver of the Dirichlet "
                                      "problem: direct | amg")
    rank: Int | None = Field(None, description="columns solved after compression")
    compression_error: float | None = None
    iterations: Int
    residual: float
    converged: bool
    value: float | None = Field(None, description="periodic bins: the exact objective "
                                "sum_e w_e W2^2 of the result")
    lp_value: float | None = None
    gap: float | None = None
    mean_range: list[float] = Field(description="[min, max] of the per-node means")
    arrays: list[str] = Field(description="result arrays: histograms (nodes x bins; for "
                              "diffusion nodes x (times*bins), time-major), mean, std, "
                              "entropy, mode (per node; per node and time for diffusion)")


# -- inputs ---------------------------------------------------------------------------
def _bins(req: HistogramPropagationRequest) -> Bins:
    spec = req.bins
    return make_bins(spec.edges, lo=spec.lo, hi=spec.hi, count=spec.count,
                     periodic=spec.periodic, field="bins")


def _inputs(view: DomainView, req: HistogramPropagationRequest):
    """Bins, labeled nodes and label histograms (and samples), validated; raises 4xx."""
    bins = _bins(req)
    times = len(req.times) if req.times else 1
    if view.n * bins.count * times > MAX_OUTPUT_VALUES:
        raise PayloadTooLarge(f"the result would hold {view.n} x {bins.count} x {times} "
                              f"values (at most {MAX_OUTPUT_VALUES})", field="bins")
    nodes = check_node_indices([item.node for item in req.labeled], view.n, "labeled")
    check_anchored_components(view.component_labels, nodes, "labeled")
    hists, samples = [], []
    for i, item in enumerate(req.labeled):
        field = f"labeled[{i}]"
        if (item.histogram is None) == (item.samples is None):
            raise InvalidInput(f"{field} needs exactly one of histogram or samples",
                               field=f"{field}.histogram")
        if item.histogram is not None:
            h = check_histograms(item.histogram, bins.count, f"{field}.histogram")[0]
            hists.append(h)
            samples.append(None)
        else:
            x = check_samples(item.samples, bins, f"{field}.samples")
            hists.append(histogram_of_samples(x, bins))
            samples.append(x)
    if req.method == "diffusion":
        if not req.times:
            raise InvalidInput("method 'diffusion' needs times", field="times")
        for i, t in enumerate(req.times):
            if not (np.isfinite(t) and t >= 0):
                raise InvalidInput(f"times[{i}] must be finite and >= 0", field=f"times[{i}]")
        if bins.periodic:
            raise InvalidInput("method 'diffusion' is defined on the line; periodic bins are "
                               "not supported", field="bins.periodic")
    elif req.times is not None:
        raise InvalidInput("times apply to method 'diffusion' only", field="times")
    if bins.periodic and req.method == "wasserstein":
        if req.periodic_method == "entropic" and not np.allclose(bins.widths, bins.widths[0]):
            raise InvalidInput("periodic_method 'entropic' needs equal-width bins",
                               field="bins.edges")
        if req.periodic_method == "lp":
            m = _edge_count(view)
            if m is not None and m * bins.count**2 > MAX_LP_VARIABLES:
                raise InvalidInput(f"the LP would have {m} x {bins.count}^2 variables (at most "
                                   f"{MAX_LP_VARIABLES}); use periodic_method 'entropic' or "
                                   "fewer bins", field="periodic_method")
    return bins, nodes, np.stack(hists), samples


def _edge_count(view: DomainView) -> int | None:
    if view.edges is not None:
        return int(len(view.edges))
    if view.n_faces is not None:
        return int(view.n_faces) * 3 // 2 + 3  # a triangle mesh: about 3F/2 edges
    return None


def _validate(view: DomainView, req: HistogramPropagationRequest) -> list[dict]:
    _inputs(view, req)
    return []


# -- run --------------------------------------------------------------------------------
def _summary_arrays(H: np.ndarray, bins: Bins) -> dict[str, np.ndarray]:
    return {k: np.asarray(v, dtype=np.float64) for k, v in summarize(H, bins).items()}


def run(domain, req: HistogramPropagationRequest, progress, should_cancel) -> OperationOutput:
    from service.operations.base import view_of_domain

    bins, nodes, hists, samples = _inputs(view_of_domain(domain), req)
    extra: dict = {}
    if bins.periodic and req.method == "wasserstein":
        kwargs = {k: getattr(req, k) for k in ("gamma", "tol", "max_iter")
                  if getattr(req, k) is not None}
        res = propagate_circular(domain, nodes, hists, bins=bins, method=req.periodic_method,
                                 time_limit=req.time_limit or LP_TIME_LIMIT, progress=progress,
                                 should_cancel=should_cancel, **kwargs)
        H = res.histograms
        extra = {"periodic_method": res.method, "value": res.value, "lp_value": res.lp_value,
                 "gap": res.gap}
    else:
        method = "pdf" if req.method == "pdf" else "wasserstein"
        # samples keep their exact empirical inverse CDF when every label is given as
        # samples; otherwise (and for the PDF method) every label is its histogram
        if method == "wasserstein" and all(s is not None for s in samples):
            labels = {"samples": samples}
        else:
            labels = {"histograms": hists}
        res = propagate_histograms(domain, nodes, bins=bins, method=method, levels=req.levels,
                                   laplacian=req.laplacian, progress=progress,
                                   should_cancel=should_cancel, **labels)
        H = res.histograms
        extra = {"linear_method": res.linear_method, "rank": res.rank,
                 "compression_error": res.compression_error,
                 "levels": req.levels if method == "wasserstein" else None}
    iterations, residual, converged = res.iterations, res.residual, res.converged
    if req.method == "diffusion":
        diff = diffuse_histograms(domain, H, req.times, bins=bins, levels=req.levels,
                                  substeps=req.substeps, laplacian=req.laplacian,
                                  progress=progress, should_cancel=should_cancel)
        T = len(req.times)
        stack = diff.histograms  # (T, n, B)
        sums = [_summary_arrays(stack[t], bins) for t in range(T)]
        arrays = {"histograms": np.concatenate(list(stack), axis=1)}
        for name in sums[0]:
            arrays[name] = np.stack([s[name] for s in sums], axis=1)
        residual = max(float(residual), float(diff.residual))
        converged = bool(converged and diff.converged)
        export = {"fields": ["mean", "std"], "color": req.color, "frames": list(req.times)}
    else:
        arrays = {"histograms": H, **_summary_arrays(H, bins)}
        export = {"fields": ["mean", "std"], "color": req.color}
    arrays["labeled"] = nodes
    mean = arrays["mean"]
    values = {"method": req.method, "bins": bins.to_dict(), "n_nodes": int(len(H)),
              "n_labeled": int(len(nodes)), "times": req.times, "iterations": int(iterations),
              "residual": float(residual), "converged": bool(converged),
              "mean_range": [float(np.min(mean)), float(np.max(mean))],
              "arrays": sorted(arrays), **extra}
    return OperationOutput(values, arrays, export)


def estimate_bytes(view: DomainView, req: HistogramPropagationRequest) -> int:
    """The default estimate plus ~32 float64 per node and bin (the propagation's per-bin
    fields and their sweeps; measured: bench/results/operation_memory.md)."""
    spec = req.bins
    bins = len(spec.edges) - 1 if spec.edges is not None else int(spec.count or 1)
    return estimate_job_bytes(view, req) + 8 * 32 * int(view.n) * max(bins, 1)


OPERATIONS = [
    Operation("histogram-propagations", "createHistogramPropagationJob",
              "Propagate histograms from labeled nodes to every node (Wasserstein "
              "propagation of thesis ch. 5, PDF baseline, Wasserstein diffusion; S¹ bins)",
              HistogramPropagationRequest, run, _validate,
              requires="histogram_propagation",
              result_model=HistogramPropagationValues, estimate_bytes=estimate_bytes),
]
