r"""Propagation of histograms on the circle S¹ or a small metric space (thesis §5.4).

Off the line the inverse-CDF trick is gone, but on a discrete target domain of ``B``
points (bin centers) with ground cost :math:`C_{ij}` (default: squared geodesic distance,
wrapped on periodic bins) the Dirichlet energy in :math:`W_2^2` is a linear program in
one transport plan :math:`\pi_e \in \mathbb{R}_+^{B \times B}` per edge:

.. math::  \min \sum_{e = (u, v)} w_e \langle C, \pi_e \rangle \quad\text{s.t.}\quad
           \pi_e \mathbf 1 = \mu_u,\; \pi_e^\top \mathbf 1 = \mu_v,\;
           \mu_v \ge 0,\; \mathbf 1^\top \mu_v = 1 \text{ (unlabeled } v),

with :math:`\mu_v` fixed on the labeled nodes.  ``algorithm="lp"`` solves it exactly with
HiGHS (``scipy.optimize.linprog``), the constraint matrix assembled sparse (``2B`` rows per
edge), by column generation: the plans start on a band of cheap entries around the
diagonal and the other entries are priced out with the LP duals and added while any has a
negative reduced cost, so the result is the optimum over all :math:`m B^2` entries.
``algorithm="entropic"`` solves the regularized version with the convolutional propagation of Alg. 4
(:func:`solvers.convolutional.wasserstein_propagation`) on a periodic 1-D
:class:`~solvers.domains.Grid` of the bin centers (heat kernel
:math:`e^{-d^2/\gamma}`), which scales to larger graphs; its exact objective is evaluated
with per-edge transport LPs, and, when the LP optimum is known, the gap is reported.
"""

from __future__ import annotations

import time
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
    check_edge_weights,
    check_node_indices,
    check_positive,
)


@dataclass(kw_only=True)
class CircularPropagationResult(SolverResult):
    """``histograms`` ``(n, B)``; ``value`` the exact objective
    :math:`\\sum_e w_e W_C(\\mu_u, \\mu_v)` of the returned histograms; ``lp_value`` the LP
    optimum when known and ``gap = value - lp_value`` (0 for the LP itself)."""

    algorithm: str
    histograms: np.ndarray
    value: float
    lp_value: float | None = None
    gap: float | None = None
    gamma: float | None = None
    labeled: np.ndarray | None = None


def circle_cost(bins: Bins, power: float = 2.0) -> np.ndarray:
    """``(B, B)`` ground cost ``d^power`` between bin centers (wrapped if periodic)."""
    c = bins.centers
    d = np.abs(c[:, None] - c[None, :])
    if bins.periodic:
        d = np.minimum(d, bins.period - d)
    return d**power


def _graph_arrays(graph):
    if not isinstance(graph, Graph):
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
    """Exact :math:`\\min_\\pi \\langle C, \\pi\\rangle` between two histograms (HiGHS)."""
    from scipy.optimize import linprog

    B = len(mu)
    # masses below 1e-15 only trouble HiGHS' feasibility tolerances; totals made equal, and
    # the last column constraint (implied by the others) dropped
    mu = np.where(mu > 1e-15, mu, 0.0)
    nu = np.where(nu > 1e-15, nu, 0.0)
    mu, nu = mu / mu.sum(), nu / nu.sum()
    rows = np.concatenate([np.repeat(np.arange(B), B), B + np.tile(np.arange(B), B)])
    cols = np.concatenate([np.arange(B * B), np.arange(B * B)])
    A = sp.csr_matrix((np.ones(2 * B * B), (rows, cols)), shape=(2 * B, B * B))[:-1]
    res = linprog(cost.ravel(), A_eq=A, b_eq=np.concatenate([mu, nu])[:-1], bounds=(0, None),
                  method="highs")
    if res.status == 2:  # feasible by construction: HiGHS' presolve misjudged tiny masses
        res = linprog(cost.ravel(), A_eq=A, b_eq=np.concatenate([mu, nu])[:-1],
                      bounds=(0, None), method="highs", options={"presolve": False})
    if res.status != 0:
        raise ConvergenceError(f"transport LP failed: {res.message}")
    return float(res.fun)


def dirichlet_value(histograms: np.ndarray, edges, weights, cost: np.ndarray) -> float:
    r""":math:`\sum_e w_e\, OT_C(\mu_u, \mu_v)` of per-node histograms (exact, per-edge LPs)."""
    H = np.asarray(histograms, dtype=np.float64)
    H = H / H.sum(axis=1, keepdims=True)
    return float(sum(w * transport_cost(H[u], H[v], cost)
                     for (u, v), w in zip(np.asarray(edges), np.asarray(weights), strict=True)))


def _lp_problem(n, edges, w, nodes, h, cost, active):
    """Sparse LP over the plan entries ``active = (e, i, j)`` and the free histograms."""
    B = cost.shape[0]
    m = len(edges)
    free_index = np.full(n, -1, dtype=np.int64)
    is_label = np.zeros(n, dtype=bool)
    is_label[nodes] = True
    free = np.flatnonzero(~is_label)
    free_index[free] = np.arange(len(free))
    label_row = np.full(n, -1, dtype=np.int64)
    label_row[nodes] = np.arange(len(nodes))
    ae, ai, aj = active
    n_plan = len(ae)
    n_var = n_plan + len(free) * B
    var = np.arange(n_plan)
    # row marginals: row e*2B + i sums plan entries (i, *); column marginals: e*2B + B + j
    rows = [ae * 2 * B + ai, ae * 2 * B + B + aj]
    cols = [var, var]
    vals = [np.ones(2 * n_plan)]
    b = np.zeros(2 * m * B + len(free))
    for side in (0, 1):
        end = edges[:, side]
        off = side * B
        fe = np.flatnonzero(free_index[end] >= 0)
        if len(fe):
            r = ((fe * 2 * B + off)[:, None] + np.arange(B)[None, :]).ravel()
            c = (n_plan + (free_index[end[fe]] * B)[:, None] + np.arange(B)[None, :]).ravel()
            rows.append(r)
            cols.append(c)
            vals.append(-np.ones(len(r)))
        le = np.flatnonzero(free_index[end] < 0)
        if len(le):
            r = ((le * 2 * B + off)[:, None] + np.arange(B)[None, :]).ravel()
            b[r] = h[label_row[end[le]]].ravel()
    if len(free):  # each unlabeled histogram sums to one
        rows.append(2 * m * B + np.repeat(np.arange(len(free)), B))
        cols.append(n_plan + np.arange(len(free) * B))
        vals.append(np.ones(len(free) * B))
        b[2 * m * B:] = 1.0
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(len(b), n_var))
    c_vec = np.concatenate([w[ae] * cost[ai, aj], np.zeros(len(free) * B)])
    return A, b, c_vec, free, n_plan


def _initial_support(edges, nodes, cost, band: int):
    """Plan entries to start from: for each row the ``2 band + 1`` cheapest columns; the
    full ``B × B`` on edges between two labeled nodes (their plan is fully determined)."""
    B = cost.shape[0]
    m = len(edges)
    near = np.argsort(cost, axis=1, kind="stable")[:, :min(B, 2 * band + 1)]
    bi = np.repeat(np.arange(B), near.shape[1])
    bj = near.ravel()
    labeled = np.zeros(int(edges.max()) + 1 if m else 0, dtype=bool)
    labeled[nodes[nodes < len(labeled)]] = True
    both = labeled[edges[:, 0]] & labeled[edges[:, 1]] if m else np.zeros(0, dtype=bool)
    some = np.flatnonzero(~both)
    full = np.flatnonzero(both)
    ii, jj = (x.ravel() for x in np.meshgrid(np.arange(B), np.arange(B), indexing="ij"))
    e = np.concatenate([np.repeat(some, len(bi)), np.repeat(full, B * B)])
    i = np.concatenate([np.tile(bi, len(some)), np.tile(ii, len(full))])
    j = np.concatenate([np.tile(bj, len(some)), np.tile(jj, len(full))])
    return e, i, j


def _solve_lp(n, edges, w, nodes, h, cost, monitor, time_limit, band=None):
    r"""Column generation: solve on a band of plan entries, price out the others with the
    duals (reduced cost :math:`w_e C_{ij} - y^{row}_{e,i} - y^{col}_{e,j}`), add the
    negative ones, repeat until none is left -- then the restricted optimum is the full
    LP's.  An infeasible band falls back to the full support."""
    from scipy.optimize import linprog

    B = cost.shape[0]
    m = len(edges)
    h = np.where(h > 1e-15, h, 0.0)  # below HiGHS' tolerances; keeps the LP feasible
    h = h / h.sum(axis=1, keepdims=True)
    band = max(2, B // 6) if band is None else int(band)
    active = _initial_support(edges, nodes, cost, band)
    full_size = m * B * B
    deadline = None if time_limit is None else time.monotonic() + float(time_limit)
    rounds = 0
    while True:
        rounds += 1
        monitor.check_cancel("before the LP")
        A, b, c_vec, free, n_plan = _lp_problem(n, edges, w, nodes, h, cost, active)
        options = {} if deadline is None else {
            "time_limit": max(1.0, deadline - time.monotonic())}
        res = linprog(c_vec, A_eq=A, b_eq=b, bounds=(0, None), method="highs",
                      options=options)
        if res.status == 2 and n_plan >= full_size and "presolve" not in options:
            # the full problem is feasible by construction: retry without presolve, which
            # can misjudge near-zero label masses
            res = linprog(c_vec, A_eq=A, b_eq=b, bounds=(0, None), method="highs",
                          options={**options, "presolve": False})
        if res.status == 2 and n_plan < full_size:  # infeasible band: take everything
            ii, jj = (x.ravel() for x in np.meshgrid(np.arange(B), np.arange(B),
                                                     indexing="ij"))
            active = (np.repeat(np.arange(m), B * B), np.tile(ii, m), np.tile(jj, m))
            continue
        if res.status != 0 or res.x is None:
            raise ConvergenceError(f"the propagation LP did not solve: {res.message}")
        if n_plan >= full_size:
            break
        y = np.asarray(res.eqlin.marginals)
        yr = y[: 2 * m * B].reshape(m, 2, B)
        rc = w[:, None, None] * cost[None] - yr[:, 0, :, None] - yr[:, 1, None, :]
        have = np.zeros((m, B, B), dtype=bool)
        have[active] = True
        add = np.argwhere((rc < -1e-9) & ~have)
        monitor(rounds, float(-rc[~have].min()) if (~have).any() else 0.0)
        if len(add) == 0:
            break
        active = tuple(np.concatenate([a, add[:, k]]) for k, a in enumerate(active))
    H = np.zeros((n, B))
    H[nodes] = h
    H[free] = np.clip(res.x[n_plan:].reshape(len(free), B), 0.0, None)
    violation = float(np.abs(A @ res.x - b).max()) if len(b) else 0.0
    monitor(rounds, violation)
    return H, float(res.fun), violation, rounds


def propagate_circular(graph: Graph, labeled, histograms, *, bins,
                       algorithm: Literal["lp", "entropic"] = "lp", cost: np.ndarray | None = None,
                       gamma: float | None = None, tol: float = 1e-6,
                       max_iter: int | None = None, time_limit: float | None = None,
                       evaluate: bool = True, lp_value: float | None = None,
                       progress=None, should_cancel=None) -> CircularPropagationResult:
    r"""Propagate histograms over periodic bins (S¹) or a small metric space (§5.4).

    Parameters
    ----------
    graph : a :class:`~solvers.domains.Graph` (edges, positive weights), or any source
        :func:`~solvers.histograms.graphs.as_graph` accepts (mesh, point cloud, weights).
    labeled : ``(k,)`` nodes, at least one per connected component; histograms ``(k, B)``.
    bins : :class:`Bins` (``periodic=True`` for S¹) or edges.
    algorithm : ``"lp"`` (exact, HiGHS) or ``"entropic"`` (Alg. 4 on a periodic 1-D grid).
    cost : optional ``(B, B)`` ground cost (a small metric space); default
        :func:`circle_cost` (squared wrapped distance of bin centers).
    gamma : entropic regularization (default ``(2 w)^2``, ``w`` the mean bin width), in the
        bins' squared units; ``tol``, ``max_iter``: its Sinkhorn stopping rule.
    time_limit : seconds given to HiGHS.
    evaluate : compute the exact objective of the entropic result (per-edge LPs);
        ``lp_value``: a known LP optimum to report the gap against.
    """
    b = make_bins(bins)
    n, edges, w, nodes, h = _labels(graph, labeled, histograms, b)
    C = circle_cost(b) if cost is None else np.asarray(cost, dtype=np.float64)
    if C.shape != (b.count, b.count) or not np.all(np.isfinite(C)) or np.any(C < 0):
        raise InputError(f"cost must be a finite non-negative ({b.count}, {b.count}) matrix",
                         field="cost")
    if algorithm not in ("lp", "entropic"):
        raise InputError(f"algorithm must be 'lp' or 'entropic', got {algorithm!r}",
                         field="algorithm")
    monitor = Monitor(progress, should_cancel)
    if algorithm == "lp":
        H, value, violation, nit = _solve_lp(n, edges, w, nodes, h, C, monitor, time_limit)
        return CircularPropagationResult(algorithm="lp", histograms=H, value=value, lp_value=value,
                                         gap=0.0, labeled=nodes, iterations=nit,
                                         residual=violation, converged=violation <= 1e-7)
    if cost is not None:
        raise InputError("algorithm='entropic' uses the circle's heat kernel; a custom cost "
                         "needs algorithm='lp'", field="cost")
    from solvers.convolutional import wasserstein_propagation
    from solvers.domains import Grid

    width = float(b.widths.mean())
    if not np.allclose(b.widths, width, rtol=1e-9):
        raise InputError("algorithm='entropic' needs equal-width bins", field="bins.edges")
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
    return CircularPropagationResult(algorithm="entropic", histograms=H, value=value,
                                     lp_value=lp_value, gap=gap, gamma=gamma, labeled=nodes,
                                     iterations=res.iterations, residual=res.residual,
                                     converged=res.converged)
