r"""Wasserstein diffusion of histograms on a graph (thesis Prop. 16, §5.3.3).

The gradient flow of the Dirichlet energy :math:`\sum_{uv} w_{uv} W_2^2(\mu_u, \mu_v)` on
Prob(ℝ) is the heat equation on the inverse CDFs, level by level:
:math:`\partial_t g(\cdot, s) = \Delta g(\cdot, s)`.  It is integrated by implicit
(backward Euler) heat steps :math:`g_t = (M + \tfrac{t}{k} \mathcal{L})^{-k} M g_0`
(``k = substeps``; ``M = I`` on graphs and weight matrices, the lumped areas on meshes,
point clouds and grids), one factorization per time, applied to all ``m`` levels at once.
The PDF baseline applies the same steps to the histograms themselves: mixtures, which
flatten, while Wasserstein diffusion moves and averages the quantiles and keeps each
node's spread.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from solvers.domains.base import Domain
from solvers.errors import InputError
from solvers.histograms.bins import check_histograms, make_bins
from solvers.histograms.graphs import graph_laplacian
from solvers.histograms.quantiles import (
    histograms_from_inverse_cdf,
    inverse_cdf_from_histograms,
    quantile_levels,
)
from solvers.kernels import ImplicitEulerHeatKernel
from solvers.monitor import Monitor, SolverResult
from solvers.validation import check_choice, check_int, check_positive


@dataclass(kw_only=True)
class HistogramDiffusionResult(SolverResult):
    """Result of :func:`diffuse_histograms`.

    Attributes
    ----------
    method : {"wasserstein", "pdf"}
        The method used.
    times : (T,) array
        The diffusion times.
    histograms : (T, n, B) array
        Histograms at each time.
    quantiles : (T, n, m) array or None
        Inverse CDFs at each time (Wasserstein method, else ``None``).
    levels : (m,) array or None
        Their quantile levels.
    bins : Bins
        The bins.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`); ``residual`` is the
        largest row-sum error of the histograms.
    """

    method: str
    times: np.ndarray
    histograms: np.ndarray
    quantiles: np.ndarray | None
    levels: np.ndarray | None
    bins: object


def _kernel(graph, t: float, substeps: int, laplacian: str):
    L = graph_laplacian(graph, laplacian)
    mass = graph.heat_mass if isinstance(graph, Domain) else np.ones(L.shape[0])
    build = lambda: ImplicitEulerHeatKernel(mass, L, t, substeps)  # noqa: E731
    if isinstance(graph, Domain):
        return graph.operators.get(("histograms.diffusion", laplacian, t, substeps), build)
    return build()


def diffuse_histograms(graph, histograms, times, *, bins, method: Literal["wasserstein", "pdf"]
                       = "wasserstein", levels: int = 100, substeps: int = 1,
                       laplacian: str = "auto", progress=None, should_cancel=None
                       ) -> HistogramDiffusionResult:
    r"""Diffuse one histogram per node for each time in ``times`` (Prop. 16, §5.3.3).

    ``method="wasserstein"``: the gradient flow of the Dirichlet energy in :math:`W_2` is
    the heat equation on the inverse CDFs :math:`g` (Prop. 16), integrated by implicit
    steps :math:`g_t = (M + \tfrac{t}{k} \mathcal{L})^{-k} M g_0` (``k = substeps``);
    ``"pdf"``: the same steps on the histograms.
    ``t = 0`` returns the input.

    Parameters
    ----------
    graph : Graph, TriangleMesh, PointCloud, Grid or (n, n) sparse matrix
        The domain, or a symmetric non-negative weight matrix (see :mod:`.graphs`).
    histograms : (n, B) array
        One histogram per node.
    times : (T,) array
        Non-negative diffusion times.
    bins : Bins or (B + 1,) array
        The bins, or their edges.
    method : {"wasserstein", "pdf"}
        Diffuse inverse CDFs, or histograms bin by bin.
    levels : int
        Number ``m`` of quantile levels.
    substeps : int
        Implicit steps per time interval.
    laplacian : {"auto", "robust", "cotan"}
        The Laplacian of a mesh (cotangent or robust); other domains have one.
    progress, should_cancel : callable, optional
        As in :func:`~solvers.histograms.propagate_histograms`.

    Returns
    -------
    HistogramDiffusionResult
        ``histograms`` ``(T, n, B)``; ``residual`` the largest row-sum error (mass
        conservation, measured).
    """
    check_choice(method, ("wasserstein", "pdf"), "method")
    b = make_bins(bins)
    if b.periodic:
        raise InputError("Wasserstein diffusion is defined here on Prob(R); periodic bins are "
                         "not supported", field="bins.periodic")
    L = graph_laplacian(graph, laplacian)
    n = L.shape[0]
    h = check_histograms(histograms, b.count, "histograms")
    if len(h) != n:
        raise InputError(f"histograms needs one row per node ({n}), got {len(h)}",
                         field="histograms")
    try:
        ts = np.asarray(times, dtype=np.float64).ravel()
    except (TypeError, ValueError) as exc:
        raise InputError("times must be numbers", field="times") from exc
    if ts.size == 0 or not np.all(np.isfinite(ts)) or np.any(ts < 0):
        raise InputError("times must be a non-empty list of finite non-negative numbers",
                         field="times")
    substeps = check_int(substeps, "substeps", low=1, high=1000)
    monitor = Monitor(progress, should_cancel)
    lev = quantile_levels(levels) if method == "wasserstein" else None
    g0 = inverse_cdf_from_histograms(h, b, lev) if method == "wasserstein" else h
    out_h, out_q = [], []
    for i, t in enumerate(ts):
        monitor.check_cancel(f"at time {t:g}")
        if t == 0:
            g = g0.copy()
        else:
            g = _kernel(graph, check_positive(t, f"times[{i}]"), substeps, laplacian).apply(g0)
        if method == "wasserstein":
            g = np.sort(g, axis=1)
            out_q.append(g)
            out_h.append(histograms_from_inverse_cdf(g, lev, b))
        else:
            out_h.append(np.clip(g, 0.0, None))
        monitor(i, 0.0)
    H = np.stack(out_h)
    residual = float(np.abs(H.sum(axis=2) - 1.0).max())
    H /= H.sum(axis=2, keepdims=True)
    return HistogramDiffusionResult(method=method, times=ts, histograms=H,
                                    quantiles=np.stack(out_q) if out_q else None, levels=lev,
                                    bins=b, iterations=len(ts), residual=residual,
                                    converged=residual <= 1e-8)
