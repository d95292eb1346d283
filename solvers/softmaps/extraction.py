r"""Point-to-point correspondences from a soft map (thesis §4.5.1) and a spectral refinement.

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
  among the rows of :math:`\Phi C^\top`.  Used as the optional refinement after extraction.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy.spatial import cKDTree

from solvers.errors import InputError
from solvers.softmaps.descriptors import eigenpairs
from solvers.validation import check_int, check_positive

EXTRACTIONS = ("mode", "barycentric", "path")
REFINEMENTS = ("zoomout", "none")


def mode(rows: np.ndarray, target_areas: np.ndarray) -> np.ndarray:
    """``(N,)`` argmax over ``y`` of the density ``rows[i, y] / a(y)``."""
    rows = np.asarray(rows)
    return np.argmax(rows / np.asarray(target_areas, dtype=rows.dtype)[None, :], axis=1)


def barycentric_projection(rows: np.ndarray, target, radius: float | None = None
                           ) -> np.ndarray:
    r"""``(N,)`` nearest target vertex of each distribution's local barycenter.

    The barycenter :math:`\sum_y \mu_x(y)\, y` is taken over the target vertices within
    Euclidean distance ``radius`` of the mode (default ``5 * target.mean_edge_length``), so a
    distribution split between symmetric places is not averaged into the middle.
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


def zoomout(source, target, correspondence, *, k_start: int = 20, k_end: int = 100,
            step: int = 1) -> np.ndarray:
    r"""Refine a point map ``source vertex -> target vertex`` by spectral upsampling.

    At each size ``k`` in ``k_start, k_start + step, ..., k_end``:
    :math:`C_k = \Phi_{0,k}^\top A_0 \Phi_k[T]` and :math:`T(x) = \arg\min_y
    \|\Phi_{0,k}(x) - \Phi_k(y) C_k^\top\|` (the adjoint read-out of ZoomOut).
    Returns the ``(n_source,)`` refined map.
    """
    k_start = check_int(k_start, "k_start", low=2)
    k_end = check_int(k_end, "k_end", low=k_start)
    step = check_int(step, "step", low=1)
    corr = np.asarray(correspondence, np.int64)
    if corr.shape != (source.n,) or corr.min() < 0 or corr.max() >= target.n:
        raise InputError(f"correspondence must be {source.n} target vertices",
                         field="correspondence")
    _, phi0 = eigenpairs(source, k_end)
    _, phi1 = eigenpairs(target, k_end)
    a0 = source.areas
    for k in list(range(k_start, k_end, step)) + [k_end]:
        C = (phi0[:, :k] * a0[:, None]).T @ phi1[corr, :k]
        # Adjoint read-out (as ZoomOut): source rows against the target rows mapped by C^T.
        corr = nearest_rows(phi1[:, :k] @ C.T, phi0[:, :k])
    return corr


def nearest_rows(points: np.ndarray, queries: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Index of the nearest row of ``points`` for every row of ``queries`` (brute force)."""
    p32 = np.asarray(points, np.float32)
    sq = (p32**2).sum(1)
    out = np.empty(len(queries), np.int64)
    for s in range(0, len(queries), chunk):
        q = np.asarray(queries[s:s + chunk], np.float32)
        out[s:s + chunk] = np.argmin(sq[None, :] - 2.0 * q @ p32.T, axis=1)
    return out
