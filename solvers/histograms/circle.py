r"""Propagation of histograms on the circle S¹ or a small metric space (thesis §5.4).

Off the line the inverse-CDF trick is gone, but on a discrete target domain of ``B``
points (bin centers) with ground cost :math:`C_{ij}` (default: squared geodesic distance,
wrapped on periodic bins) the Dirichlet energy in :math:`W_2^2` is a linear program in
one transport plan :math:`\pi_e \in \mathbb{R}_+^{B \times B}` per edge:

.. math::  \min \sum_{e = (u, v)} w_e \langle C, \pi_e \rangle \quad\text{s.t.}\quad
           \pi_e \mathbf 1 = \mu_u,\; \pi_e^\top \mathbf 1 = \mu_v,\;
           \mu_v \ge 0,\; \mathbf 1^\top \mu_v = 1 \text{ (unlabeled } v),

with :math:`\mu_v` fixed on the labeled nodes.  ``method="lp"`` solves it exactly with
HiGHS (``highspy``, dual simplex), the constraint matrix assembled sparse (``2B - 1``
independent rows per edge), by warm-started column generation: the plans start on a band
of cheap entries around the diagonal plus a feasible plan per edge, all other entries are
priced with the LP duals and the negative ones added to the same model (re-solved from the
previous basis) until none is left; a dual lower bound over all :math:`m B^2` entries then
certifies that the result is the unrestricted LP's optimum.  ``lp_method="hybrid"`` (the
default on large graphs) starts the same column generation from the support found by a
structured primal-dual interior-point method on the full LP (:mod:`.circle_ipm`: each
edge's plan block eliminated in closed form onto the node histograms, one sparse
Cholesky per iteration), run to a moderate accuracy; the optimum and its certificate are
the simplex's.
``method="entropic"`` solves the regularized version with the convolutional propagation of Alg. 4
(:func:`solvers.convolutional.wasserstein_propagation`) on a periodic 1-D
:class:`~solvers.domains.Grid` of the bin centers (heat kernel
:math:`e^{-d^2/\gamma}`), which scales to larger graphs; its exact objective is evaluated
with per-edge exact transport (network simplex), and, when the LP optimum is known, the
gap is reported.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.sparse as sp

from solvers.domains import Graph
from solvers.errors import ConvergenceError, InputError
from solvers.histograms.bins import Bins, check_histograms, make_bins
from solvers.histograms.graphs import as_graph
from solvers.monitor import Monitor, SolverResult
from solvers.validation import (
    check_anchored_components,
    check_choice,
    check_edge_weights,
    check_node_indices,
    check_positive,
)


@dataclass(kw_only=True)
class CircularPropagationResult(SolverResult):
    r"""Result of :func:`propagate_circular`.

    Attributes
    ----------
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
        For ``method="lp"``, ``iterations`` counts column-generation rounds.
    method : {"lp", "entropic"}
        The method used.
    histograms : (n, B) array
        Per-node histograms.
    value : float
        The exact objective :math:`\sum_e w_e W_C(\mu_u, \mu_v)` of ``histograms``.
    lp_value : float or None
        The LP optimum, when known.
    gap : float or None
        ``value - lp_value`` (0 for the LP itself).
    gamma : float or None
        Entropic regularization (``method="entropic"``).
    labeled : (k,) array or None
        The labeled nodes.
    lower_bound : float or None
        ``method="lp"``: a dual bound on the *unrestricted* LP (all :math:`m B^2` plan
        entries priced).
    min_reduced_cost : float or None
        The most negative reduced cost over all the LP's columns.
    certified : bool or None
        Whether ``value - lower_bound <= 1e-7 max(1, |value|)``, i.e. the restricted
        optimum is the full LP's.
    plan_entries : int or None
        The plan entries the LP ended with.
    simplex_iterations : int or None
        HiGHS simplex iterations.
    lp_method : {"simplex", "hybrid"} or None
        The start of the column generation.
    ipm_iterations : int or None
        Interior-point iterations of the hybrid start.
    """

    method: str
    histograms: np.ndarray
    value: float
    lp_value: float | None = None
    gap: float | None = None
    gamma: float | None = None
    labeled: np.ndarray | None = None
    lower_bound: float | None = None
    min_reduced_cost: float | None = None
    certified: bool | None = None
    plan_entries: int | None = None
    simplex_iterations: int | None = None
    lp_method: str | None = None
    ipm_iterations: int | None = None


def circle_cost(bins: Bins, power: float = 2.0) -> np.ndarray:
    """Ground cost ``d^power`` between bin centers (distance wrapped if periodic).

    Parameters
    ----------
    bins : Bins
        The bins.
    power : float
        Exponent of the distance.

    Returns
    -------
    (B, B) array
    """
    c = bins.centers
    d = np.abs(c[:, None] - c[None, :])
    if bins.periodic:
        d = np.minimum(d, bins.period - d)
    return d**power


def _graph_arrays(graph):
    graph = as_graph(graph)
    return graph.n, graph.edges, graph.weights, np.asarray(graph.component_labels)


def _labels(graph, labeled, histograms, bins: Bins):
    n, edges, weights, comps = _graph_arrays(graph)
    nodes = check_node_indices(labeled, n, "labeled")
    check_anchored_components(comps, nodes, "labeled")
    h = check_histograms(histograms, bins.count, "histograms")
    if len(h) != len(nodes):
        raise InputError(f"histograms has {len(h)} labels for {len(nodes)} labeled nodes",
                         field="histograms")
    return n, edges, check_edge_weights(weights, len(edges), "weights"), nodes, h


def transport_cost(mu: np.ndarray, nu: np.ndarray, cost: np.ndarray) -> float:
    """Exact :math:`\\min_\\pi \\langle C, \\pi\\rangle` between two histograms (POT's network
    simplex, ``ot.emd2``; totals made equal first)."""
    import ot

    mu = np.where(mu > 1e-15, mu, 0.0)
    nu = np.where(nu > 1e-15, nu, 0.0)
    value = ot.emd2(mu / mu.sum(), nu / nu.sum(), np.ascontiguousarray(cost, dtype=np.float64),
                    numItermax=10_000_000)
    return float(value)


def dirichlet_value(histograms: np.ndarray, edges, weights, cost: np.ndarray) -> float:
    r"""The Dirichlet energy :math:`\sum_e w_e\, OT_C(\mu_u, \mu_v)` of per-node histograms.

    Exact: one transport LP per edge.

    Parameters
    ----------
    histograms : (n, B) array
        Per-node histograms.
    edges : (m, 2) int array
        Graph edges.
    weights : (m,) array
        Edge weights :math:`w_e`.
    cost : (B, B) array
        Ground cost :math:`C` between bins.

    Returns
    -------
    float
    """
    H = np.asarray(histograms, dtype=np.float64)
    H = H / H.sum(axis=1, keepdims=True)
    return float(sum(w * transport_cost(H[u], H[v], cost)
                     for (u, v), w in zip(np.asarray(edges), np.asarray(weights), strict=True)))


def _nw_corner_support(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entries of the north-west-corner plan between histograms ``a`` and ``b`` (at most
    ``2B - 1``): a feasible plan for any two marginals of equal mass."""
    ca, cb = np.cumsum(a), np.cumsum(b)
    ca[-1] = cb[-1] = 1.0
    br = np.unique(np.concatenate([[0.0], ca, cb]))
    mid = 0.5 * (br[:-1] + br[1:])[np.diff(br) > 0]
    B = len(a)
    return (np.minimum(np.searchsorted(ca, mid), B - 1),
            np.minimum(np.searchsorted(cb, mid), B - 1))


def _harmonic_guess(n, edges, w, nodes, h, free):
    """Per-bin harmonic extension of the labels (the PDF route): a feasible starting point
    whose plans seed the LP's support."""
    import scipy.sparse.linalg as spla

    W = sp.coo_matrix((np.r_[w, w], (np.r_[edges[:, 0], edges[:, 1]],
                                     np.r_[edges[:, 1], edges[:, 0]])), shape=(n, n)).tocsr()
    L = (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()
    H = np.zeros((n, h.shape[1]))
    H[nodes] = h
    if len(free):
        X = spla.spsolve(L[free][:, free].tocsc(), -(L[free][:, nodes] @ h))
        H[free] = np.clip(np.asarray(X).reshape(len(free), -1), 1e-12, None)
    return H / H.sum(axis=1, keepdims=True)


class _PlanLP:
    r"""The §5.4 LP restricted to a set of plan entries, kept in one ``highspy.Highs``
    model so that added entries re-solve from the previous basis.

    Rows, per edge ``e = (u, v)``: the ``B`` row marginals :math:`\sum_j \pi_e(i, j) =
    \mu_u(i)` and the first ``B - 1`` column marginals (the last one follows from the
    others, the plan's unit mass and :math:`\mathbf 1^\top \mu_v = 1`; dropping it makes
    the rows independent); then :math:`\mathbf 1^\top \mu_v = 1` per unlabeled node.
    Columns: the unlabeled histograms ``(n_free, B)`` first, then plan entries."""

    def __init__(self, n, edges, w, nodes, h, cost, time_limit):
        import highspy

        self.highspy = highspy
        B = cost.shape[0]
        m = len(edges)
        self.B, self.m, self.R = B, m, 2 * B - 1
        self.edges, self.w, self.cost = edges, w, cost
        is_label = np.zeros(n, dtype=bool)
        is_label[nodes] = True
        self.free = np.flatnonzero(~is_label)
        free_index = np.full(n, -1, dtype=np.int64)
        free_index[self.free] = np.arange(len(self.free))
        label_row = np.full(n, -1, dtype=np.int64)
        label_row[nodes] = np.arange(len(nodes))
        R, n_free = self.R, len(self.free)
        self.n_rows = m * R + n_free
        b = np.zeros(self.n_rows)
        b[m * R:] = 1.0
        rows, cols = [], []
        for side in (0, 1):
            end, width = edges[:, side], (B if side == 0 else B - 1)
            fe = np.flatnonzero(free_index[end] >= 0)
            le = np.flatnonzero(free_index[end] < 0)
            rows.append(((fe * R + side * B)[:, None] + np.arange(width)).ravel())
            cols.append(((free_index[end[fe]] * B)[:, None] + np.arange(width)).ravel())
            b[((le * R + side * B)[:, None] + np.arange(width)).ravel()] = (
                h[label_row[end[le]], :width].ravel())
        vals = [-np.ones(len(r)) for r in rows]
        rows.append(m * R + np.repeat(np.arange(n_free), B))
        cols.append(np.arange(n_free * B))
        vals.append(np.ones(n_free * B))
        A = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(self.n_rows, n_free * B))
        self.b = b
        self.n_mu = n_free * B
        lp = highspy.HighsLp()
        lp.num_col_, lp.num_row_ = self.n_mu, self.n_rows
        lp.col_cost_ = np.zeros(self.n_mu)
        lp.col_lower_ = np.zeros(self.n_mu)
        lp.col_upper_ = np.full(self.n_mu, highspy.kHighsInf)
        lp.row_lower_ = lp.row_upper_ = b
        lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
        lp.a_matrix_.num_col_, lp.a_matrix_.num_row_ = self.n_mu, self.n_rows
        lp.a_matrix_.start_ = A.indptr.astype(np.int32)
        lp.a_matrix_.index_ = A.indices.astype(np.int32)
        lp.a_matrix_.value_ = A.data
        self.h = highspy.Highs()
        self.h.setOptionValue("output_flag", False)
        self.h.setOptionValue("threads", 1)
        if time_limit is not None:
            self.h.setOptionValue("time_limit", float(time_limit))
        self.h.passModel(lp)
        self.have = np.zeros((m, B, B), dtype=bool)
        self.entries = [np.zeros(0, dtype=np.int64)] * 3

    def add(self, e, i, j):
        """Add plan entries ``(e, i, j)`` (none already present) as columns."""
        B, R, k = self.B, self.R, len(e)
        if k == 0:
            return
        self.have[e, i, j] = True
        last = j == B - 1  # no column-marginal row for the last bin
        counts = np.where(last, 1, 2)
        starts = np.r_[0, np.cumsum(counts)[:-1]].astype(np.int32)
        index = np.empty(int(counts.sum()), dtype=np.int32)
        index[starts] = e * R + i
        index[starts[~last] + 1] = e[~last] * R + B + j[~last]
        self.h.addCols(k, self.w[e] * self.cost[i, j], np.zeros(k),
                       np.full(k, self.highspy.kHighsInf), len(index), starts, index,
                       np.ones(len(index)))
        self.entries = [np.concatenate([a, x]) for a, x in zip(self.entries, (e, i, j),
                                                             strict=True)]

    def solve(self):
        self.h.run()
        status = self.h.getModelStatus()
        if status != self.highspy.HighsModelStatus.kOptimal:
            raise ConvergenceError(
                f"the propagation LP did not solve: {self.h.modelStatusToString(status)}")
        sol = self.h.getSolution()
        return np.asarray(sol.col_value), np.asarray(sol.row_dual), np.asarray(sol.col_dual)

    def reduced_costs(self, y):
        r""":math:`w_e C_{ij} - y^{row}_{e,i} - y^{col}_{e,j}` of all ``m B^2`` plan
        entries ``(m, B, B)`` (``y^{col}_{e,B-1} = 0``: that row is not in the LP)."""
        B, m, R = self.B, self.m, self.R
        Y = y[: m * R].reshape(m, R)
        y_col = np.concatenate([Y[:, B:], np.zeros((m, 1))], axis=1)
        return self.w[:, None, None] * self.cost[None] - Y[:, :B, None] - y_col[:, None, :]


def _solve_lp(n, edges, w, nodes, h, cost, monitor, time_limit, band=None,
              price_tol=1e-9, support=None, guess=None):
    r"""Column generation, warm-started: start from a band of ``2 band + 1`` cheap entries
    per plan row plus the north-west-corner plans of the per-bin harmonic extension (so the
    restricted LP is feasible), price all :math:`m B^2` plan entries with the duals
    (reduced cost :math:`w_e C_{ij} - y^{row}_{e,i} - y^{col}_{e,j}`), add the negative ones
    as columns of the same HiGHS model (the previous basis stays primal feasible), repeat
    until none is below ``-price_tol``.

    The certificate: with duals ``y`` and the reduced costs ``r`` of *all* columns,
    :math:`b^\top y + \sum_k \min(r_k, 0)` is a lower bound on the unrestricted LP (every
    variable lies in ``[0, 1]``: masses); it is returned beside the primal value.

    ``support`` (``(m, B, B)`` booleans) and ``guess`` (``(n, B)`` histograms) replace the
    band and the harmonic extension as the start (the hybrid route)."""
    B = cost.shape[0]
    m = len(edges)
    h = np.where(h > 1e-12, h, 0.0)  # below HiGHS' tolerances; keeps the LP well scaled
    h = h / h.sum(axis=1, keepdims=True)
    band = 2 if band is None else int(band)
    lp = _PlanLP(n, edges, w, nodes, h, cost, time_limit)
    if support is None:
        have = np.zeros((m, B, B), dtype=bool)
        near = np.argsort(cost, axis=1, kind="stable")[:, :min(B, 2 * band + 1)]
        have[:, np.repeat(np.arange(B), near.shape[1]), near.ravel()] = True
    else:
        have = np.array(support, dtype=bool)
    if guess is None:
        guess = _harmonic_guess(n, edges, w, nodes, h, lp.free)
    for e, (u, v) in enumerate(edges):
        i, j = _nw_corner_support(guess[u], guess[v])
        have[e, i, j] = True
    lp.add(*np.nonzero(have))
    rounds = 0
    while True:
        rounds += 1
        monitor.check_cancel("before the LP")
        x, y, col_dual = lp.solve()
        rc = lp.reduced_costs(y)
        min_rc = float(rc.min())
        add = np.nonzero((rc < -price_tol) & ~lp.have)
        monitor(rounds, max(0.0, -min_rc))
        if len(add[0]) == 0:
            break
        lp.add(*add)
    mu_rc = col_dual[: lp.n_mu]
    lower = float(lp.b @ y + np.minimum(rc, 0.0).sum() + np.minimum(mu_rc, 0.0).sum())
    value = float(lp.h.getInfo().objective_function_value)
    H = np.zeros((n, B))
    H[nodes] = h
    H[lp.free] = np.clip(x[: lp.n_mu].reshape(len(lp.free), B), 0.0, None)
    info = lp.h.getInfo()
    violation = float(info.max_primal_infeasibility)
    monitor(rounds, violation)
    return {"histograms": H, "value": value, "violation": violation, "rounds": rounds,
            "lower_bound": lower, "min_reduced_cost": min(min_rc, float(mu_rc.min(initial=0))),
            "plan_entries": int(lp.have.sum()), "full_entries": m * B * B,
            "simplex_iterations": int(info.simplex_iteration_count)}


def _ipm_support(n, edges, w, nodes, h, cost, monitor, time_limit, ipm_iterations):
    r"""The structured interior-point method (:mod:`.circle_ipm`) run to a moderate
    accuracy; returns the starting support of the column generation — the entries whose
    IPM plan value exceeds ``1e-3`` of its edge's largest, or whose IPM reduced cost
    :math:`w_e C_{ij} - y^{row}_{e,i} - y^{col}_{e,j}` is below :math:`0.1 w_e` — and the
    IPM histograms (their north-west-corner plans make the restricted LP feasible)."""
    from solvers.histograms.circle_ipm import solve_ipm

    res = solve_ipm(n, edges, w, nodes, h, cost, monitor, tol=1e-5, max_iter=ipm_iterations,
                    time_limit=time_limit)
    lp = res["lp"]
    X = res["X"]
    tp, _ = lp.At_y(res["yr"], res["yc"], res["z"])
    support = ((X > 1e-3 * X.max(axis=(1, 2), keepdims=True))
               | (lp.c - tp < 0.1 * np.asarray(w, dtype=np.float64)[:, None, None]))
    H = np.zeros((n, cost.shape[0]))
    H[nodes] = h
    H[lp.free] = np.clip(res["mu"], 1e-15, None)
    H /= H.sum(axis=1, keepdims=True)
    return support, H, res


def _propagate_lp(n, edges, w, nodes, h, C, monitor, *, time_limit, lp_method,
                  ipm_iterations) -> CircularPropagationResult:
    """:func:`propagate_circular` by the exact LP (column generation, started as
    ``lp_method`` says: ``"auto"`` resolved here)."""
    n_free = n - len(np.unique(nodes))
    if lp_method == "auto":
        lp_method = "hybrid" if n_free > 0 and len(edges) * len(C)**2 >= 200_000 else "simplex"
    if n_free == 0:
        lp_method = "simplex"
    support = guess = None
    ipm_its = None
    if lp_method == "hybrid":
        hc = np.where(h > 1e-12, h, 0.0)
        hc = hc / hc.sum(axis=1, keepdims=True)
        support, guess, ipm = _ipm_support(n, edges, w, nodes, hc, C, monitor, time_limit,
                                           int(ipm_iterations))
        ipm_its = ipm["iterations"]
    lp = _solve_lp(n, edges, w, nodes, h, C, monitor, time_limit, support=support,
                   guess=guess)
    value, lower = lp["value"], lp["lower_bound"]
    certified = value - lower <= 1e-7 * max(1.0, abs(value))
    return CircularPropagationResult(
        method="lp", histograms=lp["histograms"], value=value, lp_value=value,
        gap=0.0, labeled=nodes, iterations=lp["rounds"], residual=lp["violation"],
        converged=certified and lp["violation"] <= 1e-7, lower_bound=lower,
        min_reduced_cost=lp["min_reduced_cost"], certified=certified,
        plan_entries=lp["plan_entries"], simplex_iterations=lp["simplex_iterations"],
        lp_method=lp_method, ipm_iterations=ipm_its)


def propagate_circular(graph: Graph, labeled, histograms, *, bins,
                       method: Literal["lp", "entropic"] = "lp", cost: np.ndarray | None = None,
                       gamma: float | None = None, tol: float = 1e-6,
                       max_iter: int | None = None, time_limit: float | None = None,
                       evaluate: bool = True, lp_value: float | None = None,
                       lp_method: Literal["auto", "hybrid", "simplex"] = "auto",
                       ipm_iterations: int = 45,
                       progress=None, should_cancel=None) -> CircularPropagationResult:
    r"""Propagate histograms over periodic bins (S¹) or a small metric space (§5.4).

    Solves for the unlabeled nodes' histograms

    .. math:: \min_{\mu_v,\, v \notin L} \sum_{e = (u, v)} w_e\, W_C(\mu_u, \mu_v),
       \qquad \mu_v \text{ fixed for } v \in L,

    exactly as one LP (``"lp"``, HiGHS with column generation) or with entropic
    regularization (``"entropic"``, Alg. 4 on a periodic 1-D grid).

    Parameters
    ----------
    graph : Graph or domain
        A :class:`~solvers.domains.Graph` (edges, positive weights), or any source
        :func:`~solvers.histograms.graphs.as_graph` accepts (mesh, point cloud, weights).
    labeled : (k,) int array
        Labeled nodes, at least one per connected component.
    histograms : (k, B) array
        Their histograms.
    bins : Bins or (B + 1,) array
        The bins (``periodic=True`` for S¹) or their edges.
    method : {"lp", "entropic"}
        Exact LP, or entropic (Alg. 4).
    cost : (B, B) array, optional
        Ground cost :math:`C` (a small metric space); default :func:`circle_cost`
        (squared wrapped distance of bin centers).
    gamma : float, optional
        Entropic regularization (default ``(2 w)^2``, ``w`` the mean bin width), in the
        bins' squared units.
    tol : float
        Sinkhorn stopping tolerance (``"entropic"``).
    max_iter : int, optional
        Sinkhorn iteration budget (``"entropic"``).
    time_limit : float, optional
        Seconds given to HiGHS (over all column-generation rounds; the LP raises
        :class:`~solvers.errors.ConvergenceError` when it runs out) and, separately, to the
        interior-point start of ``lp_method="hybrid"``.
    evaluate : bool
        Compute the exact objective of the entropic result (per-edge exact OT).
    lp_value : float, optional
        A known LP optimum to report the gap against.
    lp_method : {"auto", "hybrid", "simplex"}
        How ``method="lp"`` starts its column generation (the optimum and its certificate
        are the same): ``"simplex"`` from a band of cheap entries around the diagonal;
        ``"hybrid"`` from the support found by at most ``ipm_iterations`` iterations of the
        structured interior-point method of :mod:`.circle_ipm` (all :math:`m B^2` entries;
        per-edge blocks eliminated onto the node histograms, one sparse Cholesky per
        iteration); ``"auto"``: hybrid when :math:`m B^2 \ge 2 \cdot 10^5` and some node is
        unlabeled.
    ipm_iterations : int
        Iteration budget of the hybrid start.
    progress, should_cancel : callable, optional
        As in :func:`~solvers.histograms.propagate_histograms`.

    Returns
    -------
    CircularPropagationResult
        ``histograms`` ``(n, B)``, the objective ``value`` and, for the LP, its certificate.
    """
    b = make_bins(bins)
    n, edges, w, nodes, h = _labels(graph, labeled, histograms, b)
    C = circle_cost(b) if cost is None else np.asarray(cost, dtype=np.float64)
    if C.shape != (b.count, b.count) or not np.all(np.isfinite(C)) or np.any(C < 0):
        raise InputError(f"cost must be a finite non-negative ({b.count}, {b.count}) matrix",
                         field="cost")
    check_choice(method, ("lp", "entropic"), "method")
    monitor = Monitor(progress, should_cancel)
    check_choice(lp_method, ("auto", "hybrid", "simplex"), "lp_method")
    if method == "lp":
        return _propagate_lp(n, edges, w, nodes, h, C, monitor, time_limit=time_limit,
                             lp_method=lp_method, ipm_iterations=ipm_iterations)
    if cost is not None:
        raise InputError("method='entropic' uses the circle's heat kernel; a custom cost "
                         "needs method='lp'", field="cost")
    from solvers.convolutional import wasserstein_propagation
    from solvers.domains import Grid

    width = float(b.widths.mean())
    if not np.allclose(b.widths, width, rtol=1e-9):
        raise InputError("method='entropic' needs equal-width bins", field="bins.edges")
    gamma = (2.0 * width) ** 2 if gamma is None else check_positive(gamma, "gamma")
    lo = b.lo + 0.5 * width
    axis = Grid((b.count,), bounds=[(lo, lo + b.period)], periodic=b.periodic)
    fixed = {int(u): h[i] for i, u in enumerate(nodes)}
    res = wasserstein_propagation(axis, n, edges, fixed, edge_weights=w, gamma=gamma, tol=tol,
                                  max_iter=max_iter, progress=progress,
                                  should_cancel=should_cancel)
    H = np.asarray(res.masses, dtype=np.float64).T.copy()
    H /= H.sum(axis=1, keepdims=True)
    value = dirichlet_value(H, edges, w, C) if evaluate else float("nan")
    gap = None if lp_value is None or not evaluate else value - float(lp_value)
    return CircularPropagationResult(method="entropic", histograms=H, value=value,
                                     lp_value=lp_value, gap=gap, gamma=gamma, labeled=nodes,
                                     iterations=res.iterations, residual=res.residual,
                                     converged=res.converged)
