r"""Curves on a mesh as feature sets for :func:`solvers.emd.distance_to_features` (Fig. 2.14).

A curve is given by waypoints (vertices); consecutive waypoints are joined by the shortest
path along mesh edges (Dijkstra on edge lengths), and the curve's feature set is every
vertex on those paths.  The distance to the curve is then the distance to that vertex set,
whose spacing is one edge, i.e. within half an edge length of the distance to the polyline.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from solvers.errors import InputError
from solvers.validation import check_indices


def _edge_graph(mesh) -> sp.csr_matrix:
    e = mesh.edges
    length = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)
    g = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(mesh.n, mesh.n))
    return (g + g.T).tocsr()


def curve_vertices(mesh, waypoints, *, closed: bool = False, field: str = "curve",
                   graph: sp.csr_matrix | None = None) -> np.ndarray:
    """Vertices of the edge path through ``waypoints`` in order (back to the first if
    ``closed``), waypoints included, consecutive duplicates removed.

    ``graph``: the mesh's edge-length graph, when several curves are traced."""
    points = check_indices(waypoints, mesh.n, field=field)
    if len(points) < 2:
        raise InputError(f"{field} needs at least two waypoints", field=field)
    if closed:
        points = np.append(points, points[0])
    graph = _edge_graph(mesh) if graph is None else graph
    _, pred = dijkstra(graph, directed=False, indices=points[:-1], return_predecessors=True)
    path = [int(points[0])]
    for k in range(len(points) - 1):
        a, b = int(points[k]), int(points[k + 1])
        segment = []
        node = b
        while node != a:
            if node < 0:
                raise InputError(f"{field}: waypoints {a} and {b} are on different connected "
                                 "components", field=field)
            segment.append(node)
            node = int(pred[k, node])
        path.extend(reversed(segment))
    return np.asarray(path, dtype=np.int64)


def feature_set(mesh, vertices=(), curves=()) -> np.ndarray:
    """Sorted unique feature vertices: ``vertices`` plus every curve's path.

    ``curves``: sequence of ``(waypoints, closed)``."""
    parts = []
    if len(vertices):
        parts.append(check_indices(vertices, mesh.n, field="vertices"))
    graph = _edge_graph(mesh) if len(curves) else None
    for i, (waypoints, closed) in enumerate(curves):
        parts.append(curve_vertices(mesh, waypoints, closed=closed, field=f"curves[{i}]",
                                    graph=graph))
    if not parts:
        raise InputError("give feature vertices or curves", field="vertices")
    return np.unique(np.concatenate(parts))
