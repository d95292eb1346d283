r"""Per-vertex histograms of geometric quantities over geodesic neighbourhoods (§5.6, Fig. 5.6).

The thesis evaluates propagation on meshes whose vertices carry the distribution of a
local quantity: here the signed mean curvature (Prob(ℝ)) or the angle of the principal
curvature direction in a tangent frame (S¹, period π) (both of :mod:`solvers.curvature`),
histogrammed over the vertices within a geodesic radius (shortest paths along mesh edges,
a standard approximation).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from solvers.histograms.bins import Bins, histogram_of_samples
from solvers.validation import check_positive


def neighbourhood_histograms(mesh, values, bins: Bins, radius: float) -> np.ndarray:
    """``(V, B)`` histogram of ``values`` over each vertex's ball of geodesic ``radius``
    (shortest paths along edges, Euclidean edge lengths; values clipped into the bins)."""
    radius = check_positive(radius, "radius")
    x = np.asarray(values, dtype=np.float64)
    if not bins.periodic:
        x = np.clip(x, bins.lo, bins.hi)
    tri = sp.triu(mesh.cotan_laplacian, 1).tocoo()
    v = mesh.vertices
    length = np.linalg.norm(v[tri.row] - v[tri.col], axis=1)
    graph = sp.coo_matrix((length, (tri.row, tri.col)), shape=(mesh.n, mesh.n)).tocsr()
    out = np.zeros((mesh.n, bins.count))
    for start in range(0, mesh.n, 512):
        idx = np.arange(start, min(mesh.n, start + 512))
        dist = dijkstra(graph, directed=False, indices=idx, limit=radius)
        for row, i in enumerate(idx):
            out[i] = histogram_of_samples(x[np.isfinite(dist[row])], bins)
    return out
