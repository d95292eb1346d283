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
update, Alg. 2, weights :math:`\omega_e / \sum_{e \ni u} \omega_e`).

Batched sweeps.  The update of a node reads only the scalings at the *other* ends of its
edges, so nodes that share no edge can be updated at once with the same result as one
after the other.  The nodes are colored greedily (no edge inside a color class) and a sweep
runs the classes in turn: every kernel application of a class -- one column per incident
edge end of its nodes, the diagonal rescalings applied outside the kernel -- is one
multi-column solve.  This is Gauss–Seidel in the node order "by color", the same Bregman
projections and the same fixed point as visiting the nodes one by one, with a handful of
multi-RHS solves per sweep instead of one small solve per node.

``node_scalings`` is the node-level case of eq. 3.18 that soft maps use:
:math:`K_e = D_{d_u} H_t D_{d_{u'}}` for every edge, stored once per node (``n_nodes × n``)
instead of twice per edge.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix

from solvers.convolutional.common import (
    check_components,
    log_density,
    masses_block,
    masses_from_log,
    prepare,
)
from solvers.convolutional.distance import watch_stagnation
from solvers.errors import InputError
from solvers.validation import check_anchored, check_edge_weights, check_edges


@dataclass
class PropagationResult:
    r"""``masses`` ``(n, n_nodes)``: the fixed inputs and the propagated distributions.

    ``edge_values`` ``(m,)``: per edge the convolutional transport value
    :math:`\gamma(\langle m_u, \log v_e\rangle + \langle m_{u'}, \log w_e\rangle)` of its
    final plan (eq. 3.10, the scalings without the diagonal rescalings), i.e. the entropic
    :math:`W^2_{2,H_t}` of the edge; ``colors``: color classes per sweep (kernel blocks).
    """

    masses: np.ndarray
    iterations: int
    residual: float
    converged: bool
    free_nodes: np.ndarray
    gamma: float = 0.0
    t: float = 0.0
    edge_values: np.ndarray | None = None
    colors: int = 0


def _check_graph(n_nodes, edges, edge_weights, fixed):
    try:
        n_nodes = int(n_nodes)
    except (TypeError, ValueError) as exc:
        raise InputError("n_nodes must be an integer", field="n_nodes") from exc
    if n_nodes < 2:
        raise InputError("propagation needs at least two nodes", field="n_nodes")
    e = check_edges(edges, n_nodes, "edges")
    if len(e) == 0:
        raise InputError("edges must have shape (m, 2) with m > 0", field="edges")
    w = check_edge_weights(edge_weights, len(e), "edge_weights")
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
    check_anchored(n_nodes, e, keys, "edges")
    return n_nodes, e, w, keys


def check_edge_kernels(edge_kernels, n_edges: int, n: int):
    r"""Validate ``{edge: (p, q)}`` diagonal rescalings (eq. 3.18); return their logs.

    Returns ``(log_p, log_q)`` as ``(n_edges, n)`` arrays (zeros where an edge has none), or
    ``(None, None)`` when ``edge_kernels`` is empty or ``None``.
    """
    if not edge_kernels:
        return None, None
    if not isinstance(edge_kernels, dict):
        raise InputError("edge_kernels maps an edge index to a pair (p, q)",
                         field="edge_kernels")
    log_p = np.zeros((n_edges, n))
    log_q = np.zeros((n_edges, n))
    for key, pq in edge_kernels.items():
        try:
            k = int(key)
            p, q = pq
        except (TypeError, ValueError) as exc:
            raise InputError("edge_kernels maps an edge index to a pair (p, q)",
                             field="edge_kernels") from exc
        if not 0 <= k < n_edges:
            raise InputError(f"edge_kernels: edge {k} out of range", field="edge_kernels")
        for name, arr, out in (("p", p, log_p), ("q", q, log_q)):
            x = np.asarray(arr, dtype=np.float64)
            if x.shape != (n,) or not np.all(np.isfinite(x)) or np.any(x < 0):
                raise InputError(f"edge_kernels[{k}].{name} must be {n} finite "
                                 "non-negative numbers", field="edge_kernels")
            with np.errstate(divide="ignore"):
                out[k] = np.log(x)
    return log_p, log_q


def check_node_scalings(node_scalings, n_nodes: int, n: int) -> np.ndarray | None:
    """Validate ``(n_nodes, n)`` log-rescalings :math:`\\log d_u` (finite or ``-inf``)."""
    if node_scalings is None:
        return None
    x = np.asarray(node_scalings, dtype=np.float64)
    if x.shape != (n_nodes, n):
        raise InputError(f"node_scalings must have shape ({n_nodes}, {n}), got {x.shape}",
                         field="node_scalings")
    if np.any(np.isnan(x)) or np.any(x == np.inf):
        raise InputError("node_scalings must be finite logs (or -inf)", field="node_scalings")
    return x


def greedy_coloring(n_nodes: int, edges: np.ndarray) -> np.ndarray:
    """Color classes with no edge inside a class (greedy, largest degree first)."""
    nbrs = [[] for _ in range(n_nodes)]
    for u0, u1 in edges:
        nbrs[u0].append(u1)
        nbrs[u1].append(u0)
    color = -np.ones(n_nodes, dtype=np.int64)
    for u in np.argsort([-len(x) for x in nbrs], kind="stable"):
        used = {int(color[v]) for v in nbrs[u]}
        c = 0
        while c in used:
            c += 1
        color[u] = c
    return color


# Columns per kernel solve: the sparse triangular solves are fastest on narrow blocks.
_SOLVE_COLUMNS = 32
# Edge ends updated together (bounds the (ends, n) temporaries of a sweep).
_BATCH_ENDS = 512


def wasserstein_propagation(
    domain,
    n_nodes: int,
    edges,
    fixed: dict,
    *,
    edge_weights=None,
    edge_kernels: dict | None = None,
    node_scalings=None,
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
    node_scalings : optional ``(n_nodes, n)`` logs :math:`\log d_u`; every edge's kernel
        gets :math:`D_{d_u} \cdot D_{d_{u'}}` on its two sides (combined with
        ``edge_kernels``).  With :math:`\log d_u = -c_u / (\gamma \sum_{e \ni u}\omega_e)` this
        adds :math:`\sum_u \langle c_u, m_u\rangle` to the objective (soft maps, §3.7).
    gamma, t, substeps, tol, max_iter, progress, should_cancel : as in :func:`barycenter`;
        ``residual`` is the largest L1 violation of an edge marginal at its node.

    Returns
    -------
    PropagationResult(masses (n, n_nodes), iterations, residual, converged, free_nodes,
    edge_values (m,))
    """
    n_nodes, e, w, keys = _check_graph(n_nodes, edges, edge_weights, fixed)
    setup = prepare(domain, gamma=gamma, t=t, substeps=substeps, tol=tol, max_iter=max_iter,
                    progress=progress, should_cancel=should_cancel)
    setup.monitor = watch_stagnation(setup, project=max_iter is None)  # stalled -> stop
    a, logk = setup.areas, setup.logk
    n = domain.n
    fixed_m = {u: masses_block(domain, fixed[key], f"fixed[{u}]")
               for u, key in zip(keys, fixed, strict=True)}
    for u, m in fixed_m.items():
        if m.ndim != 1:
            raise InputError(f"fixed[{u}] must have shape ({n},)", field=f"fixed[{u}]")
    check_components(domain, np.stack(list(fixed_m.values()), axis=1), setup.tol, "fixed")
    log_p, log_q = check_edge_kernels(edge_kernels, len(e), n)
    log_d = check_node_scalings(node_scalings, n_nodes, n)

    # Edge ends: end j = (edge k, side s) at node e[k, s]; its scaling log S[k, s].
    S = np.zeros((len(e), 2, n))
    is_fixed = np.zeros(n_nodes, dtype=bool)
    is_fixed[list(fixed_m)] = True
    log_fixed = np.zeros((n_nodes, n))
    for u, m in fixed_m.items():
        log_fixed[u] = log_density(m, a)
    color = greedy_coloring(n_nodes, e)
    classes = []
    degree = np.bincount(e.ravel(), minlength=n_nodes)
    batches = []
    for c in range(int(color.max()) + 1):
        # A color class in batches of at most _BATCH_ENDS edge ends (split between nodes:
        # nodes of one class are independent, so the batches give the same updates).
        nodes_c = np.flatnonzero(color == c)
        cut = np.searchsorted(np.cumsum(degree[nodes_c]),
                              np.arange(_BATCH_ENDS, degree[nodes_c].sum(), _BATCH_ENDS))
        batches += np.split(nodes_c, np.unique(cut))
    for nodes_b in batches:
        if len(nodes_b) == 0:
            continue
        member = np.zeros(n_nodes, dtype=bool)
        member[nodes_b] = True
        k0 = np.flatnonzero(member[e[:, 0]])
        k1 = np.flatnonzero(member[e[:, 1]])
        kk = np.concatenate([k0, k1])
        ss = np.concatenate([np.zeros(len(k0), np.int64), np.ones(len(k1), np.int64)])
        node = e[kk, ss]
        order = np.argsort(node, kind="stable")
        kk, ss, node = kk[order], ss[order], node[order]
        starts = np.flatnonzero(np.r_[True, node[1:] != node[:-1]])
        owners = node[starts]
        group = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(node)]))
        om = w[kk] / np.bincount(group, weights=w[kk])[group]
        # Weighted geometric mean over each node's ends: one sparse (owners x ends) product.
        mean = csr_matrix((om, (group, np.arange(len(kk)))), shape=(len(starts), len(kk)))
        classes.append((kk, ss, node, group, owners, mean))
    free = np.flatnonzero(~is_fixed)
    log_bar = np.zeros((n_nodes, n))

    def side_scaling(kk, side, node):
        if log_p is None and log_d is None:
            return 0.0
        out = np.zeros((len(kk), n))
        if log_p is not None:
            out += np.where((side == 0)[:, None], log_p[kk], log_q[kk])
        if log_d is not None:
            out += log_d[node]
        return out

    it = 0
    residual = np.inf
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        while True:
            sweep = 0.0
            for kk, ss, node, group, owners, mean in classes:
                other = 1 - ss
                # Kernel from the other end towards each end: D_own H_t D_other (eq. 3.18).
                block = S[kk, other] + side_scaling(kk, other, e[kk, other])
                out = np.empty_like(block)
                for c0 in range(0, len(kk), _SOLVE_COLUMNS):
                    cols = slice(c0, c0 + _SOLVE_COLUMNS)
                    out[cols] = logk(np.ascontiguousarray(block[cols].T)).T
                del block
                out += side_scaling(kk, ss, node)
                ld = S[kk, ss] + out
                fx = is_fixed[node]
                target = np.empty_like(ld)
                target[fx] = log_fixed[node[fx]]
                lbar = mean @ np.maximum(ld, -1e300)
                log_bar[owners] = lbar
                nf = ~fx
                target[nf] = lbar[group[nf]]
                gap = np.abs(np.exp(ld) - np.exp(target)) @ a
                sweep = max(sweep, float(np.max(gap)))
                new = target - out
                if fx.any():
                    masses_fx = np.stack([fixed_m[int(u)] for u in node[fx]])
                    new[fx] = np.where(masses_fx > 0, new[fx], -np.inf)
                S[kk, ss] = new
            residual = sweep if np.isfinite(sweep) else float("inf")
            setup.monitor(it, residual)
            if residual <= setup.tol or it >= setup.max_iter or not np.isfinite(residual) \
                    or setup.monitor.stalled:
                break
            it += 1
    masses = np.zeros((n, n_nodes))
    for u, m in fixed_m.items():
        masses[:, u] = m
    if len(free):
        masses[:, free] = masses_from_log(log_bar[free].T, a)
    node_mass = masses.T
    values = np.zeros(len(e))
    for s in (0, 1):
        ms = node_mass[e[:, s]]
        values += np.einsum("ij,ij->i", ms, np.where(ms > 0, S[:, s], 0.0))
    return PropagationResult(masses=masses, iterations=int(it), residual=float(residual),
                             converged=bool(residual <= setup.tol), free_nodes=free,
                             gamma=setup.gamma, t=setup.t, edge_values=setup.gamma * values,
                             colors=int(color.max()) + 1)
