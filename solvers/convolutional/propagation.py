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
runs the classes in turn, in chunks of whole nodes of about 32 edge ends: the kernel
applications of a chunk -- one column per edge end, the diagonal rescalings kept inside the
stored log-scalings -- are one multi-column solve, and the chunk's exp/log/gap work stays in
cache.  This is Gauss–Seidel in the node order "by color", the same Bregman projections and
the same fixed point as visiting the nodes one by one.  ``acceleration="over-relaxation"``
over-relaxes the sweeps (same fixed point, fewer sweeps on large graphs).

Normalized barycenters.  The free-node update normalizes the weighted geometric mean to
unit mass.  Plain Alg. 4 leaves it unnormalized, and then the plans' masses relax to 1 like
a harmonic function on the graph, pinned only at the fixed nodes: one hop per sweep, so on a
1,024-node soft-map graph the residual (a mass deficit at the fixed nodes) stayed near 1 for
tens of sweeps (bench/results/softmaps.md).  The fixed point is the same: normalizing shifts
the weighted mean of the free node's log-scalings by a scalar, which scales its kernels by a
constant; on the feasible set (every plan couples probability measures, since each
component of the graph holds a fixed node) that changes the objective by a constant only.
``tests/test_convolutional.py`` checks the fixed point against the textbook node-by-node
Alg. 4.

``node_scalings`` is the node-level case of eq. 3.18 that soft maps use:
:math:`K_e = D_{d_u} H_t D_{d_{u'}}` for every edge, stored once per node (``n_nodes × n``)
instead of twice per edge.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from solvers.convolutional.common import (
    BARYCENTER_ACCELERATIONS,
    OverRelaxation,
    check_acceleration,
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


# Edge ends per chunk (one kernel solve): the sparse triangular solves are fastest on
# narrow blocks, and a chunk's (ends, n) temporaries stay in cache.
_SOLVE_COLUMNS = 32
# Over-relaxation starts once the residual (largest L1 marginal violation, at most 2) is below.
_RELAX_BELOW = 0.5
# ... and restarts from plain sweeps if the residual exceeds this multiple of its best since
# the (re)start (10, not 2: the largest-violation residual spikes under over-relaxation
# without diverging; restarting at 2x, 1,024 soft-map samples were at 3.9e-3 after 97
# sweeps, against 2.7e-3 at 10x).
_RESTART_ABOVE = 10.0


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
    acceleration: str = "none",
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
    acceleration : ``"none"`` (default: the plain Bregman projections of Alg. 4) or
        ``"over-relaxation"``: every sweep's update of the log-scalings is over-relaxed,
        :math:`\log s \leftarrow \log s + \omega(\log s_{\text{Alg. 4}} - \log s)`,
        with :math:`\omega` adapted from the measured rate (:class:`OverRelaxation`,
        from plain sweeps once the residual is below 0.5; backs off if it grows).  The
        weighted mean of the log-scalings at a free node is kept as Alg. 4 keeps it, so the
        fixed point is the same; only the path to it changes (fixed nodes take the plain
        Sinkhorn update).

    Returns
    -------
    PropagationResult(masses (n, n_nodes), iterations, residual, converged, free_nodes,
    edge_values (m,))
    """
    n_nodes, e, w, keys = _check_graph(n_nodes, edges, edge_weights, fixed)
    accelerate = check_acceleration(acceleration, BARYCENTER_ACCELERATIONS) == "over-relaxation"
    relax = OverRelaxation(enabled=accelerate)
    best = np.inf
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

    # Edge ends: end (k, s) sits at node e[k, s].  T holds, per end, its log-scaling plus
    # its own-side log-rescaling (log p/q of eq. 3.18 and log d of the node): the kernel
    # input seen from the opposite end is exp(T), and the plan's marginal at the end is
    # T + log H_t exp(T_opposite), so a sweep never forms the rescalings again.
    is_fixed = np.zeros(n_nodes, dtype=bool)
    is_fixed[list(fixed_m)] = True
    color = greedy_coloring(n_nodes, e)
    degree = np.bincount(e.ravel(), minlength=n_nodes)
    end_edge = np.concatenate([np.arange(len(e)), np.arange(len(e))])
    end_side = np.repeat(np.array([0, 1]), len(e))
    end_node = e[end_edge, end_side]
    # Rows of T ordered by (color, node): a chunk of whole nodes is a contiguous slice.
    order = np.lexsort((end_node, color[end_node]))
    end_edge, end_side, end_node = end_edge[order], end_side[order], end_node[order]
    row_of = np.empty((len(e), 2), dtype=np.int64)
    row_of[end_edge, end_side] = np.arange(2 * len(e))
    opposite = row_of[end_edge, 1 - end_side]
    chunks = _node_chunks(color, degree, end_node, w[end_edge])
    for chunk in chunks:
        local = end_node[chunk[0]]
        chunk[4] = [(int(j), int(local[j])) for j in np.flatnonzero(is_fixed[local])]
        chunk[5] = [(r0, r1, not is_fixed[local[r0]]) for r0, r1, _ in chunk[5]]
    T = _own_side_logs(log_p, log_q, log_d, end_edge, end_side, end_node, n)
    fixed_density = {u: m / a for u, m in fixed_m.items()}
    log_fixed = {u: log_density(m, a) for u, m in fixed_m.items()}
    free = np.flatnonzero(~is_fixed)
    log_bar = np.zeros((n_nodes, n))

    it = 0
    residual = np.inf
    omega = 1.0
    with np.errstate(over="ignore", under="ignore", invalid="ignore", divide="ignore"):
        while True:
            sweep = 0.0
            for rows, nodes, mean, group, fixed_ends, node_rows in chunks:
                out = logk(T[opposite[rows]].T).T  # (ends, n): log H_t exp(T_opposite)
                old = T[rows]
                ld = old + out  # log-density of each end's plan marginal at its node
                np.maximum(ld, -1e300, out=ld)  # no -inf * 0 in the mean below
                lbar = mean @ ld  # weighted geometric mean per node (rows of fixed: 0)
                # Normalized to unit mass (see the module notes): weight = exp(lbar) a.
                top = np.max(lbar, axis=1, keepdims=True)
                weight = np.exp(lbar - top)
                weight *= a
                mass = weight.sum(axis=1, keepdims=True)
                weight /= mass
                lbar -= top + np.log(mass)
                log_bar[nodes] = lbar
                new = lbar[group]
                new -= out  # the Bregman projection: marginals = their geometric mean
                for j, u in fixed_ends:  # Sinkhorn update at fixed nodes
                    new[j] = log_fixed[u] - out[j]
                    sweep = max(sweep, float(np.abs(np.exp(ld[j]) - fixed_density[u]) @ a))
                # Free ends: the marginal is exp(lbar + delta), delta = old - new, so its
                # L1 gap is <a exp(lbar), |expm1(delta)|> (float32: relative precision
                # 1e-7 of the gap itself; clipped where the marginal exceeds e^80 x target).
                delta = (old - new).astype(np.float32)  # difference in float64: no -inf+inf
                np.minimum(delta, 80.0, out=delta)
                np.abs(np.expm1(delta, out=delta), out=delta)
                for k, (r0, r1, free_node) in enumerate(node_rows):
                    if free_node:
                        gap = delta[r0:r1] @ weight[k]
                        sweep = max(sweep, float(np.max(gap)))
                if omega != 1.0:
                    new -= old
                    new *= omega
                    new += old
                    for j, u in fixed_ends:
                        new[j] = log_fixed[u] - out[j]
                T[rows] = new
            residual = sweep if np.isfinite(sweep) else float("inf")
            if accelerate and residual < _RELAX_BELOW:
                # The linear rate model behind OverRelaxation holds once the sweeps are in
                # their asymptotic regime; far from it (e.g. residual ~1 on a large graph at
                # small gamma) over-relaxed sweeps were measured to blow up.  A residual
                # _RESTART_ABOVE times the best one since the (re)start restarts it.
                if omega > 1.0 and residual > _RESTART_ABOVE * best:
                    relax, best = OverRelaxation(), np.inf
                best = min(best, residual)
                omega = relax.update(residual)
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
    # Edge values from the scalings S = T - (own-side rescalings), one chunk at a time.
    values = np.zeros(len(e))
    node_mass = masses.T
    for rows, *_ in chunks:
        own = _own_side_logs(log_p, log_q, log_d, end_edge[rows], end_side[rows],
                             end_node[rows], n)
        ms = node_mass[end_node[rows]]
        s_log = T[rows] - own if isinstance(own, np.ndarray) else T[rows]
        np.add.at(values, end_edge[rows],
                  np.einsum("ij,ij->i", ms, np.where(ms > 0, s_log, 0.0)))
    return PropagationResult(masses=masses, iterations=int(it), residual=float(residual),
                             converged=bool(residual <= setup.tol), free_nodes=free,
                             gamma=setup.gamma, t=setup.t, edge_values=setup.gamma * values,
                             colors=int(color.max()) + 1)


def _own_side_logs(log_p, log_q, log_d, end_edge, end_side, end_node, n):
    """``(ends, n)`` own-side log-rescalings of edge ends (zeros without rescalings),
    filled in row blocks (no full-size temporaries)."""
    out = np.zeros((len(end_edge), n))
    for r0 in range(0, len(end_edge), 256):
        rows = slice(r0, r0 + 256)
        if log_p is not None:
            k, side = end_edge[rows], end_side[rows]
            out[rows] += np.where((side == 0)[:, None], log_p[k], log_q[k])
        if log_d is not None:
            out[rows] += log_d[end_node[rows]]
    return out


def _node_chunks(color, degree, end_node, end_weight):
    """Chunks of whole nodes of one color class, about ``_SOLVE_COLUMNS`` ends each.

    Returns ``(rows, nodes, mean, group, fixed_ends)`` per chunk: the slice of its ends in
    ``T``, its nodes, the ``(nodes, ends)`` weights of the geometric mean, the local node of
    every end, and ``(local end, node)`` for ends at fixed nodes (filled by the caller).
    """
    starts = np.flatnonzero(np.r_[True, end_node[1:] != end_node[:-1]])
    bounds = np.r_[starts, len(end_node)]
    chunks = []
    i = 0
    while i < len(starts):
        c = color[end_node[starts[i]]]
        j = i + 1
        while (j < len(starts) and color[end_node[starts[j]]] == c
               and bounds[j + 1] - bounds[i] <= _SOLVE_COLUMNS):
            j += 1
        rows = slice(int(bounds[i]), int(bounds[j]))
        local = end_node[rows]
        nodes, group = np.unique(local, return_inverse=True)
        wt = end_weight[rows]
        mean = np.zeros((len(nodes), len(local)))
        mean[group, np.arange(len(local))] = wt / np.bincount(group, weights=wt)[group]
        node_starts = np.flatnonzero(np.r_[True, local[1:] != local[:-1]])
        node_rows = [(int(r0), int(r1), True) for r0, r1 in
                     zip(node_starts, np.r_[node_starts[1:], len(local)], strict=True)]
        chunks.append([rows, nodes, mean, group, [], node_rows])
        i = j
    return chunks
