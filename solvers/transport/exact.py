r"""Exact W2 for sparse supports: a geodesic cost matrix and the transport LP.

.. math::  W_2^2(\mu_0, \mu_1) = \min_{\pi \ge 0,\ \pi 1 = m_0,\ \pi^\top 1 = m_1}
           \textstyle\sum_{ij} d(x_i, y_j)^2\, \pi_{ij}

over the support points ``x_i`` of ``mu0`` and ``y_j`` of ``mu1`` only (thesis eq. 1.1,
the discrete Kantorovich problem the convolutional solvers regularize).  ``d`` is the exact
polyhedral geodesic distance on meshes (MMP, :mod:`solvers.geodesics`), the Euclidean
distance on grids (the metric whose Gaussian the grid heat kernel is; periodic axes wrap) and
on point clouds; the LP is POT's network simplex (``ot.emd``).  No entropic bias, no
heat-kernel discretization: the value is the discrete transport cost itself.

Meshes: distances only as far as the optimal plan needs them.  An exact one-to-all solve
costs ~``n^1.7`` (10-20 s on the 35k-50k shared meshes), but one stopped at a radius ``R``
costs about the area it covers, and the optimal plan of scattered points only links nearby
points.  So, from each point ``x_i`` of the smaller support: a bound ``R_i`` (the edge-path
length, an upper bound of ``d``, to the targets of ``x_i`` in the LP on squared edge-path
lengths), exact distances up to ``R_i`` (MMP stopped there), and the LP on the *lower
bounds* ``L_ij = d_ij`` where known, ``max(R_i, |x_i - y_j|)`` where ``d_ij > R_i``.  If its
optimal plan uses only known entries, its value is that plan's true cost, which no plan can
beat (``L <= d`` entrywise): it is the exact W2².  Otherwise the bounds of the rows that use
an unknown entry grow to cover it and the loop repeats (at most until every entry is known).

The cost is one (bounded) geodesic solve per point of the smaller support and an LP of size
``n0 × n1``, so the method is for sparse inputs (point masses, few scattered points) and small
meshes; :func:`exact_route_estimate` models its time from the stored domain alone (sizes,
edge paths, constants calibrated offline by ``bench/distance_routes.py``), and the default
decision of a distance (:mod:`solvers.transport.decision`) takes the method when that
estimate fits its budget.  Measured accuracy and times: ``bench/results/distance_routes.md``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from solvers.domains import kinds_supporting, supports
from solvers.errors import InputError
from solvers.monitor import Monitor, SolverResult

# The method refuses supports whose LP has more entries than this (its dense n0 x n1 cost
# matrix).
MAX_SUPPORT_PRODUCT = 25_000_000
# Meshes: each solve bound is the edge-path length it must cover times BOUND_MARGIN; the
# triangle-inequality lower bounds are used while rows^2 x columns stays below
# TRIANGLE_ENTRIES (homer's near bumps, 435 x 492: 14 LP rounds and 1096 solves with them,
# 107 rounds and 1709 solves without).
BOUND_MARGIN = 1.0
TRIANGLE_ENTRIES = 200_000_000
# Above that, each row's bounds go through its PIVOT_ROWS nearest rows with known distances
# (rows x PIVOT_ROWS x columns per round): without any, homer's near r = 0.2 bumps took 118
# rounds and stanford-bunny's near r = 0.1 bumps 162 (bench/results/exact_geodesics_speed.md);
# the nearest rows give the tightest bounds |d(x_i, y) - d(x_k, y)| <= d(x_i, x_k).
PIVOT_ROWS = 64
# Estimates (exact_route_estimate, constants fitted by bench/distance_routes.py calibrate):
# the later rounds of the bounded-solve loop (rows whose bound grows) took 0.5-0.8 x the
# first round's time on 25 + 25 scattered points: the first round counts this much; the
# network simplex takes about LP_COEF * n0 n1 log2(n0 n1) seconds; the plan of the first
# round is estimated on at most PLAN_POINTS representatives of the smaller support.
ROUNDS_FACTOR = 1.8
LP_COEF = 4.7e-9
PLAN_POINTS = 32
EXACT_KINDS = kinds_supporting("exact_transport")  # mesh, grid, pointcloud


@dataclass(kw_only=True)
class ExactTransportResult(SolverResult):
    """Result of :func:`exact_wasserstein_distance`.

    Attributes
    ----------
    value : float
        :math:`W_2^2` (squared distance units, unit area on meshes).
    sources, targets : array of int
        Support indices of ``mu0`` and ``mu1``.
    plan : (len(sources), len(targets)) array
        Optimal coupling.
    cost_seconds, lp_seconds : float
        Time of the cost matrix and of the LP.
    method : str
        ``"exact"``.
    decision : DistanceDecision or None
        The decision of a :func:`wasserstein_distance` call.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
        ``residual``: L1 marginal violation of ``plan``.
    """

    value: float
    sources: np.ndarray
    targets: np.ndarray
    plan: np.ndarray = field(repr=False)
    cost_seconds: float = 0.0
    lp_seconds: float = 0.0
    method: str = "exact"
    decision: object = None  # the DistanceDecision of a wasserstein_distance call


def supports_exact(domain) -> bool:
    """Whether the exact method is available on ``domain`` (meshes, grids, point clouds): a
    domain or its sketch with the capability ``"exact_transport"``."""
    return supports(domain, "exact_transport")


def lp_seconds(n0: int, n1: int) -> float:
    """Modelled seconds of the transport LP between supports of ``n0`` and ``n1`` points."""
    return LP_COEF * float(n0) * float(n1) * np.log2(max(n0 * n1, 2))


@dataclass
class _MeshPlan:
    """The smaller support as rows, edge-path upper bounds and the first solve bounds."""

    flipped: bool
    rows: np.ndarray
    cols: np.ndarray
    row_mass: np.ndarray
    col_mass: np.ndarray
    upper: np.ndarray  # (r, c) edge-path lengths between rows and cols (>= geodesic)
    need: np.ndarray  # (r,) the bound of each row's first solve


def _network_simplex(a: np.ndarray, b: np.ndarray, cost: np.ndarray, **options):
    """``ot.emd`` on masses that are never empty nor without mass: POT's network simplex
    reads out of bounds on an empty support and took the whole API process down (a
    segfault: the client's connection closed) when an overflowing sum had zeroed masses."""
    import ot

    for name, m in (("row", a), ("column", b)):
        if m.size == 0 or not np.isfinite(m).all() or not m.sum() > 0:
            raise ValueError(f"transport LP with an empty or massless {name} support")
    return ot.emd(a, b, cost, **options)


def _finite_cost(cost: np.ndarray) -> np.ndarray:
    """Infinite entries (other components) priced above any finite plan: matching
    component masses leave them unused."""
    finite = np.isfinite(cost)
    if finite.all():
        return cost
    return np.where(finite, cost, 10.0 * float(cost[finite].max(initial=0.0)) * cost.size + 1.0)


def _first_bounds(paths: np.ndarray, cols: np.ndarray, row_mass, col_mass):
    """``(upper, need)``: edge-path lengths from the rows (``paths``, rows x n) to ``cols``
    and, per row, the longest of them that the LP on their squares uses."""
    upper = paths[:, cols]
    guess = _network_simplex(row_mass, col_mass, _finite_cost(upper**2), numItermax=10_000_000)
    return upper, np.where(guess > 0, upper, 0.0).max(axis=1)


def _mesh_plan(mesh, src, dst, a, b) -> _MeshPlan:
    from solvers.geodesics import edge_path_distances

    flipped = len(dst) < len(src)
    rows, cols, ra, cb = (dst, src, b, a) if flipped else (src, dst, a, b)
    upper, need = _first_bounds(edge_path_distances(mesh, rows), cols, ra, cb)
    return _MeshPlan(flipped, rows, cols, ra, cb, upper, need)


def exact_route_estimate(sketch, m0, m1, budget: float | None = None) -> float:
    """Modelled seconds of :func:`exact_wasserstein_distance` between the masses ``m0`` and
    ``m1`` on the domain of ``sketch`` (a :class:`~solvers.domains.sketch.DomainSketch`): a
    pure function of the stored domain and the inputs.  Meshes: one MMP solve
    (:func:`solvers.geodesics.mmp_solve_seconds`) per point of the smaller support, out to the
    bound its first round needs (edge-path plan, module docstring; on at most
    :data:`PLAN_POINTS` representatives, each standing for the rows nearest to it) times
    :data:`ROUNDS_FACTOR`, the exact distances from the junction vertices of non-manifold
    meshes, and the LP; grids and point clouds: the cost matrix and the LP.  When the
    size-only lower bound (every solve at its setup cost) is above ``budget`` that bound is
    returned without planning."""
    from solvers.geodesics import mmp_solve_seconds

    m0, m1 = np.asarray(m0), np.asarray(m1)
    src, dst = np.flatnonzero(m0 > 0), np.flatnonzero(m1 > 0)
    lp = lp_seconds(len(src), len(dst))
    if not sketch.supports("geodesic_solves"):
        return lp + 1e-8 * float(len(src)) * float(len(dst))
    rows, cols, rmass, cmass = (dst, src, m1, m0) if len(dst) < len(src) else (src, dst, m0, m1)
    closure = sketch.junctions * mmp_solve_seconds(sketch.n, 1.0)
    floor = len(rows) * mmp_solve_seconds(sketch.n, 0.0) + lp + closure
    if budget is not None and floor > budget:
        return floor
    from solvers.regularization import quantize

    reps, weight = quantize(sketch.points, rmass, PLAN_POINTS)
    counts = np.bincount(_nearest(sketch.points, rows, reps), minlength=len(reps))
    paths = sketch.path_lengths(reps)
    _, need = _first_bounds(paths, cols, weight / weight.sum(), cmass[cols] / cmass[cols].sum())
    reach = (paths <= need[:, None]).mean(axis=1)
    solves = sum(int(c) * mmp_solve_seconds(sketch.n, float(r))
                 for c, r in zip(counts, reach, strict=True))
    return ROUNDS_FACTOR * solves + lp + closure


def exact_route_upper_bound(sketch, m0, m1) -> float:
    """An upper bound of :func:`exact_route_estimate` (every solve of the smaller support
    reaching the whole mesh), from the support sizes alone: when it fits a budget, so does
    the estimate, with no planning."""
    from solvers.geodesics import mmp_solve_seconds

    n0, n1 = int(np.count_nonzero(m0)), int(np.count_nonzero(m1))
    lp = lp_seconds(n0, n1)
    if not sketch.supports("geodesic_solves"):
        return lp + 1e-8 * float(n0) * float(n1)
    closure = sketch.junctions * mmp_solve_seconds(sketch.n, 1.0)
    return ROUNDS_FACTOR * min(n0, n1) * mmp_solve_seconds(sketch.n, 1.0) + lp + closure


def _nearest(points: np.ndarray, rows: np.ndarray, reps: np.ndarray) -> np.ndarray:
    """Index (into ``reps``) of the representative nearest to each row (straight lines)."""
    from scipy.spatial import cKDTree

    return cKDTree(points[reps]).query(points[rows])[1]


def _triangle_bounds(near: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """``(r, c)`` lower bounds ``max_k |d(x_i, x_k) - d(x_k, y_j)|`` (triangle inequality)
    from the known row-row distances ``near`` and row-column distances ``dist`` (nan:
    unknown)."""
    out = np.zeros(dist.shape)
    for i in range(len(near)):
        with np.errstate(invalid="ignore"):
            gaps = np.abs(near[i][:, None] - dist)  # (k, c)
        gaps = np.where(np.isnan(gaps), 0.0, gaps)
        out[i] = gaps.max(axis=0, initial=0.0)
    return out


def _pivot_bounds(near: np.ndarray, dist: np.ndarray, pivots: int) -> np.ndarray:
    """:func:`_triangle_bounds` through each row's ``pivots`` nearest rows of known distance
    only: ``(r, c)`` lower bounds at ``r x pivots x c`` entries instead of ``r^2 x c``."""
    out = np.zeros(dist.shape)
    gap = np.where(np.isnan(near), np.inf, near)
    count = min(pivots, len(near))
    nearest = np.argpartition(gap, count - 1, axis=1)[:, :count]
    for i in range(len(near)):
        k = nearest[i][np.isfinite(gap[i, nearest[i]])]
        if k.size:
            out[i] = _triangle_bounds(near[i, k][None, :], dist[k])[0]
    return out


def _mesh_exact(mesh, plan: _MeshPlan, stop, max_iter: int):
    """The bounded-solve loop of the module docstring: ``(plan, squared cost, log, LP
    seconds)``."""

    from solvers.geodesics import geodesic_distances_within

    r, c = len(plan.rows), len(plan.cols)
    dist = np.full((r, c), np.nan)  # exact where known
    near = np.full((r, r), np.nan)  # exact row-row distances where known
    bound = np.full(r, -1.0)
    need = plan.need * BOUND_MARGIN
    v = np.asarray(mesh.vertices, dtype=np.float64)
    straight = np.linalg.norm(v[plan.rows][:, None, :] - v[plan.cols][None, :, :], axis=2)
    triangle = r * r * c <= TRIANGLE_ENTRIES
    lp_seconds = 0.0
    while True:
        for i in np.flatnonzero(need > bound):
            stop()
            d = geodesic_distances_within(mesh, int(plan.rows[i]), float(need[i]))
            bound[i] = need[i]
            everything = not np.isfinite(need[i])  # an unbounded solve: inf is known too
            dist[i] = np.where(np.isfinite(d[plan.cols]) | everything, d[plan.cols], np.nan)
            seen = np.isfinite(d[plan.rows]) | everything
            near[i, seen] = near[seen, i] = d[plan.rows][seen]
        known = ~np.isnan(dist)
        lower = np.maximum(bound[:, None], straight)
        lower = np.maximum(lower, _triangle_bounds(near, dist) if triangle
                           else _pivot_bounds(near, dist, PIVOT_ROWS))
        lower = np.where(known, dist, lower)
        begin = time.perf_counter()
        coupling, log = _network_simplex(plan.row_mass, plan.col_mass, _finite_cost(lower**2),
                                         numItermax=int(max_iter), log=True)
        lp_seconds += time.perf_counter() - begin
        guessed = (coupling > 0) & ~known
        if not guessed.any():
            return coupling, np.where(known, dist, np.inf) ** 2, log, lp_seconds
        grow = np.flatnonzero(guessed.any(axis=1))  # cover the guessed entries: upper >= d
        cover = np.where(guessed[grow], plan.upper[grow], 0.0).max(axis=1)
        need[grow] = np.maximum(need[grow] * BOUND_MARGIN, cover * BOUND_MARGIN)


def exact_wasserstein_distance(
    domain,
    mu0,
    mu1,
    *,
    max_iter: int = 10_000_000,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> ExactTransportResult:
    r"""Exact :math:`W_2^2` between ``mu0`` and ``mu1`` (module docstring).

    Parameters
    ----------
    domain : a TriangleMesh, Grid or PointCloud.
    mu0, mu1 : ``(n,)`` masses (normalized here); their supports set the LP size.
    max_iter : network-simplex iteration cap; when hit, ``converged`` is False.
    progress, should_cancel : called between the geodesic solves and before the LP.

    Returns
    -------
    ExactTransportResult(value, sources, targets, plan, iterations, residual, converged, ...)
    """

    from solvers.errors import CancelledError
    from solvers.validation import check_components, distribution_pair

    if not supports_exact(domain):
        raise InputError(f"the exact method needs a mesh, grid or point cloud, not a "
                         f"{getattr(domain, 'kind', type(domain).__name__)}", field="method")
    m0, m1 = distribution_pair(domain, mu0, mu1)
    check_components(domain, np.stack([m0, m1], axis=1), 1e-9, "mu1")
    src, dst = np.flatnonzero(m0 > 0), np.flatnonzero(m1 > 0)
    if len(src) * len(dst) > MAX_SUPPORT_PRODUCT:
        raise InputError(f"the exact method's LP has {len(src)} x {len(dst)} entries, above "
                         f"its limit of {MAX_SUPPORT_PRODUCT}; use method='convolutional'",
                         field="method")
    monitor = Monitor(progress, should_cancel)
    monitor(0, float("nan"))
    start = time.perf_counter()
    a, b = m0[src], m1[dst]

    def stop() -> None:  # before each geodesic solve
        if should_cancel is not None and should_cancel():
            raise CancelledError("cancelled between geodesic solves")

    if domain.supports("geodesic_solves"):
        plan = _mesh_plan(domain, src, dst, a, b)
        coupling, cost, log, lp_seconds = _mesh_exact(domain, plan, stop, max_iter)
        cost_seconds = time.perf_counter() - start - lp_seconds
        if plan.flipped:
            coupling, cost = coupling.T, cost.T
    else:  # grids, point clouds: the whole cost matrix, no geodesic solves
        cost, squared = domain.ground_distances(src, dst)
        cost = cost if squared else np.square(cost)
        cost_seconds = time.perf_counter() - start
        monitor.check_cancel("before the transport LP")
        begin = time.perf_counter()
        coupling, log = _network_simplex(a, b, cost, numItermax=int(max_iter), log=True)
        lp_seconds = time.perf_counter() - begin
    residual = float(np.abs(coupling.sum(axis=1) - a).sum()
                     + np.abs(coupling.sum(axis=0) - b).sum())
    converged = int(log.get("result_code", 0)) == 1
    used = coupling > 0
    value = float(np.sum(coupling[used] * cost[used]))
    monitor(1, residual)
    return ExactTransportResult(value=value, sources=src, targets=dst, plan=coupling,
                                iterations=1, residual=residual, converged=converged,
                                cost_seconds=cost_seconds, lp_seconds=lp_seconds)
