r"""Wasserstein propagation on a graph of distributions (thesis Alg. 4, eq. 3.17-3.18).

A graph :math:`G = (V, E)` whose nodes carry distributions over the domain; the
nodes in :math:`V_0` are fixed, the others are unknown:

.. math::  \min_{\{\mu_u\}_{u \notin V_0}} \sum_{e = (u, u') \in E} \omega_e\,
           W^2_{2,H_t}(\mu_u, \mu_{u'}) .

Every edge carries a transport plan :math:`\pi_e = D_{a v_e} K_e D_{a w_e}` with
:math:`K_e = D_{p_e} H_t D_{q_e}` -- the heat kernel rescaled diagonally per edge
(eq. 3.18; e.g. :math:`p_e, q_e = e^{-\phi/\gamma}` adds a compatibility cost
:math:`\phi(x) + \psi(y)` to the transport, as soft maps do).  Iterative Bregman
projections visit the nodes in turn: at a fixed node every incident plan's
marginal is set to :math:`\mu_u` (a Sinkhorn update, Alg. 1); at a free node the
incident marginals are replaced by their weighted geometric mean (a barycenter
update, Alg. 2, weights :math:`\omega_e / \sum_{e \ni u} \omega_e`).  The
incident edges of a node form one kernel block.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from solvers.convolutional.common import (
    check_components,
    log_density,
    masses_block,
    masses_from_log,
    prepare,
)
from solvers.errors import InputError


@dataclass
class PropagationResult:
    """``masses`` ``(n, n_nodes)``: the fixed inputs and the propagated distributions."""

    masses: np.ndarray
    iterations: int
    residual: float
    converged: bool
    free_nodes: np.ndarray
    gamma: float = 0.0
    t: float = 0.0


def _check_graph(n_nodes, edges, edge_weights, fixed):
    try:
        n_nodes = int(n_nodes)
    except (TypeError, ValueError) as exc:
        raise InputError("n_nodes must be an integer", field="n_nodes") from exc
    if n_nodes < 2:
        raise InputError("propagation needs at least two nodes", field="n_nodes")
    e = np.asarray(edges)
    if e.ndim != 2 or e.shape[1] != 2 or len(e) == 0:
        raise InputError(f"edges must have shape (m, 2) with m > 0, got {e.shape}",
                         field="edges")
    if not np.issubdtype(e.dtype, np.integer):
        raise InputError("edge endpoints must be integers", field="edges")
    e = e.astype(np.int64)
    if e.min() < 0 or e.max() >= n_nodes:
        raise InputError(f"edge endpoints must lie in [0, {n_nodes - 1}]", field="edges")
    if np.any(e[:, 0] == e[:, 1]):
        raise InputError("edges must join two different nodes", field="edges")
    if edge_weights is None:
        w = np.ones(len(e))
    else:
        w = np.asarray(edge_weights, dtype=np.float64)
        if w.shape != (len(e),) or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise InputError(f"edge_weights must be {len(e)} positive numbers",
                             field="edge_weights")
    if not isinstance(fixed, dict) or not fixed:
        raise InputError("fixed must map at least one node index to its masses", field="fixed")
    keys = []
    for key in fixed:
        try:
            u = int(key)
        except (TypeError, ValueError) as exc:
            raise InputError(f"fixed node {key!r} is not an integer", field="fixed") from exc
        if not 0 <= u < n_nodes:
            raise InputError(f"fixed node {u} out of range [0, {n_nodes - 1}]", field="fixed")
        keys.append(u)
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n_nodes, n_nodes))
    _, labels = connected_components(graph, directed=False)
    anchored = set(labels[keys].tolist())
    lost = [u for u in range(n_nodes) if labels[u] not in anchored]
    if lost:
        raise InputError(f"node {lost[0]} is not connected to any fixed node", field="edges")
    return n_nodes, e, w, keys


def wasserstein_propagation(
    domain,
    n_nodes: int,
    edges,
    fixed: dict,
    *,
    edge_weights=None,
    edge_kernels: dict | None = None,
    gamma: float,
    t: float | None = None,
    substeps: int = 1,
    tol: float = 1e-5,
    max_iter: int | None = None,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> PropagationResult:
    r"""Propagate distributions from fixed graph nodes to the others (Alg. 4, eq. 3.17).

    Parameters
    ----------
    domain : the domain carrying the distributions.
    n_nodes : number of graph nodes; edges : ``(m, 2)`` node pairs ``(u, u')``.
    fixed : ``{node: (n,) masses}`` for the nodes of :math:`V_0` (at least one per
        connected piece of the graph).
    edge_weights : ``(m,)`` positive :math:`\omega_e` (default 1).
    edge_kernels : optional ``{edge: (p, q)}`` non-negative ``(n,)`` diagonal
        rescalings, :math:`K_e = D_p H_t D_q` (eq. 3.18), ``p`` on the side of
        ``u = edges[e, 0]``, ``q`` on the side of ``u' = edges[e, 1]``.
    gamma, t, substeps, tol, max_iter, progress, should_cancel : as in :func:`barycenter`;
        ``residual`` is the largest L1 violation of an edge marginal at its node.

    Returns
    -------
    PropagationResult(masses (n, n_nodes), iterations, residual, converged, free_nodes)
    """
    n_nodes, e, w, keys = _check_graph(n_nodes, edges, edge_weights, fixed)
    setup = prepare(domain, gamma=gamma, t=t, substeps=substeps, tol=tol, max_iter=max_iter,
                    progress=progress, should_cancel=should_cancel)
    a, logk = setup.areas, setup.logk
    fixed_m = {u: masses_block(domain, fixed[key], f"fixed[{u}]")
               for u, key in zip(keys, fixed, strict=True)}
    for u, m in fixed_m.items():
        if m.ndim != 1:
            raise InputError(f"fixed[{u}] must have shape ({domain.n},)", field=f"fixed[{u}]")
    check_components(domain, np.stack(list(fixed_m.values()), axis=1), setup.tol, "fixed")
    log_p = np.zeros((len(e), domain.n))
    log_q = np.zeros((len(e), domain.n))
    for key, pq in (edge_kernels or {}).items():
        try:
            k = int(key)
            p, q = pq
        except (TypeError, ValueError) as exc:
            raise InputError("edge_kernels maps an edge index to a pair (p, q)",
                             field="edge_kernels") from exc
        if not 0 <= k < len(e):
            raise InputError(f"edge_kernels: edge {k} out of range", field="edge_kernels")
        for name, arr, out in (("p", p, log_p), ("q", q, log_q)):
            x = np.asarray(arr, dtype=np.float64)
            if x.shape != (domain.n,) or not np.all(np.isfinite(x)) or np.any(x < 0):
                raise InputError(f"edge_kernels[{k}].{name} must be {domain.n} finite "
                                 "non-negative numbers", field="edge_kernels")
            with np.errstate(divide="ignore"):
                out[k] = np.log(x)

    # Scaling logs per edge end: S[e, 0] at node e0, S[e, 1] at node e1.
    S = np.zeros((len(e), 2, domain.n))
    incident = [[] for _ in range(n_nodes)]
    for k, (u0, u1) in enumerate(e):
        incident[u0].append((k, 0))
        incident[u1].append((k, 1))
    log_fixed = {u: log_density(m, a) for u, m in fixed_m.items()}
    free = np.array([u for u in range(n_nodes) if u not in fixed_m], dtype=np.int64)
    log_bar = {int(u): np.zeros(domain.n) for u in free}
    it = 0
    residual = np.inf
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        while True:
            sweep = 0.0
            for u in range(n_nodes):
                ends = incident[u]
                # Kernel from the other end towards u: side 0 gets D_p H D_q, side 1 D_q H D_p.
                block = np.stack([S[k, 1 - s] + (log_q[k] if s == 0 else log_p[k])
                                  for k, s in ends], axis=1)
                out = logk(block)
                out += np.stack([log_p[k] if s == 0 else log_q[k] for k, s in ends], axis=1)
                cur = np.stack([S[k, s] for k, s in ends], axis=1)
                ld = cur + out
                if u in fixed_m:
                    target = np.broadcast_to(log_fixed[u][:, None], ld.shape)
                    new = np.where(fixed_m[u][:, None] > 0, target - out, -np.inf)
                else:
                    om = np.array([w[k] for k, _ in ends])
                    om = om / om.sum()
                    lbar = np.where(np.isfinite(ld), ld, -1e300) @ om
                    log_bar[u] = lbar
                    target = np.broadcast_to(lbar[:, None], ld.shape)
                    new = cur + target - ld
                gap = np.abs(a[:, None] * (np.exp(ld) - np.exp(target))).sum(axis=0)
                sweep = max(sweep, float(np.max(gap)))
                for j, (k, s) in enumerate(ends):
                    S[k, s] = new[:, j]
            residual = sweep if np.isfinite(sweep) else float("inf")
            setup.monitor(it, residual)
            if residual <= setup.tol or it >= setup.max_iter or not np.isfinite(residual):
                break
            it += 1
    masses = np.zeros((domain.n, n_nodes))
    for u, m in fixed_m.items():
        masses[:, u] = m
    for u in free:
        masses[:, u] = masses_from_log(log_bar[int(u)], a)
    return PropagationResult(masses=masses, iterations=int(it), residual=float(residual),
                             converged=bool(residual <= setup.tol), free_nodes=free,
                             gamma=setup.gamma, t=setup.t)
