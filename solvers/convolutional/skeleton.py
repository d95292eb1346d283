r"""Skeleton layout by Wasserstein propagation (thesis §3.7, Fig. 3.13).

Input: a closed triangle mesh, a skeleton graph ``(nodes, edges)`` and the positions
:math:`x_u` of a few fixed nodes :math:`u \in V_0` inside the volume.

1. Each fixed position becomes a distribution on the surface through its mean value
   coordinates (§2.6, :func:`solvers.emd.volumetric.mean_value_coordinates`):
   :math:`\sum_v w_v(x) = 1,\ \sum_v w_v(x) p_v = x`.  MVC weights can be *negative*
   in concave regions (a point sees some surface through other surface); a distribution
   cannot, so the negative weights are **clipped to 0 and the rest renormalized**.  The
   clipped fraction :math:`\sum_v \max(-w_v,0) / \sum_v \max(w_v,0)` is reported per fixed
   node (``clipped``), and so is how far the clipped coordinates' barycenter
   :math:`\sum_v \tilde w_v p_v` moved from :math:`x_u` (``fixed_error``).
2. Wasserstein propagation (Alg. 4, eq. 3.17, uniform edge weights,
   :func:`solvers.convolutional.wasserstein_propagation`) gives distributions
   :math:`\mu_u` at the free nodes.
3. Each free node is placed at the barycenter of its distribution's support points,
   the distribution used as barycentric coordinates: :math:`x_u = \sum_v \mu_u(v) p_v`.
   Fixed nodes keep their given positions.

For comparison, :func:`linear_layout` interpolates the positions linearly along the graph
(the harmonic extension with uniform edge weights: every free node at the mean of its
neighbours; on a chain, evenly spaced on the straight segment between its fixed ends).

Units: positions are in the mesh's normalized frame (``mesh.vertices``, unit area), or in
the loaded file's coordinates with ``units="input"`` (results then in input units too).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.convolutional.propagation import wasserstein_propagation
from solvers.emd.volumetric import mean_value_coordinates, winding_number
from solvers.errors import InputError
from solvers.monitor import SolverResult
from solvers.validation import check_anchored, check_choice, check_edges, check_int

INSIDE = 0.5  # winding number above which a point counts as inside
# Default gamma = (DEFAULT_GAMMA_EDGES * mean edge length)^2 (measured on spot's legs and a
# capsule: bench/results/applications.md).
DEFAULT_GAMMA_EDGES = 4.0


@dataclass
class SkeletonLayoutResult(SolverResult):
    """Skeleton layout.

    ``positions`` ``(N, 3)``: fixed nodes as given, free nodes at their distributions'
    barycenters; ``linear`` ``(N, 3)``: linear interpolation along the graph;
    ``masses`` ``(n, N)``: the node distributions on the surface; ``winding`` /
    ``linear_winding`` ``(N,)``: winding numbers of the nodes (about 1 inside);
    ``clipped`` ``(N,)``: fraction of negative MVC weight clipped at each fixed node
    (0 at free nodes); ``fixed_error`` ``(N,)``: distance between a fixed position and
    the barycenter of its clipped coordinates (0 at free nodes); ``free_nodes``;
    ``iterations``/``residual``/``converged`` of the propagation.

    Attributes
    ----------
    positions : (N, 3) array
        Fixed nodes as given, free nodes at their distributions' barycenters.
    linear : (N, 3) array
        Linear interpolation along the graph.
    masses : (n, N) array
        The node distributions on the surface.
    winding, linear_winding : (N,) array
        Winding numbers of the nodes (about 1 inside).
    clipped : (N,) array
        Fraction of negative MVC weight clipped at each fixed node.
    fixed_error : (N,) array
        Distance between a fixed position and the barycenter of its clipped coordinates.
    free_nodes : array of int
        The nodes solved for.
    gamma : float
        Regularization used.
    iterations, residual, converged : int, float, bool
        Convergence data of the propagation.
    """

    positions: np.ndarray
    linear: np.ndarray
    masses: np.ndarray
    winding: np.ndarray
    linear_winding: np.ndarray
    clipped: np.ndarray
    fixed_error: np.ndarray
    free_nodes: np.ndarray
    gamma: float


def check_skeleton(n_nodes, edges, fixed) -> tuple[int, np.ndarray, list[int], np.ndarray]:
    """Validated ``(n_nodes, edges (m, 2), fixed node list, positions (F, 3))``.

    Parameters
    ----------
    n_nodes : int
        Skeleton nodes ``N``.
    edges : (m, 2) int array
        Node pairs.
    fixed : dict
        ``{node: (3,) position}``.

    Returns
    -------
    n_nodes : int
    edges : (m, 2) int array
    fixed_nodes : list of int
    positions : (F, 3) array
    """
    n_nodes = check_int(n_nodes, "n_nodes", low=2)
    e = check_edges(edges, n_nodes, "edges")
    if len(e) == 0:
        raise InputError("edges must have shape (m, 2) with m > 0", field="edges")
    if not isinstance(fixed, dict) or not fixed:
        raise InputError("fixed must map at least one node to its position", field="fixed")
    nodes, pos = [], []
    for key, x in fixed.items():
        try:
            u = int(key)
        except (TypeError, ValueError) as exc:
            raise InputError(f"fixed node {key!r} is not an integer", field="fixed") from exc
        if not 0 <= u < n_nodes or u in nodes:
            raise InputError(f"fixed node {u} out of range [0, {n_nodes - 1}] or repeated",
                             field="fixed")
        p = np.asarray(x, dtype=np.float64) if np.ndim(x) == 1 else None
        if p is None or p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InputError(f"fixed[{u}] must be a finite 3-D position", field=f"fixed[{u}]")
        nodes.append(u)
        pos.append(p)
    check_anchored(n_nodes, e, nodes, "edges")
    return n_nodes, e, nodes, np.array(pos)


def linear_layout(n_nodes: int, edges, fixed: dict) -> np.ndarray:
    """Positions ``(N, 3)`` interpolated linearly along the graph (harmonic, uniform
    weights): free node = mean of its neighbours, fixed nodes as given.

    Parameters
    ----------
    n_nodes, edges, fixed : int, (m, 2) int array, dict
        As in :func:`check_skeleton`.

    Returns
    -------
    (N, 3) array
    """
    n_nodes, e, nodes, pos = check_skeleton(n_nodes, edges, fixed)
    A = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                      shape=(n_nodes, n_nodes)).tocsr()
    L = (sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A).tocsr()
    X = np.zeros((n_nodes, 3))
    X[nodes] = pos
    free = np.setdiff1d(np.arange(n_nodes), nodes)
    if len(free):
        Lff = L[free][:, free].tocsc()
        rhs = -(L[free][:, nodes] @ pos)
        X[free] = np.column_stack([spla.spsolve(Lff, rhs[:, c]) for c in range(3)])
    return X


def position_distributions(mesh, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(masses (n, P), clipped (P,), error (P,))``: clipped, renormalized MVC of points
    ``(P, 3)`` (mesh frame) as surface distributions; see the module docstring.

    Parameters
    ----------
    mesh : TriangleMesh
        A closed surface (``n`` vertices).
    points : (P, 3) array
        Positions in the mesh frame.

    Returns
    -------
    masses : (n, P) array
    clipped : (P,) array
    error : (P,) array
    """
    W = mean_value_coordinates(mesh, points)
    pos = np.maximum(W, 0.0)
    neg = np.maximum(-W, 0.0).sum(axis=1)
    total = pos.sum(axis=1)
    if np.any(total <= 0):
        raise InputError("a fixed position has no positive mean value coordinate",
                         field="fixed")
    M = (pos / total[:, None]).T
    err = np.linalg.norm(M.T @ mesh.vertices - np.asarray(points), axis=1)
    return M, neg / total, err


def skeleton_layout(
    mesh,
    n_nodes: int,
    edges,
    fixed: dict,
    *,
    gamma: float | None = None,
    substeps: int = 1,
    units: str = "mesh",
    tol: float = 1e-5,
    max_iter: int | None = None,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> SkeletonLayoutResult:
    r"""Embed a skeleton graph in a closed mesh (module docstring; Alg. 4 + MVC, §3.7).

    Parameters
    ----------
    mesh : closed :class:`~solvers.TriangleMesh`.
    n_nodes : number of skeleton nodes.
    edges : ``(m, 2)`` node pairs.
    fixed : ``{node: (3,) position}`` inside the volume (at least one per graph piece).
    gamma : regularization of the propagation (unit-area units; default
        :math:`(4h)^2`, ``h`` the mean edge length: at :math:`(2h)^2` the free nodes'
        distributions stay too concentrated to span a limb and layouts leave thin
        volumes; bench/results/applications.md).
    substeps : heat-kernel substeps.
    units : ``"mesh"`` (normalized frame) or ``"input"`` (file coordinates).
    tol, max_iter, progress, should_cancel : of the propagation.

    Returns
    -------
    SkeletonLayoutResult
    """
    check_choice(units, ("mesh", "input"), "units")
    n_nodes, e, nodes, pos = check_skeleton(n_nodes, edges, fixed)
    scale = mesh.length_scale if units == "input" else 1.0
    pos = pos / scale
    wind = winding_number(mesh, pos)
    outside = [u for u, w in zip(nodes, wind, strict=True) if w < INSIDE]
    if outside:
        raise InputError(f"fixed nodes {outside} lie outside the surface (winding number "
                         f"< {INSIDE})", field="fixed")
    M, clipped, err = position_distributions(mesh, pos)
    if gamma is None:
        gamma = (DEFAULT_GAMMA_EDGES * mesh.mean_edge_length) ** 2
    result = wasserstein_propagation(
        mesh, n_nodes, e, {u: M[:, j] for j, u in enumerate(nodes)}, gamma=gamma,
        substeps=substeps, tol=tol, max_iter=max_iter, progress=progress,
        should_cancel=should_cancel, method="convolutional")
    X = result.masses.T @ mesh.vertices
    X[nodes] = pos
    lin = linear_layout(n_nodes, e, {u: p for u, p in zip(nodes, pos, strict=True)})
    clip = np.zeros(n_nodes)
    clip[nodes] = clipped
    ferr = np.zeros(n_nodes)
    ferr[nodes] = err
    return SkeletonLayoutResult(
        positions=X * scale, linear=lin * scale, masses=result.masses,
        winding=winding_number(mesh, X), linear_winding=winding_number(mesh, lin),
        clipped=clip, fixed_error=ferr * scale, free_nodes=result.free_nodes,
        gamma=float(result.gamma), iterations=result.iterations, residual=result.residual,
        converged=result.converged)


def segment_inside_fraction(mesh, points, edges, samples: int = 16) -> float:
    """Fraction of points sampled along the segments ``points[edges]`` (mesh frame) whose
    winding number exceeds :data:`INSIDE` (1.0: every drawn bone stays in the volume).

    Parameters
    ----------
    mesh : TriangleMesh
        A closed surface.
    points : (N, 3) array
        Node positions (mesh frame).
    edges : (m, 2) int array
        Segments.
    samples : int
        Points sampled per segment.

    Returns
    -------
    float
    """
    P = np.asarray(points, dtype=np.float64)
    e = np.asarray(edges, dtype=np.int64)
    s = (np.arange(samples) + 0.5) / samples
    pts = (P[e[:, 0]][:, None] * (1 - s)[None, :, None]
           + P[e[:, 1]][:, None] * s[None, :, None]).reshape(-1, 3)
    return float(np.mean(winding_number(mesh, pts) > INSIDE))
