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
the same fixed point as visiting the nodes one by one.  The chunks of a color class run in
threads: the compiled passes and the solves release the GIL (the kernel is factored by the
``"triangular"`` backend of :func:`solvers.linalg.factorize_spd`; cholespy's solves hold
it).  ``acceleration="over-relaxation"`` over-relaxes the sweeps (same fixed point, fewer
sweeps on large graphs).

Active nodes.  Late in a solve most nodes have converged while a few still move (on a
512-node soft map the median gap is 1e-3 of the largest one after 60 sweeps).  A sweep
visits only the nodes whose gap may exceed ``tol / 2``: a node's gap is bounded by twice the
sum of the L1 changes of its edges' plans since its last visit (each is the gap of the
opposite end when that end was updated, times the over-relaxation), plus what its own
over-relaxed update left.  Skipping a node is a different order of the same Bregman
projections (same fixed point), and convergence is only declared after a sweep that visits
every node.

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
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from solvers.convolutional.common import (
    BARYCENTER_ACCELERATIONS,
    OverRelaxation,
    check_acceleration,
    floor_underflow,
    log_density,
    masses_from_log,
    prepare,
)
from solvers.convolutional.distance import watch_stagnation
from solvers.errors import InputError
from solvers.parallel import thread_count
from solvers.regularization import shape_method
from solvers.validation import (
    check_anchored,
    check_components,
    check_edge_weights,
    check_edges,
    masses_block,
)


@dataclass
class PropagationResult:
    r"""Result of :func:`wasserstein_propagation`.

    Attributes
    ----------
    masses : (n, n_nodes) array
        The fixed inputs and the propagated distributions.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
        ``residual``: the largest L1 violation of an edge marginal at its node.
    free_nodes : array of int
        The nodes solved for.
    gamma, t : float
        Regularization and heat time used.
    edge_values : (m,) array or None
        Per edge the convolutional transport value
        :math:`\gamma(\langle m_u, \log v_e\rangle + \langle m_{u'}, \log w_e\rangle)` of its
        final plan (eq. 3.10, the scalings without the diagonal rescalings), i.e. the
        entropic :math:`W^2_{2,H_t}` of the edge.
    colors : int
        Color classes per sweep (kernel blocks).
    kernel_columns : int
        Kernel applications in all (one per visited edge end and sweep).
    scalings : (2m, n) array or None
        With ``keep_scalings=True``, the final log-scalings :math:`\log v_e, \log w_e` of
        the edge ends (without the diagonal rescalings), for a later ``initial``.
    end_order : (2m,) int array or None
        Row ``r`` of ``scalings`` is the end ``(edge end_order[r] % m, side
        end_order[r] // m)``.
    method : str
        The kernel used.
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
    kernel_columns: int = 0
    scalings: np.ndarray | None = None
    end_order: np.ndarray | None = None
    method: str = "convolutional"


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
    """Validate ``(n_nodes, n)`` log-rescalings :math:`\\log d_u` (finite or ``-inf``;
    float32 or float64)."""
    if node_scalings is None:
        return None
    x = np.asarray(node_scalings)
    if x.dtype != np.float32:  # float32 logs are kept as given (no float64 copy)
        x = np.asarray(x, dtype=np.float64)
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
# Sweeps per rate measurement of the adaptive over-relaxation (OverRelaxation's default is
# 5): 3 applied fewer kernel columns at every soft-map size measured (bench/softmaps.py
# relaxation).
_RELAX_WINDOW = 3
# A node is skipped while the bound on its gap is below this fraction of tol.
_ACTIVE = 0.5
# Nodes whose final masses are formed at once (the (n, nodes) temporaries of the exp).
MASS_COLUMNS = 64


def wasserstein_propagation(
    domain, n_nodes: int, edges, fixed: dict, *, edge_weights=None,
    edge_kernels: dict | None = None, node_scalings=None, gamma: float,
    t: float | None = None, substeps: int = 1, tol: float = 1e-5, max_iter: int | None = None,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None, acceleration: str = "none",
    threads: int | None = None, initial: PropagationResult | None = None,
    keep_scalings: bool = False, start_masses=None, scalings_dtype=np.float64,
    method: str = "auto",
) -> PropagationResult:
    r"""Propagate distributions from fixed graph nodes to the others (Alg. 4, eq. 3.17).

    Parameters
    ----------
    domain : the domain carrying the distributions.
    n_nodes : number of graph nodes.
    edges : ``(m, 2)`` node pairs ``(u, u')``.
    fixed : ``{node: (n,) masses}`` for the nodes of :math:`V_0` (at least one per
        connected piece of the graph).
    edge_weights : ``(m,)`` positive :math:`\omega_e` (default 1).
    edge_kernels : optional ``{edge: (p, q)}`` non-negative ``(n,)`` diagonal rescalings,
        :math:`K_e = D_p H_t D_q` (eq. 3.18), ``p`` on the side of ``u = edges[e, 0]``.
    node_scalings : optional ``(n_nodes, n)`` logs :math:`\log d_u`; every edge's kernel
        gets :math:`D_{d_u} \cdot D_{d_{u'}}` (combined with ``edge_kernels``).  With
        :math:`\log d_u = -c_u / (\gamma \sum_{e \ni u}\omega_e)` this adds
        :math:`\sum_u \langle c_u, m_u\rangle` to the objective (soft maps, §3.7).
    gamma, t, substeps, tol, max_iter, progress, should_cancel : as in :func:`barycenter`;
        ``residual`` is the largest L1 violation of an edge marginal at its node.
    acceleration : ``"none"`` (default: plain Alg. 4) or ``"over-relaxation"``: every
        sweep's update of the log-scalings is over-relaxed by :math:`\omega` adapted from
        the measured rate (:class:`OverRelaxation`, once the residual is below 0.5; backs
        off if it grows).  Same fixed point; fixed nodes take the plain Sinkhorn update.
    threads : worker threads for the chunks of a color class (default: the usable CPUs).
    initial : warm start: the result of an earlier call on the same graph and domain with
        ``keep_scalings=True``; its edge log-scalings times ``initial.gamma / gamma``
        (:math:`\varepsilon`-scaling) replace the zero start.  Same fixed point.
    keep_scalings : return the final edge log-scalings in ``scalings`` (``2m x n`` floats,
        the solver's largest array, handed over without a copy).
    start_masses : optional ``(n, n_nodes)`` guesses of the distributions (e.g. a coarser
        solve prolonged): first every edge takes one Sinkhorn step towards the guesses at
        its two ends (first ends, then second ends).  Same fixed point, another start.
    scalings_dtype : ``np.float64`` (default) or ``np.float32``: the storage of the edge
        log-scalings, of the barycenters' log-densities and of ``masses``; the arithmetic
        is float64 either way, so only stored values are rounded (relative 6e-8).
    method : the kernel, as in :func:`barycenter` (``result.method`` says which).

    Returns
    -------
    PropagationResult
        ``masses`` ``(n, n_nodes)``, ``iterations``, ``residual``, ``converged``,
        ``free_nodes``, ``edge_values`` ``(m,)``.
    """
    n_nodes, e, w, keys = _check_graph(n_nodes, edges, edge_weights, fixed)
    accelerate = check_acceleration(acceleration, BARYCENTER_ACCELERATIONS) == "over-relaxation"
    # The sweeps solve in threads: the triangular backend's solves release the GIL.
    setup = prepare(domain, gamma=gamma, t=t, substeps=substeps, tol=tol, max_iter=max_iter,
                    progress=progress, should_cancel=should_cancel, backend="triangular",
                    method=shape_method(domain, method))
    setup.monitor = watch_stagnation(setup, project=max_iter is None)  # stalled -> stop
    fixed_m = _fixed_masses(domain, fixed, keys, setup.tol)
    ends = _EdgeEnds.of_graph(n_nodes, e, w, domain.n, edge_kernels, node_scalings)
    if np.dtype(scalings_dtype) not in (np.float32, np.float64):
        raise InputError("scalings_dtype must be float32 or float64", field="scalings_dtype")
    T = ends.own_side_logs(slice(None), scalings_dtype)
    if initial is not None:
        _warm_start(T, initial, ends.order, setup.gamma)
    sweeper = _Sweeper(setup, T, ends.node, ends.opposite, ends.weight, fixed_m, threads)
    is_fixed = np.isin(np.arange(n_nodes), list(fixed_m))
    if start_masses is not None:
        if initial is not None:
            raise InputError("give initial or start_masses, not both", field="start_masses")
        _start_from_masses(sweeper, start_masses, ends, is_fixed, setup.areas)
    it, residual, every_node = _sweep_to_convergence(sweeper, ends, is_fixed, setup, accelerate)
    free = np.flatnonzero(~is_fixed)
    masses = _final_masses(sweeper, free, fixed_m, setup.areas)
    values = _edge_values(T, masses, ends, keep_scalings)
    return PropagationResult(
        masses=masses, iterations=int(it), residual=float(residual),
        converged=bool(residual <= setup.tol and every_node), free_nodes=free,
        gamma=setup.gamma, t=setup.t, edge_values=setup.gamma * values,
        colors=len(ends.by_color), kernel_columns=sweeper.columns,
        scalings=T if keep_scalings else None, end_order=ends.order, method=setup.method)


def _fixed_masses(domain, fixed, keys, tol) -> dict:
    """``{node: (n,) masses}`` of the fixed nodes, checked (one distribution each, every
    component of the domain carrying mass)."""
    n = domain.n
    fixed_m = {u: masses_block(domain, fixed[key], f"fixed[{u}]")
               for u, key in zip(keys, fixed, strict=True)}
    for u, m in fixed_m.items():
        if m.ndim != 1:
            raise InputError(f"fixed[{u}] must have shape ({n},)", field=f"fixed[{u}]")
    check_components(domain, np.stack(list(fixed_m.values()), axis=1), tol, "fixed")
    return fixed_m


@dataclass
class _EdgeEnds:
    """The edge ends of the graph, the rows of the sweeps' array ``T``, with their own-side
    rescalings.

    End ``(k, s)`` sits at node ``edges[k, s]``.  ``T`` holds, per end, its log-scaling plus
    its own-side log-rescaling (log p/q of eq. 3.18 and log d of the node): the kernel input
    seen from the opposite end is exp(T), and the plan's marginal at the end is
    T + log H_t exp(T_opposite), so a sweep never forms the rescalings again.  Rows are
    ordered by (color, node): the ends of a node are contiguous.  ``edge``, ``side``,
    ``node``: per row; ``opposite``: the row of the other end of its edge; ``order``: the
    row's index ``side * m + edge``; ``weight``: its edge weight over the node's total;
    ``by_color``: the nodes of each color class; ``degree``: per node.
    """

    edge: np.ndarray
    side: np.ndarray
    node: np.ndarray
    opposite: np.ndarray
    order: np.ndarray
    weight: np.ndarray
    by_color: list
    degree: np.ndarray
    n: int
    log_p: np.ndarray | None
    log_q: np.ndarray | None
    log_d: np.ndarray | None

    @classmethod
    def of_graph(cls, n_nodes, e, w, n, edge_kernels, node_scalings):
        """The ends of the edges ``e`` (weights ``w``) of a graph of ``n_nodes`` nodes, with
        the rescalings ``edge_kernels`` and ``node_scalings`` checked."""
        log_p, log_q = check_edge_kernels(edge_kernels, len(e), n)
        log_d = check_node_scalings(node_scalings, n_nodes, n)
        color = greedy_coloring(n_nodes, e)
        degree = np.bincount(e.ravel(), minlength=n_nodes)
        end_edge = np.concatenate([np.arange(len(e)), np.arange(len(e))])
        end_side = np.repeat(np.array([0, 1]), len(e))
        end_node = e[end_edge, end_side]
        order = np.lexsort((end_node, color[end_node]))
        end_edge, end_side, end_node = end_edge[order], end_side[order], end_node[order]
        row_of = np.empty((len(e), 2), dtype=np.int64)
        row_of[end_edge, end_side] = np.arange(2 * len(e))
        weight = w[end_edge] / np.bincount(e.ravel(), weights=np.repeat(w, 2),
                                           minlength=n_nodes)[end_node]
        return cls(end_edge, end_side, end_node, row_of[end_edge, 1 - end_side],
                   end_side * len(e) + end_edge, weight,
                   [np.flatnonzero(color == c) for c in range(int(color.max()) + 1)], degree,
                   n, log_p, log_q, log_d)

    def own_side_logs(self, rows, dtype=np.float64):
        """``(ends, n)`` own-side log-rescalings of the ends ``rows``."""
        return _own_side_logs(self.log_p, self.log_q, self.log_d, self.edge[rows],
                              self.side[rows], self.node[rows], self.n, dtype)


def _start_from_masses(sweeper, start_masses, ends, is_fixed, a) -> None:
    """Start the sweeps from guesses of the distributions: one Sinkhorn step per edge
    towards ``start_masses``, then the free nodes' log-scalings centred."""
    _sinkhorn_start(sweeper, start_masses, ends.side, ends.node, ends.opposite,
                    len(is_fixed), a)
    # Alg. 4's fixed point needs the weighted mean of the log-scalings at a free node to
    # be 0 (its dual constraint, kept by every barycenter update): centre them.
    own = ends.own_side_logs(slice(None))
    _centre_free_nodes(sweeper.T, own, sweeper.end_weight, ends.node, is_fixed)
    del own


def _sweep_to_convergence(sweeper, ends, is_fixed, setup, accelerate):
    """Run sweeps of the color classes until the residual is below ``setup.tol`` after a
    sweep over every node (or the solve stops); return ``(iterations, residual,
    every_node)``."""
    n_nodes = len(is_fixed)
    relax = OverRelaxation(enabled=accelerate, window=_RELAX_WINDOW)
    best = np.inf
    it = 0
    residual = np.inf
    omega = 1.0
    # Active nodes: a node is visited when the perturbation of its marginals since its last
    # visit may exceed _ACTIVE * tol (bounds below); the sweep that certifies convergence
    # visits every node.
    pending = np.zeros(n_nodes)  # sum of the L1 changes of its edges' plans since its visit
    settled = np.full(n_nodes, np.inf)  # its own gap left by the last (over-relaxed) update
    visit_all = True
    with np.errstate(over="ignore", under="ignore", invalid="ignore", divide="ignore"), \
            sweeper:
        while True:
            sweep = 0.0
            visited = 0
            for nodes in ends.by_color:
                if not visit_all:
                    # An end's marginal moves by at most the L1 change of its plan, and the
                    # node's barycenter by at most the largest such move: gap <= 2 pending.
                    nodes = nodes[2.0 * pending[nodes] + settled[nodes] >= _ACTIVE * setup.tol]
                visited += len(nodes)
                for chunk, (worst, gaps) in sweeper.run(nodes, ends.degree, omega):
                    sweep = max(sweep, worst)
                    pending[chunk.nodes] = 0.0
                    node_gap = np.maximum.reduceat(gaps, chunk.starts[:-1])
                    settled[chunk.nodes] = np.where(is_fixed[chunk.nodes], 0.0,
                                                    (omega - 1.0) * node_gap)
                    # The plan of an end's edge changed by the end's marginal change:
                    # its gap, over-relaxed by omega.
                    np.add.at(pending, ends.node[ends.opposite[chunk.rows]], omega * gaps)
            every_node = visited == n_nodes
            residual = sweep if np.isfinite(sweep) else float("inf")
            if accelerate and residual < _RELAX_BELOW:
                # The linear rate model behind OverRelaxation holds once the sweeps are in
                # their asymptotic regime; far from it (e.g. residual ~1 on a large graph at
                # small gamma) over-relaxed sweeps were measured to blow up.  A residual
                # _RESTART_ABOVE times the best one since the (re)start restarts it.
                if omega > 1.0 and residual > _RESTART_ABOVE * best:
                    relax, best = OverRelaxation(window=_RELAX_WINDOW), np.inf
                best = min(best, residual)
                omega = relax.update(residual)
            setup.monitor(it, residual)
            if (residual <= setup.tol and every_node) or it >= setup.max_iter \
                    or not np.isfinite(residual) or setup.monitor.stalled:
                break
            visit_all = residual <= setup.tol  # certify with a sweep over every node
            it += 1
    return it, residual, every_node


def _final_masses(sweeper, free, fixed_m, a) -> np.ndarray:
    """``(n, n_nodes)`` masses: the free nodes' barycenters and the fixed inputs.

    The masses overwrite the barycenters' log-densities, a block of nodes at a time (no
    second (n_nodes, n) array; the blocks' temporaries stay small); the result is its
    transpose, a view.
    """
    log_bar, sweeper.log_bar = sweeper.log_bar, None
    for c0 in range(0, len(free), MASS_COLUMNS):
        cols = free[c0:c0 + MASS_COLUMNS]
        log_bar[cols] = masses_from_log(log_bar[cols].T, a).T
    for u, m in fixed_m.items():
        log_bar[u] = m
    return log_bar.T


def _edge_values(T, masses, ends, keep_scalings) -> np.ndarray:
    r"""``(m,)`` per edge :math:`\langle m_u, \log v_e\rangle + \langle m_{u'}, \log w_e\rangle`.

    From the scalings S = T - (own-side rescalings), one chunk at a time; with
    ``keep_scalings``, S replaces T in place (no second (2m, n) array).
    """
    values = np.zeros(len(T) // 2)
    node_mass = masses.T
    for r0 in range(0, len(T), _SOLVE_COLUMNS):
        rows = slice(r0, r0 + _SOLVE_COLUMNS)
        own = ends.own_side_logs(rows)
        ms = node_mass[ends.node[rows]]
        # Where an end's own side is zero (log -inf) its scaling is undefined: 0.
        s_log = np.where(own > -np.inf, T[rows] - own, 0.0)
        np.add.at(values, ends.edge[rows],
                  np.einsum("ij,ij->i", ms, np.where(ms > 0, s_log, 0.0)))
        if keep_scalings:
            T[rows] = s_log
    return values


def _sinkhorn_start(sweeper, start_masses, end_side, end_node, opposite, n_nodes, a) -> None:
    """One Sinkhorn step per edge towards ``start_masses`` at its ends, in place in ``T``:
    the first ends' marginals are set to their guesses, then the second ends'."""
    m = np.asarray(start_masses, np.float64)
    if m.shape != (len(a), n_nodes) or not np.all(np.isfinite(m)) or np.any(m < 0):
        raise InputError(f"start_masses must be ({len(a)}, {n_nodes}) finite non-negative "
                         "masses", field="start_masses")
    T = sweeper.T
    floor = 1e-300
    for side in (0, 1):
        rows = np.flatnonzero(end_side == side)
        for r0 in range(0, len(rows), 256):
            r = rows[r0:r0 + 256]
            guess = np.log(np.maximum(m[:, end_node[r]].T, floor) / a[None, :])
            with np.errstate(over="ignore", under="ignore", invalid="ignore",
                             divide="ignore"):
                T[r] += guess - (T[r] + sweeper._log_kernel(opposite[r]))


def _centre_free_nodes(T, own, end_weight, end_node, is_fixed) -> None:
    """Subtract from the log-scalings ``T - own`` of every free node's ends their weighted
    mean (``end_weight`` sums to 1 over a node's ends; a node's ends are contiguous)."""
    starts = np.flatnonzero(np.r_[True, end_node[1:] != end_node[:-1]])
    bounds = np.r_[starts, len(end_node)]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        if is_fixed[end_node[a]]:
            continue
        S = T[a:b] - own[a:b]
        S = np.where(np.isfinite(S), S, 0.0)
        T[a:b] -= end_weight[a:b] @ S


def _warm_start(T, initial, end_order, gamma) -> None:
    """Add ``initial``'s edge log-scalings, rescaled to ``gamma``, to ``T`` in place."""
    if not isinstance(initial, PropagationResult) or initial.scalings is None:
        raise InputError("initial must be a PropagationResult made with keep_scalings=True",
                         field="initial")
    if initial.scalings.shape != T.shape or not np.array_equal(initial.end_order, end_order):
        raise InputError(f"initial has scalings of shape {initial.scalings.shape}; this graph "
                         f"and domain need {T.shape} in the same edge order", field="initial")
    ratio = initial.gamma / gamma
    for r0 in range(0, len(T), 256):
        T[r0:r0 + 256] += ratio * initial.scalings[r0:r0 + 256]


def _own_side_logs(log_p, log_q, log_d, end_edge, end_side, end_node, n, dtype=np.float64):
    """``(ends, n)`` own-side log-rescalings of edge ends (zeros without rescalings),
    filled in row blocks (no full-size temporaries)."""
    out = np.zeros((len(end_edge), n), dtype)
    for r0 in range(0, len(end_edge), 256):
        rows = slice(r0, r0 + 256)
        if log_p is not None:
            k, side = end_edge[rows], end_side[rows]
            out[rows] += np.where((side == 0)[:, None], log_p[k], log_q[k])
        if log_d is not None:
            out[rows] += log_d[end_node[rows]]
    return out


@dataclass
class _Chunk:
    """Whole nodes of one color class: ``rows`` their ends (rows of ``T``), node ``i`` owning
    ``rows[starts[i]:starts[i+1]]``."""

    nodes: np.ndarray
    rows: np.ndarray
    starts: np.ndarray


def _chunks(nodes, first_row, degree) -> list[_Chunk]:
    """``nodes`` (of one color, in row order) in consecutive chunks of about
    ``_SOLVE_COLUMNS`` ends."""
    if len(nodes) == 0:
        return []
    d = degree[nodes]
    before = np.cumsum(d) - d
    label = before // _SOLVE_COLUMNS
    cuts = np.flatnonzero(np.r_[True, label[1:] != label[:-1], True])
    out = []
    for c0, c1 in zip(cuts[:-1], cuts[1:], strict=True):
        part, dp = nodes[c0:c1], d[c0:c1]
        starts = np.r_[0, np.cumsum(dp)]
        rows = np.repeat(first_row[part] - starts[:-1], dp) + np.arange(starts[-1])
        out.append(_Chunk(part, rows, starts))
    return out


class _Sweeper:
    """The kernel applications and Bregman projections of chunks of edge ends, in threads.

    Implicit Euler kernels (meshes, point clouds, graphs) take a direct path: the rows'
    shifts in one compiled pass, numpy's vectorized exp/log around one solve of the whole
    chunk (``"triangular"`` factor, GIL released), row-major throughout (measured faster in
    threads than the same work through :class:`LogKernel`).  Other kernels, and rows whose dynamic
    range needs more than one band, go through :class:`LogKernel`.  The projections of the
    chunk's nodes are one compiled pass (:mod:`solvers.convolutional._propagation_kernels`).
    """

    def __init__(self, setup, T, end_node, opposite, end_weight, fixed_m, threads):
        from solvers.convolutional import _propagation_kernels as kernels

        self.kernels = kernels
        self.T, self.opposite, self.end_weight = T, opposite, end_weight
        self.logk = setup.logk
        kernel = setup.logk.kernel
        self.factor = getattr(kernel, "factor", None)
        if self.logk.use_log_apply or not hasattr(kernel, "mass"):
            self.factor = None
        self.mass = getattr(kernel, "mass", None)
        self.substeps = int(getattr(kernel, "substeps", 1))
        self.areas = setup.areas
        n_nodes = int(end_node.max()) + 1
        self.first_row = np.zeros(n_nodes, dtype=np.int64)  # a node's ends are contiguous
        self.first_row[end_node[::-1]] = np.arange(len(end_node))[::-1]
        self.fixed_slot = -np.ones(n_nodes, dtype=np.int64)
        self.fixed_slot[list(fixed_m)] = np.arange(len(fixed_m))
        self.log_fixed = np.stack([log_density(m, self.areas) for m in fixed_m.values()])
        self.log_bar = np.zeros((n_nodes, T.shape[1]), T.dtype)
        self.columns = 0
        self.threads = thread_count(threads)
        self._pool = None

    def __enter__(self):
        if self.threads > 1:
            self._pool = ThreadPoolExecutor(self.threads)
        return self

    def __exit__(self, *exc):
        if self._pool is not None:
            self._pool.shutdown()
        return False

    def run(self, nodes, degree, omega):
        """``(chunk, (largest gap, gaps of its ends))`` for the chunks of ``nodes``."""
        chunks = _chunks(nodes, self.first_row, degree)
        self.columns += int(degree[nodes].sum())
        def work(chunk):
            return self._update(chunk, omega)

        pool = self._pool if self._pool is not None and len(chunks) > 1 else None
        results = pool.map(work, chunks) if pool is not None else map(work, chunks)
        return zip(chunks, results, strict=True)

    def _log_kernel(self, opp):
        r"""``(k, n)`` :math:`\log H_t \exp(T_{opp})`."""
        X = np.asarray(self.T[opp], np.float64)  # a chunk's copy (float32 storage: widened)
        if self.factor is not None:
            tops, widest = self.kernels.row_range(X)
            if widest <= self.logk.band:
                X -= tops[:, None]
                np.exp(X, out=X)
                X *= self.mass
                z = self.factor.solve(X.T)  # the chunk's ends in one block
                for _ in range(self.substeps - 1):
                    z = self.factor.solve(self.mass[:, None] * z)
                np.maximum(z, 0.0, out=z)
                out = np.log(z.T)
                out += tops[:, None]
                return floor_underflow(out.T).T
        return np.ascontiguousarray(self.logk(X.T).T)

    def _update(self, chunk, omega):
        out = self._log_kernel(self.opposite[chunk.rows])
        gaps = np.empty(len(chunk.rows))
        worst = self.kernels.update_nodes(
            self.T, chunk.rows, chunk.starts, chunk.nodes, out, self.end_weight[chunk.rows],
            self.fixed_slot, self.log_fixed, self.areas, float(omega), self.log_bar, gaps)
        return float(worst), gaps
