r"""Farthest-point samples of a source mesh and their adjacency graph (§3.7 soft maps).

The source of a soft map is seen as a graph: all vertices with the mesh edges, or ``N``
farthest-point samples (greedy, graph-geodesic distances along mesh edges, seeded with the
landmarks) whose geodesic Voronoi cells touch.  Edge weights are :math:`1/\ell^2`
(:math:`\ell` the Euclidean distance between the two samples at unit area), divided by
their mean so that weights do not grow with the number of samples; with them
:math:`\sum_e \omega_e W_2^2(\mu_u, \mu_{u'})` discretizes the Dirichlet energy
:math:`\int \|\nabla \mu\|^2` (eq. 4.1) up to a constant factor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from solvers.errors import InputError
from solvers.softmaps.descriptors import check_landmarks
from solvers.validation import check_int


@dataclass
class SourceSamples:
    r"""Farthest-point samples of a source mesh and their Voronoi adjacency.

    Attributes
    ----------
    indices : (N,) int array
        Sample vertices (seeds first).
    labels : (n,) int array
        The sample whose cell holds each vertex.
    edges : (m, 2) int array
        Adjacent sample pairs.
    weights : (m,) array
        Edge weights :math:`1/\ell^2`, of mean 1.
    lengths : (m,) array
        Edge lengths :math:`\ell`.
    radius : float
        The largest graph distance from a vertex to its sample.
    """

    indices: np.ndarray
    labels: np.ndarray
    edges: np.ndarray
    weights: np.ndarray
    lengths: np.ndarray
    radius: float

    @property
    def n(self) -> int:
        return len(self.indices)

    @property
    def nbytes(self) -> int:
        return int(sum(x.nbytes for x in (self.indices, self.labels, self.edges, self.weights,
                                           self.lengths)))


def _edge_graph(mesh) -> sp.csr_matrix:
    e = mesh.edges
    ln = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)
    g = sp.coo_matrix((ln, (e[:, 0], e[:, 1])), shape=(mesh.n, mesh.n))
    return (g + g.T).tocsr()


def _graph(mesh, indices, labels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    e = mesh.edges
    pairs = labels[e]
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    p = mesh.vertices[indices]
    lengths = np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1)
    w = 1.0 / np.maximum(lengths, 1e-12) ** 2
    return pairs.astype(np.int64), w / w.mean(), lengths


def farthest_point_samples(mesh, count: int, seeds=None) -> SourceSamples:
    """``count`` farthest-point samples (seeds first) and their Voronoi adjacency.

    ``count >= mesh.n`` returns every vertex with the mesh's own edges.  Cached in
    ``mesh.operators`` per ``(count, seeds)``.

    Parameters
    ----------
    mesh : TriangleMesh
        The source surface.
    count : int
        Number of samples ``N``.
    seeds : (s,) int array, optional
        Vertices sampled first (e.g. landmarks).

    Returns
    -------
    SourceSamples
    """
    count = check_int(count, "samples", low=2)
    seeds = check_landmarks([] if seeds is None else seeds, mesh.n, "landmarks")
    if len(seeds) > count:
        raise InputError(f"samples ({count}) must be at least the number of landmarks "
                         f"({len(seeds)})", field="samples")
    if mesh.n_components > 1:
        raise InputError(f"the source mesh has {mesh.n_components} connected components; "
                         "soft maps need one", field="source")
    key = ("softmaps.samples", min(count, mesh.n), tuple(int(s) for s in seeds))
    return mesh.operators.get(key, lambda: _build(mesh, count, seeds))


def _build(mesh, count, seeds) -> SourceSamples:
    if count >= mesh.n:
        # Every vertex, seeds first (so landmark j is sample j).
        rest = np.setdiff1d(np.arange(mesh.n), seeds)
        indices = np.concatenate([seeds, rest]).astype(np.int64)
        labels = np.empty(mesh.n, np.int64)
        labels[indices] = np.arange(mesh.n)
        edges, w, ln = _graph(mesh, indices, labels)
        return SourceSamples(indices, labels, edges, w, ln, 0.0)
    graph = _edge_graph(mesh)
    mind = np.full(mesh.n, np.inf)
    labels = np.zeros(mesh.n, np.int64)
    indices = []
    start = list(seeds) if len(seeds) else [int(np.argmax(np.linalg.norm(
        mesh.vertices - mesh.vertices.mean(0), axis=1)))]
    for j in range(count):
        v = int(start[j]) if j < len(start) else int(np.argmax(mind))
        limit = np.inf if not np.isfinite(mind).all() else float(mind.max())
        d = dijkstra(graph, indices=v, limit=limit)
        closer = d < mind
        mind[closer] = d[closer]
        labels[closer] = j
        indices.append(v)
    indices = np.asarray(indices, np.int64)
    edges, w, ln = _graph(mesh, indices, labels)
    return SourceSamples(indices, labels, edges, w, ln, float(mind.max()))
