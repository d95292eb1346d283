r"""Geodesic-like distance to features from the W1 dual potential (thesis §2.7).

The Kantorovich potential ``u`` of W1 between the uniform distribution and a
distribution ``ν`` supported on a feature set ``S`` (points, a curve) is
1-Lipschitz with ``|∇u| = 1`` along every transport ray, and every point of the
surface sends mass, so ``u(p) - u(x)`` equals the length of the ray from ``x``
to its target ``p ∈ S``.  For a single feature point this is exactly the
geodesic distance.  For larger sets the masses on ``S`` decide which part of
``S`` each point is sent to; by default every feature vertex receives the area of
its Voronoi cell (nearest feature along mesh edges, Dijkstra), so the optimal
plan sends every point to (approximately) its nearest feature and
``d(x) = u(p(x)) - u(x)`` with ``p(x)`` the feature of ``x``'s cell is the distance
to the set.  Explicit ``feature_weights`` give ``d = max_S u - u`` instead.
The W1 solve (:func:`solvers.emd.earth_movers_distance`) also accepts
anisotropic ``face_weights`` (per-face ``A(x)`` in ``∫‖A J‖``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.emd.beckmann import EMDResult, earth_movers_distance
from solvers.errors import InputError


@dataclass
class FeatureDistanceResult:
    """``distances`` (V,) to the feature set; ``emd`` is the underlying W1 solve.

    Attributes
    ----------
    distances : (V,) array
        Distance of every vertex to the feature set.
    potential : (V,) array
        The W1 solve's Kantorovich potential.
    feature_vertices : array of int
        The vertices of the feature set.
    emd : EMDResult
        The underlying W1 solve.
    """

    distances: np.ndarray
    potential: np.ndarray
    feature_vertices: np.ndarray
    emd: EMDResult

    @property
    def iterations(self) -> int:
        return self.emd.iterations

    @property
    def residual(self) -> float:
        return self.emd.residual

    @property
    def converged(self) -> bool:
        return self.emd.converged


def _voronoi_cells(mesh, feats: np.ndarray) -> np.ndarray:
    """Nearest feature vertex of every vertex along mesh edges (-1 if unreachable)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    e = mesh.edges
    length = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)
    graph = sp.csr_matrix((length, (e[:, 0], e[:, 1])), shape=(mesh.n, mesh.n))
    _, _, sources = dijkstra(graph, directed=False, indices=feats, min_only=True,
                             return_predecessors=True)
    return np.asarray(sources, dtype=np.int64)


def distance_to_features(mesh, feature_vertices, *, feature_weights=None, face_weights=None,
                         basis: str = "full", method: str = "admm", tol: float = 1e-4,
                         max_iter: int | None = None, progress=None,
                         should_cancel=None) -> FeatureDistanceResult:
    r"""Distance from every vertex to a feature set via W1(uniform, feature) (§2.7).

    With :math:`u` the Kantorovich potential of :math:`W_1(\text{uniform}, \nu_S)`,
    :math:`d(x) = u(p(x)) - u(x)`, :math:`p(x)` the feature of ``x``'s Voronoi cell
    (with explicit ``feature_weights``: :math:`d = \max_S u - u`; module docstring).

    Parameters
    ----------
    mesh : TriangleMesh.
    feature_vertices : (s,) vertex indices of the feature (points or a sampled curve).
    feature_weights : optional (s,) non-negative masses on the features (default:
        the area of each feature vertex's Voronoi cell).
    face_weights : optional (F,) or (F, 3, 3) anisotropic cost, see
        :func:`~solvers.emd.earth_movers_distance`.
    basis, method, tol, max_iter, progress, should_cancel : as for the W1 solve.

    Returns
    -------
    FeatureDistanceResult(distances (V,), potential (V,), feature_vertices, emd).
    """
    n = mesh.n
    feats = np.unique(np.asarray(feature_vertices).ravel())
    if feats.size == 0 or not np.issubdtype(feats.dtype, np.integer) or feats.min() < 0 \
            or feats.max() >= n:
        raise InputError(f"feature_vertices must be non-empty vertex indices in [0, {n - 1}]",
                         field="feature_vertices")
    nu = np.zeros(n)
    cell = None
    if feature_weights is None:
        cell = _voronoi_cells(mesh, feats)
        reached = cell >= 0
        np.add.at(nu, cell[reached], mesh.areas[reached])
    else:
        w = np.asarray(feature_weights, dtype=np.float64)
        order = np.asarray(feature_vertices).ravel()
        if w.shape != order.shape or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InputError("feature_weights must be finite, non-negative, one per feature "
                             "vertex", field="feature_weights")
        np.add.at(nu, order, w)
    uniform = np.asarray(mesh.areas, dtype=np.float64)
    if mesh.n_components > 1:  # each component must receive its own mass
        labels = mesh.component_labels
        comp_nu = mesh.component_masses(nu / nu.sum())
        uniform = uniform * (comp_nu / np.maximum(mesh.component_masses(uniform), 1e-300))[labels]
    result = earth_movers_distance(mesh, uniform, nu, method=method, basis=basis,
                                   face_weights=face_weights, tol=tol, max_iter=max_iter,
                                   progress=progress, should_cancel=should_cancel)
    u = result.potential
    if cell is not None:
        distances = np.full(n, np.nan)
        reached = cell >= 0
        distances[reached] = u[cell[reached]] - u[reached]
    elif mesh.n_components > 1:
        labels = mesh.component_labels
        top = np.full(mesh.n_components, -np.inf)
        np.maximum.at(top, labels[feats], u[feats])
        distances = top[labels] - u
        distances[~np.isfinite(distances)] = np.nan
    else:
        distances = u[feats].max() - u
    return FeatureDistanceResult(distances=distances, potential=u, feature_vertices=feats,
                                 emd=result)
