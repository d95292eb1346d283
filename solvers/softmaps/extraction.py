r"""Point-to-point correspondences from a soft map (thesis §4.5.1) and their refinements.

* :func:`mode` -- the most likely target vertex of each distribution (largest density
  :math:`\rho_x(y) = \mu_x(y) / a(y)`);
* :func:`barycentric_projection` -- the mass-weighted mean position of each distribution
  near its mode, projected back onto the target surface (its nearest vertex);
* :func:`trace_path` -- eq. 4.7: starting from one seed match, follow the source graph and
  move the matched point by explicit Euler steps along the transportation potential's
  gradient :math:`\nabla Q` (:func:`solvers.softmaps.energies.transportation_potential`);
* :func:`zoomout` -- spectral upsampling (Melzi et al. 2019, "ZoomOut"): a point map gives
  a functional map :math:`C = \Phi_0^\top A_0 \Phi[T]` in ``k`` eigenfunctions, ``k`` grows
  step by step and the map is re-read as nearest neighbours of the rows of :math:`\Phi_0`
  among the rows of :math:`\Phi C^\top`; ``symmetric=True`` also reads out the reverse
  map and ties the two functional maps by :math:`C_{M\to M_0} = C^\top` (the adjoint of an
  area-preserving map, as in the bijective ZoomOut of Ren et al. 2021).  Used as the
  optional refinement after extraction.
* :func:`sinkhorn_projection` -- the soft map's plan :math:`\pi = D_{c}P` (``c`` the
  source cell areas) scaled by rows and columns, :math:`\pi \leftarrow D_u \pi D_v`, until its
  target marginal is the target's area :math:`a` as well (the doubly-stochastic set w.r.t.
  the two area measures, i.e. bijectivity density :math:`b \equiv 1`, eq. 4.5); an optional
  refinement *before* extraction.
* :func:`extract_correspondence` -- extraction then refinement as :func:`soft_map` does it:
  ``refine`` one of :data:`REFINEMENTS` (``"sinkhorn+zoomout"``: both).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from solvers.errors import InputError
from solvers.jit import cached_njit
from solvers.monitor import SolverResult
from solvers.parallel import run_blocks
from solvers.softmaps.descriptors import eigenpairs
from solvers.validation import check_choice, check_indices, check_int, check_positive

EXTRACTIONS = ("mode", "barycentric", "path")
REFINEMENTS = ("symmetric-zoomout", "zoomout", "sinkhorn", "sinkhorn+zoomout", "none")
SINKHORN_ITERATIONS = 50  # at most: stops at SINKHORN_TOL (bench/results/softmaps_refinement.md)
SINKHORN_TOL = 1e-3  # L1 target-marginal violation (the plan's total mass is 1)


# Rows at a time in the mode search (a block's density: rows x n_target floats).
_MODE_ROWS = 64


def mode(rows: np.ndarray, target_areas: np.ndarray, prolongation=None) -> np.ndarray:
    """``(N,)`` argmax over ``y`` of the density ``rows[i, y] / a(y)``; with a
    ``prolongation`` (:class:`~solvers.softmaps.coarse_target.Prolongation`) ``rows`` are
    coarse masses and the density is that of the prolonged rows, formed a block of rows at
    a time.

    Parameters
    ----------
    rows : (N, n) array
        Target masses per source node (``(N, n_coarse)`` with a ``prolongation``).
    target_areas : (n,) array
        Target vertex areas :math:`a`.
    prolongation : Prolongation, optional
        With a coarse target (:class:`~solvers.softmaps.coarse_target.Prolongation`): ``rows``
        are coarse masses, prolonged to every target vertex a block of rows at a time.

    Returns
    -------
    (N,) int array
        Target vertex of largest density per row.
    """
    rows = np.asarray(rows)
    out = np.empty(len(rows), np.int64)
    for r0, block in _fine_blocks(rows, prolongation):
        density = block / np.asarray(target_areas, dtype=block.dtype)[None, :]
        out[r0:r0 + len(block)] = np.argmax(density, axis=1)
    return out


def _fine_blocks(rows, prolongation):
    """``(first row, rows on the target)`` in blocks of rows (prolonged when asked)."""
    if prolongation is not None:
        yield from prolongation.blocks(rows)
        return
    for r0 in range(0, len(rows), _MODE_ROWS):
        yield r0, rows[r0:r0 + _MODE_ROWS]


def barycentric_projection(rows: np.ndarray, target, radius: float | None = None
                           ) -> np.ndarray:
    r"""``(N,)`` nearest target vertex of each distribution's local barycenter.

    The barycenter :math:`\sum_y \mu_x(y)\, y` is taken over the target vertices within
    Euclidean distance ``radius`` of the mode (default ``5 * target.mean_edge_length``), so a
    distribution split between symmetric places is not averaged into the middle.

    Parameters
    ----------
    rows : (N, n) array
        Target masses per source node.
    target : TriangleMesh
        The target surface.
    radius : float, optional
        Euclidean radius around the mode (default ``5 * target.mean_edge_length``).

    Returns
    -------
    (N,) int array
        Target vertices.
    """
    rows = np.asarray(rows)
    radius = 5.0 * target.mean_edge_length if radius is None else check_positive(radius,
                                                                                 "radius")
    peaks = mode(rows, target.areas)
    tree = cKDTree(target.vertices)
    out = np.empty(len(rows), np.int64)
    for i, p in enumerate(peaks):
        near = np.asarray(tree.query_ball_point(target.vertices[p], radius), np.int64)
        m = rows[i, near].astype(np.float64)
        center = (m @ target.vertices[near]) / max(m.sum(), 1e-300)
        out[i] = tree.query(center)[1]
    return out


def trace_path(source_edges, n_nodes: int, rows: np.ndarray, target, seed: tuple[int, int],
               *, eps: float = 1e-3, steps: int = 1) -> np.ndarray:
    r"""eq. 4.7: propagate one seed match ``(node, target vertex)`` along the source graph.

    Breadth-first from the seed node; for each tree edge :math:`(u, u')` the matched point
    :math:`y_u` moves by ``steps`` Euler steps :math:`y \leftarrow y + \nabla Q(y)/steps`,
    :math:`Q` the transportation potential of :math:`\rho_u \to \rho_{u'}` (eq. 4.3), and is
    snapped to the nearest target vertex.  Returns ``(n_nodes,)`` target vertices.

    Parameters
    ----------
    source_edges : (m, 2) int array
        Source graph edges.
    n_nodes : int
        Source nodes ``N``.
    rows : (N, n) array
        Target masses per source node.
    target : TriangleMesh
        The target surface.
    seed : tuple of int
        ``(node, target vertex)``: the seed match.
    eps : float
        Regularization of the transportation potential (:func:`transportation_potential`).
    steps : int
        Euler steps per edge.

    Returns
    -------
    (N,) int array
        Target vertex of each source node.
    """
    from solvers.softmaps.energies import transportation_potential

    steps = check_int(steps, "steps", low=1)
    e = np.asarray(source_edges, np.int64)
    node, y0 = int(seed[0]), int(seed[1])
    if not (0 <= node < n_nodes and 0 <= y0 < target.n):
        raise InputError("seed must be (source node, target vertex) in range", field="seed")
    nbrs = [[] for _ in range(n_nodes)]
    for a, b in e:
        nbrs[a].append(b)
        nbrs[b].append(a)
    tree = cKDTree(target.vertices)
    out = -np.ones(n_nodes, np.int64)
    out[node] = y0
    queue = deque([node])
    grad_face = target.gradient
    while queue:
        u = queue.popleft()
        for v in nbrs[u]:
            if out[v] >= 0:
                continue
            q = transportation_potential(target, rows[u], rows[v], eps=eps)
            g = (grad_face @ q).reshape(-1, 3)  # per-face gradient of Q
            # Per-vertex gradient: area-weighted average of the incident faces.
            fa = np.repeat(target.face_areas, 3)
            gv = np.zeros((target.n, 3))
            np.add.at(gv, target.faces.ravel(), np.repeat(g, 3, axis=0) * fa[:, None])
            gv /= np.maximum(np.bincount(target.faces.ravel(), fa, target.n), 1e-300)[:, None]
            y = target.vertices[out[u]].copy()
            vert = out[u]
            for _ in range(steps):
                y = y + gv[vert] / steps
                vert = int(tree.query(y)[1])
            out[v] = vert
            queue.append(v)
    return out


def zoomout(source, target, correspondence=None, *, k_start: int = 20, k_end: int = 100,
            step: int = 1, soft=None, queries=None, symmetric: bool = False,
            target_queries=None) -> np.ndarray:
    r"""Refine a point map ``source vertex -> target vertex`` by spectral upsampling.

    At each size ``k`` in ``k_start, k_start + step, ..., k_end``:
    :math:`C_k = \Phi_{0,k}^\top A_0 \Phi_k[T]` and :math:`T(x) = \arg\min_y
    \|\Phi_{0,k}(x) - \Phi_k(y) C_k^\top\|` (the adjoint read-out of ZoomOut).
    ``soft=(rows, labels)`` starts instead from a soft map's own functional map, its
    pull-back :math:`C = \Phi_{0,k}^\top A_0 P \Phi_k` with :math:`P_{x,y} =`
    ``rows[labels[x], y]`` (``rows`` ``(N, n_target)`` masses, ``labels`` ``(n_source,)``),
    so the first read-out sees the whole distributions, not one extracted point per row;
    ``soft=(rows, labels, prolongation)``: ``rows`` ``(N, n_coarse)`` on a coarse target
    and :math:`P\Phi_k` is ``rows @ (prolongation^T Phi_k)`` (the prolonged rows are not
    formed).
    ``queries=(vertices, weights)``: the steps before the last read out only these source
    vertices, and :math:`C_k` is the quadrature :math:`\sum_x w_x \Phi_{0,k}(x)^\top
    \Phi_k(T(x))` over them (``weights`` their areas, e.g. farthest-point cells); the
    final :math:`C` reads out every source vertex.

    ``symmetric=True`` runs ZoomOut in both directions at once, tied by the adjoint
    relation of an area-preserving map, :math:`C_{M \to M_0} = C_k^\top` (A-orthonormal
    bases): each step reads out :math:`T` and the reverse map :math:`S` (at
    ``target_queries``, default every target vertex; started from :math:`C^\top`) and
    takes :math:`C_k = \tfrac12(\Phi_{0,k}^\top A_0 \Phi_k[T] + (\Phi_k^\top A
    \Phi_{0,k}[S])^\top)`.  Returns the ``(n_source,)`` refined map.

    Parameters
    ----------
    source, target : TriangleMesh
        The two surfaces.
    correspondence : (n_source,) int array, optional
        Initial point map (or give ``soft``).
    k_start, k_end, step : int
        Spectral sizes visited.
    soft : tuple, optional
        ``(rows, labels)`` or ``(rows, labels, prolongation)``: start from a soft map.
    queries : tuple, optional
        ``(vertices, weights)``: source vertices read out before the last step.
    symmetric : bool
        Tie in the reverse map.
    target_queries : tuple, optional
        ``(vertices, weights)`` of the reverse read-out (``symmetric=True``).

    Returns
    -------
    (n_source,) int array
        The refined map.
    """
    k_start = check_int(k_start, "k_start", low=2)
    k_end = check_int(k_end, "k_end", low=k_start)
    step = check_int(step, "step", low=1)
    _, phi0 = eigenpairs(source, k_end)
    _, phi1 = eigenpairs(target, k_end)
    at, w = _queries(source, queries)
    back, wb = _queries(target, target_queries)
    if soft is not None:
        rows, labels, prolongation = (*soft, None)[:3]
        basis = phi1[:, :k_start]
        if prolongation is not None:
            basis = prolongation.transpose_apply(basis)
        rows = np.asarray(rows)
        pulled = np.empty((len(rows), basis.shape[1]))
        for r0 in range(0, len(rows), _MODE_ROWS):  # float64 copies of a block of rows only
            pulled[r0:r0 + _MODE_ROWS] = rows[r0:r0 + _MODE_ROWS] @ basis
        pulled = pulled[np.asarray(labels)[at]]
        C = (phi0[at, :k_start] * w[:, None]).T @ pulled
        corr = None
    else:
        if correspondence is None:
            raise InputError("zoomout needs a correspondence or a soft map",
                             field="correspondence")
        corr = np.asarray(correspondence, np.int64)
        if corr.shape != (source.n,) or corr.min() < 0 or corr.max() >= target.n:
            raise InputError(f"correspondence must be {source.n} target vertices",
                             field="correspondence")
        corr = corr[at]
    reverse = None
    ks = list(range(k_start, k_end, step)) + [k_end]
    for i, k in enumerate(ks):
        if corr is not None:  # the soft map's C at k_start, else the current maps'
            C = (phi0[at, :k] * w[:, None]).T @ phi1[corr, :k]
            if reverse is not None:
                C = 0.5 * (C + ((phi1[back, :k] * wb[:, None]).T @ phi0[reverse, :k]).T)
        # Adjoint read-out (as ZoomOut): source rows against the target rows mapped by C^T.
        last = i == len(ks) - 1
        corr = nearest_rows(phi1[:, :k] @ C.T, phi0[:, :k] if last else phi0[at, :k])
        if symmetric and not last:
            reverse = nearest_rows(phi0[:, :k] @ C, phi1[back, :k])
    return corr


def _queries(mesh, queries):
    """``(vertices, weights)``: the given ones, or every vertex with its area."""
    if queries is None:
        return np.arange(mesh.n), mesh.areas
    return np.asarray(queries[0], np.int64), np.asarray(queries[1], np.float64)


def nearest_rows(points: np.ndarray, queries: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Index of the nearest row of ``points`` for every row of ``queries`` (brute force:
    float32 inner products by BLAS, then a compiled arg-min per query; chunks in threads)."""
    p32 = np.asarray(points, np.float32)
    sq = (p32**2).sum(1)
    pt = np.ascontiguousarray(p32.T)
    q32 = np.asarray(queries, np.float32)
    out = np.empty(len(queries), np.int64)
    run_blocks(lambda rows: _argmin_rows(q32[rows] @ pt, sq, out[rows]), len(q32), chunk)
    return out


@cached_njit(nogil=True)
def _argmin_rows(inner, sq, out):  # pragma: no cover - compiled
    # argmin_j |p_j|^2 - 2 <q_i, p_j> = argmin_j |q_i - p_j|^2, without a temporary.
    for i in range(inner.shape[0]):
        best = np.inf
        at = 0
        for j in range(inner.shape[1]):
            v = sq[j] - 2.0 * inner[i, j]
            if v < best:
                best = v
                at = j
        out[i] = at


@dataclass(kw_only=True)
class SinkhornProjection(SolverResult):
    r"""``rows`` ``(N, n)`` float64 projected masses (each row sums to 1); ``residual`` the
    L1 violation :math:`\|\pi^\top 1 - \bar a\|_1` of the target marginal after the last
    row scaling (the source marginal is then exact; :math:`\bar a` the target areas times
    the projected rows' share of the source area); ``initial_residual`` the same for the
    soft map before projection (:math:`\int |b - 1|` of eq. 4.5 when no row is fixed)."""

    rows: np.ndarray
    initial_residual: float = float("nan")


def sinkhorn_projection(rows, source_areas, target_areas, *, fixed=None,
                        max_iter: int = SINKHORN_ITERATIONS,
                        tol: float = SINKHORN_TOL) -> SinkhornProjection:
    r"""Project a soft map onto the doubly-stochastic set w.r.t. source and target areas.

    Objective: the Kullback-Leibler projection
    :math:`\min_{\pi \ge 0} \mathrm{KL}(\pi \,\|\, D_c P)` subject to :math:`\pi 1 = c` and
    :math:`\pi^\top 1 = a` (``P`` ``(N, n)`` row-stochastic target masses of the ``N``
    source nodes, ``c`` ``(N,)`` their cell areas, ``a`` ``(n,)`` target areas, both summing
    to 1), solved by Sinkhorn's alternating scalings :math:`v = a / (\pi_0^\top u)`,
    :math:`u = c / (\pi_0 v)`, :math:`\pi = D_u \pi_0 D_v`.  A projected map has bijectivity
    density :math:`b \equiv 1` (eq. 4.5, Proposition 11's bound attained).

    ``fixed``: indices of rows kept as they are (a soft map's landmark deltas: a delta row
    of cell area :math:`c_l > a(y_l)` makes the problem infeasible); the other rows are
    projected onto the target marginal :math:`a \sum_{u\ \mathrm{free}} c_u`.  Target
    vertices that no row reaches (all-zero columns) keep zero mass and stay in the residual.
    Stops at ``residual <= tol`` or after ``max_iter`` scalings; returns
    :class:`SinkhornProjection` with ``rows = \pi / c``.

    Parameters
    ----------
    rows : (N, n) array
        Row-stochastic target masses :math:`P`.
    source_areas : (N,) array
        Cell areas :math:`c`.
    target_areas : (n,) array
        Target areas :math:`a`.
    fixed : (f,) int array, optional
        Rows kept as they are.
    max_iter : int
        Sinkhorn scaling budget.
    tol : float
        Stop at ``residual <= tol``.

    Returns
    -------
    SinkhornProjection
        ``rows`` ``(N, n)`` :math:`\pi / c`, ``residual``, ``initial_residual``.
    """
    out = np.array(rows, dtype=np.float64)  # one working copy, scaled in place
    c = np.asarray(source_areas, np.float64)
    a = np.asarray(target_areas, np.float64)
    if out.ndim != 2 or out.shape != (len(c), len(a)):
        raise InputError(f"soft map rows must have shape ({len(c)}, {len(a)}), got "
                         f"{out.shape}", field="soft_map")
    if not np.all(np.isfinite(out)) or np.any(out < 0):
        raise InputError("soft map rows must be finite non-negative masses", field="soft_map")
    max_iter = check_int(max_iter, "max_iter", low=1)
    tol = check_positive(tol, "tol")
    free = np.ones(len(c), bool)
    if fixed is not None and len(fixed):
        free[check_indices(fixed, len(c), "fixed")] = False
    out /= np.maximum(out.sum(axis=1, keepdims=True), 1e-300)
    c, a = c / c.sum(), a / a.sum()
    plan = out[free] * c[free, None]  # rows sum to c exactly
    c, a = c[free], a * c[free].sum()
    initial = float(np.abs(plan.sum(axis=0) - a).sum())
    u, v = np.ones(len(c)), np.ones(len(a))
    residual, iterations = initial, 0
    while iterations < max_iter and residual > tol:
        iterations += 1
        col = plan.T @ u
        v = np.divide(a, col, out=np.zeros_like(a), where=col > 0)
        row = plan @ v
        u = np.divide(c, row, out=np.zeros_like(c), where=row > 0)
        residual = float(np.abs((plan.T @ u) * v - a).sum())
    plan *= v[None, :]
    plan /= np.maximum(plan.sum(axis=1, keepdims=True), 1e-300)  # = pi / c, u cancels
    out[free] = plan
    return SinkhornProjection(rows=out, iterations=iterations, residual=residual,
                              converged=residual <= tol, initial_residual=initial)


@dataclass(kw_only=True)
class Correspondence:
    """``sample_correspondence`` ``(N,)`` target vertex per source node after extraction
    (on the Sinkhorn-projected rows when asked); ``correspondence`` ``(n_source,)`` per
    source vertex, after ZoomOut when asked; ``sinkhorn`` the projection (or ``None``)."""

    sample_correspondence: np.ndarray
    correspondence: np.ndarray
    sinkhorn: SinkhornProjection | None = None


def extract_correspondence(source, target, rows, *, labels, samples, cell_areas, edges,
                           fixed=None, seed_target: int | None = None, extraction: str = "mode",
                           refine: str = "zoomout",
                           zoomout_range: tuple[int, int, int] = (20, 50, 1),
                           sinkhorn_iterations: int = SINKHORN_ITERATIONS,
                           zoomout_queries=None, prolongation=None) -> Correspondence:
    r"""Point map ``source vertex -> target vertex`` from soft-map rows (§4.5.1 + refinement).

    ``rows`` ``(N, n)`` masses of the ``N`` source nodes ``samples`` (source vertex ids),
    ``labels`` ``(n_source,)`` node of every source vertex, ``cell_areas`` ``(N,)``,
    ``edges`` the source graph (for ``extraction="path"``, seeded at node 0 matched to
    ``seed_target``).  ``refine``: ``"sinkhorn"`` projects the rows first
    (:func:`sinkhorn_projection`, ``sinkhorn_iterations`` scalings, the rows ``fixed`` --
    landmark deltas -- left out), ``"zoomout"`` refines
    with :func:`zoomout` over ``zoomout_range``, started from the rows' own functional map
    (the extraction is then only the unrefined ``sample_correspondence``),
    ``"symmetric-zoomout"`` the same with the reverse map tied in (:func:`zoomout`,
    ``symmetric=True``), ``"sinkhorn+zoomout"`` both, ``"none"`` neither;
    ``zoomout_queries``: ``(source, target)`` vertices and weights of ZoomOut's
    intermediate steps (``queries``/``target_queries`` of :func:`zoomout`).  Each node's
    match is spread to the vertices of its cell.  ``prolongation``: ``rows`` are ``(N,
    n_coarse)`` masses on a coarse target, prolonged by it (mode and ZoomOut read them a
    block at a time or through :math:`P^\top`; the other options prolong them whole).

    Parameters
    ----------
    source, target : TriangleMesh
        The two surfaces.
    rows : (N, n) array
        Target masses of the ``N`` source nodes (``(N, n_coarse)`` with a ``prolongation``).
    labels : (n_source,) int array
        Node of every source vertex.
    samples : (N,) int array
        Source vertex of every node.
    cell_areas : (N,) array
        Source area of each node's cell.
    edges : (m, 2) int array
        Source graph (for ``extraction="path"``).
    fixed : (f,) int array, optional
        Rows left out of the Sinkhorn projection (landmark deltas).
    seed_target : int, optional
        Target vertex matched to node 0 (``extraction="path"``).
    extraction : {"mode", "barycentric", "path"}
        How each row is read out (§4.5.1).
    refine : {"zoomout", "symmetric-zoomout", "sinkhorn", "sinkhorn+zoomout", "none"}
        Refinement (see above).
    zoomout_range : tuple of int
        ``(k_start, k_end, step)`` of :func:`zoomout`.
    sinkhorn_iterations : int
        Scalings of :func:`sinkhorn_projection`.
    zoomout_queries : tuple, optional
        ``(source, target)`` vertices and weights of ZoomOut's intermediate steps.
    prolongation : Prolongation, optional
        With a coarse target (:class:`~solvers.softmaps.coarse_target.Prolongation`): ``rows``
        are coarse masses, prolonged to every target vertex a block of rows at a time.

    Returns
    -------
    Correspondence
        ``sample_correspondence`` ``(N,)``, ``correspondence`` ``(n_source,)`` and the
        ``sinkhorn`` projection (or ``None``).
    """
    check_choice(extraction, EXTRACTIONS, "extraction")
    check_choice(refine, REFINEMENTS, "refine")
    labels = np.asarray(labels, np.int64)
    samples = np.asarray(samples, np.int64)
    projection = None
    if prolongation is not None and (refine.startswith("sinkhorn") or extraction != "mode"):
        rows, prolongation = prolongation.apply(rows), None
    if refine.startswith("sinkhorn"):
        projection = sinkhorn_projection(rows, cell_areas, target.areas, fixed=fixed,
                                         max_iter=sinkhorn_iterations)
        rows = projection.rows
    if extraction == "mode":
        sample_corr = mode(rows, target.areas, prolongation)
    elif extraction == "barycentric":
        sample_corr = barycentric_projection(rows, target)
    else:
        if seed_target is None:
            raise InputError("path tracing needs the seed's target vertex", field="seed")
        sample_corr = trace_path(edges, len(samples), rows, target, (0, int(seed_target)))
    corr = sample_corr[labels]
    corr[samples] = sample_corr
    if refine.endswith("zoomout"):
        ks, ke, st = zoomout_range
        src_q, tgt_q = zoomout_queries or (None, None)
        corr = zoomout(source, target, k_start=ks, k_end=ke, step=st,
                       soft=(rows, labels, prolongation), queries=src_q,
                       symmetric=refine == "symmetric-zoomout", target_queries=tgt_q)
    return Correspondence(sample_correspondence=np.asarray(sample_corr, np.int64),
                          correspondence=corr, sinkhorn=projection)
