r"""Graph weights for propagation: the Laplacian :math:`L = D - W` the Dirichlet energy uses.

:math:`\sum_{(u,v) \in E} w_{uv} \|f_u - f_v\|^2 = f^\top L f`.  Sources:

* a :class:`~solvers.domains.Graph` (its edge weights),
* a :class:`~solvers.domains.TriangleMesh`: ``laplacian="robust"`` (intrinsic-Delaunay,
  non-negative weights, maximum principle; default) or ``"cotan"`` (the cotangent
  Laplacian; weights can be negative on obtuse meshes),
* a :class:`~solvers.domains.PointCloud`: its point-cloud Laplacian (the thesis' [CL06]
  choice; here Sharp & Crane's robust point-cloud Laplacian),
* a :class:`~solvers.domains.Grid`: its finite-difference Laplacian,
* a sparse symmetric ``(n, n)`` weight matrix :math:`W` (non-negative),
* :func:`knn_graph`: a k-nearest-neighbour graph of coordinates.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from solvers.domains import Graph
from solvers.domains.base import Domain, check_laplacian_name
from solvers.domains.graph import domain_graph, graph_of_laplacian
from solvers.errors import InputError
from solvers.validation import check_choice, check_int

LaplacianKind = Literal["auto", "robust", "cotan"]


def laplacian_from_weights(weights: sp.spmatrix, field: str = "graph") -> sp.csr_matrix:
    r"""The graph Laplacian :math:`L = D - W` of a weight matrix.

    Parameters
    ----------
    weights : (n, n) sparse matrix
        Symmetric, non-negative weights :math:`W`.
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised.

    Returns
    -------
    (n, n) scipy.sparse.csr_matrix
        :math:`L`, with :math:`D = \operatorname{diag}(W 1)`.
    """
    W = sp.csr_matrix(weights, dtype=np.float64)
    if W.shape[0] != W.shape[1]:
        raise InputError(f"{field}: a weight matrix must be square, got {W.shape}", field=field)
    if not np.all(np.isfinite(W.data)) or np.any(W.data < 0):
        raise InputError(f"{field}: weights must be finite and non-negative", field=field)
    if abs(W - W.T).sum() > 1e-12 * max(abs(W).sum(), 1.0):
        raise InputError(f"{field}: the weight matrix must be symmetric", field=field)
    W = W - sp.diags(W.diagonal())
    W.eliminate_zeros()
    return (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()


def graph_laplacian(graph, laplacian: LaplacianKind = "auto") -> sp.csr_matrix:
    """The PSD Laplacian ``L`` (``L·1 = 0``) of a domain or weight matrix (§5.2, §5.6).

    Parameters
    ----------
    graph : Graph, TriangleMesh, PointCloud, Grid or (n, n) sparse matrix
        The domain, or a symmetric non-negative weight matrix (see :mod:`.graphs`).
    laplacian : {"auto", "robust", "cotan"}
        The Laplacian of a mesh (cotangent or robust); other domains have one.

    Returns
    -------
    (n, n) scipy.sparse.csr_matrix
    """
    if sp.issparse(graph):
        return laplacian_from_weights(graph)
    if isinstance(graph, Domain):
        return graph.laplacian_variant(laplacian)
    check_laplacian_name(laplacian)
    if laplacian != "auto":
        raise InputError(f"laplacian={laplacian!r} applies to triangle meshes only",
                         field="laplacian")
    raise InputError("graph must be a Graph, TriangleMesh, PointCloud or Grid domain, or a "
                     "sparse weight matrix", field="graph")


def as_graph(graph, laplacian: LaplacianKind = "auto") -> Graph:
    """A :class:`~solvers.domains.Graph` with the positive off-diagonal weights :math:`-L_{uv}`.

    Negative cotangent weights of obtuse meshes are dropped; the robust Laplacian has none.

    Parameters
    ----------
    graph, laplacian
        As in :func:`graph_laplacian`.

    Returns
    -------
    Graph
    """
    if isinstance(graph, Domain):
        return domain_graph(graph, laplacian)
    return graph_of_laplacian(graph_laplacian(graph, laplacian))


def component_labels(graph, L: sp.spmatrix | None = None) -> tuple[int, np.ndarray]:
    """``(count, (n,) labels)`` of the connected components."""
    if isinstance(graph, Domain):
        return int(graph.n_components), np.asarray(graph.component_labels)
    count, labels = connected_components(abs(sp.csr_matrix(L)), directed=False)
    return int(count), labels


def knn_graph(points, k: int = 8, *, weights: Literal["uniform", "gaussian"] = "uniform"
              ) -> Graph:
    r"""Symmetric k-nearest-neighbour :class:`~solvers.domains.Graph` of points.

    ``u ~ v`` when either is among the other's ``k`` nearest neighbours.

    Parameters
    ----------
    points : (n, d) array
        Coordinates.
    k : int
        Neighbours per point.
    weights : {"uniform", "gaussian"}
        Edge weights 1, or :math:`\exp(-d_{uv}^2 / \sigma^2)` with :math:`\sigma` the mean
        neighbour distance.

    Returns
    -------
    Graph
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or len(p) < 2 or not np.all(np.isfinite(p)):
        raise InputError("points must be a finite (n, d) array with n >= 2", field="points")
    k = check_int(k, "k", low=1, high=len(p) - 1)
    check_choice(weights, ("uniform", "gaussian"), "weights")
    dist, idx = cKDTree(p).query(p, k=k + 1)
    rows = np.repeat(np.arange(len(p)), k)
    cols = idx[:, 1:].ravel()
    d = dist[:, 1:].ravel()
    a, b = np.minimum(rows, cols), np.maximum(rows, cols)
    keep = a != b
    pairs, first = np.unique(np.stack([a[keep], b[keep]], axis=1), axis=0, return_index=True)
    if weights == "gaussian":
        dd = d[keep][first]
        sigma = float(dd.mean()) or 1.0
        w = np.exp(-(dd / sigma) ** 2)
    else:
        w = np.ones(len(pairs))
    return Graph(len(p), pairs, w, positions=p)

