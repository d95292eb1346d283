r"""Exact W2 for sparse supports: a geodesic cost matrix and the transport LP.

.. math::  W_2^2(\mu_0, \mu_1) = \min_{\pi \ge 0,\ \pi 1 = m_0,\ \pi^\top 1 = m_1}
           \textstyle\sum_{ij} d(x_i, y_j)^2\, \pi_{ij}

over the support points ``x_i`` of ``mu0`` and ``y_j`` of ``mu1`` only (thesis eq. 1.1,
the discrete Kantorovich problem the convolutional solvers regularize).  ``d`` is the exact
polyhedral geodesic distance on meshes (:func:`solvers.geodesics.geodesic_distances`: one
exact one-to-all solve from each point of the smaller support), the Euclidean distance on
grids (the metric whose Gaussian the grid heat kernel is; periodic axes wrap) and on point
clouds; the LP is POT's network simplex (``ot.emd``).  No entropic bias, no heat-kernel
discretization: the value is the discrete transport cost itself.

The cost is one geodesic solve per support point and an LP of size ``n0 × n1``, so the route
is for sparse inputs (point masses, few scattered points); :func:`exact_route_seconds`
estimates it before it runs and :func:`~solvers.convolutional.distance.wasserstein_distance`
(``route="auto"``) takes it when the estimate is below :data:`AUTO_SECONDS`.  Measured
accuracy and times against the convolutional route: ``bench/results/convolutional.md``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from solvers.errors import InputError
from solvers.monitor import Monitor, SolverResult

# route="auto" takes the exact route when its estimated time is below this (seconds), and
# falls back to the convolutional route when the cost matrix takes longer than
# AUTO_BUDGET_SECONDS after all ...
AUTO_SECONDS = 5.0
AUTO_BUDGET_SECONDS = 20.0
# ... and refuses route="exact" above this (the LP's dense n0 x n1 cost matrix).
MAX_SUPPORT_PRODUCT = 25_000_000
EXACT_KINDS = ("mesh", "grid", "pointcloud")


class RouteTimeout(Exception):
    """The exact route's cost matrix ran past its ``time_budget`` (route="auto" then falls
    back to the convolutional route)."""


@dataclass(kw_only=True)
class ExactTransportResult(SolverResult):
    r"""Result of :func:`exact_wasserstein_distance`.

    ``value``: :math:`W_2^2` (squared distance units, unit area on meshes); ``sources``,
    ``targets``: support indices of ``mu0`` and ``mu1``; ``plan``: ``(len(sources),
    len(targets))`` optimal coupling; ``residual``: L1 marginal violation of ``plan``;
    ``cost_seconds``/``lp_seconds``: time of the cost matrix and of the LP.
    """

    value: float
    sources: np.ndarray
    targets: np.ndarray
    plan: np.ndarray = field(repr=False)
    cost_seconds: float = 0.0
    lp_seconds: float = 0.0
    route: str = "exact"


def supports_exact(domain) -> bool:
    """Whether the exact route is available on ``domain`` (meshes, grids, point clouds)."""
    return getattr(domain, "kind", None) in EXACT_KINDS


def exact_route_seconds(domain, n0: int, n1: int) -> float:
    """Estimated seconds of the exact route for supports of ``n0`` and ``n1`` points
    (geodesic solves plus network simplex; fitted on the shared meshes, 2 cores)."""
    lp = 2e-8 * float(n0) * float(n1) * np.log2(max(n0 * n1, 2))
    if getattr(domain, "kind", None) == "mesh":
        from solvers.geodesics import cost_estimate

        return cost_estimate(domain, n0, n1, "mmp") + lp
    return lp + 1e-8 * float(n0) * float(n1)


def _cost_matrix(domain, src: np.ndarray, dst: np.ndarray, should_cancel=None) -> np.ndarray:
    kind = domain.kind
    if kind == "mesh":
        from solvers.geodesics import geodesic_distances

        return geodesic_distances(domain, src, dst, route="mmp",
                                  should_cancel=should_cancel) ** 2
    pts = np.asarray(domain.points, dtype=np.float64)
    diff = pts[src][:, None, :] - pts[dst][None, :, :]
    if kind == "grid" and any(domain.periodic):
        width = domain.bounds[:, 1] - domain.bounds[:, 0]
        for ax, per in enumerate(domain.periodic):
            if per:
                diff[..., ax] -= width[ax] * np.round(diff[..., ax] / width[ax])
    return np.einsum("ijk,ijk->ij", diff, diff)


def exact_wasserstein_distance(
    domain,
    mu0,
    mu1,
    *,
    max_iter: int = 10_000_000,
    time_budget: float | None = None,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> ExactTransportResult:
    r"""Exact :math:`W_2^2` between ``mu0`` and ``mu1`` (module docstring).

    Parameters
    ----------
    domain : a TriangleMesh, Grid or PointCloud.
    mu0, mu1 : ``(n,)`` masses (normalized here); their supports set the LP size.
    max_iter : network-simplex iteration cap; when hit, ``converged`` is False.
    time_budget : seconds; a cost matrix running, or projected at its measured rate to run,
        past it raises :class:`RouteTimeout` (``route="auto"`` falls back to the
        convolutional route).
    progress, should_cancel : called between the geodesic solves and before the LP.

    Returns
    -------
    ExactTransportResult(value, sources, targets, plan, iterations, residual, converged, ...)
    """
    import ot

    from solvers.convolutional.common import check_components, distribution_pair

    if not supports_exact(domain):
        raise InputError(f"the exact route needs a mesh, grid or point cloud, not a "
                         f"{getattr(domain, 'kind', type(domain).__name__)}", field="route")
    m0, m1 = distribution_pair(domain, mu0, mu1)
    check_components(domain, np.stack([m0, m1], axis=1), 1e-9, "mu1")
    src, dst = np.flatnonzero(m0 > 0), np.flatnonzero(m1 > 0)
    if len(src) * len(dst) > MAX_SUPPORT_PRODUCT:
        raise InputError(f"the exact route's LP has {len(src)} x {len(dst)} entries, above "
                         f"its limit of {MAX_SUPPORT_PRODUCT}; use route='convolutional'",
                         field="route")
    monitor = Monitor(progress, should_cancel)
    monitor(0, float("nan"))
    start = time.perf_counter()
    solves = min(len(src), len(dst))
    calls = [0]

    def stop() -> bool:  # before each geodesic solve: the caller's cancel, then the budget
        if should_cancel is not None and should_cancel():
            return True
        if time_budget is not None:
            elapsed, done = time.perf_counter() - start, calls[0]
            projected = elapsed / done * solves if done else 0.0  # at the measured rate
            if elapsed > time_budget or (done >= 2 and projected > time_budget):
                raise RouteTimeout(f"exact route projected past its {time_budget:.0f} s "
                                   "budget")
        calls[0] += 1
        return False

    cost = _cost_matrix(domain, src, dst, stop)
    cost_seconds = time.perf_counter() - start
    monitor.check_cancel("before the transport LP")
    a, b = m0[src], m1[dst]
    finite = np.isfinite(cost)
    if not finite.all():  # other components: matching component masses make them unused
        cost = np.where(finite, cost, 10.0 * float(cost[finite].max(initial=0.0)) + 1.0)
    start = time.perf_counter()
    plan, log = ot.emd(a, b, cost, numItermax=int(max_iter), log=True)
    lp_seconds = time.perf_counter() - start
    residual = float(np.abs(plan.sum(axis=1) - a).sum() + np.abs(plan.sum(axis=0) - b).sum())
    converged = int(log.get("result_code", 0)) == 1
    value = float(np.sum(plan[finite] * cost[finite]))
    monitor(1, residual)
    return ExactTransportResult(value=value, sources=src, targets=dst, plan=plan,
                                iterations=1, residual=residual, converged=converged,
                                cost_seconds=cost_seconds, lp_seconds=lp_seconds)
