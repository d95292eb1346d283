"""Weighted undirected graphs."""

from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.sparse as sp

from solvers.domains.base import Domain, ExportGeometry, domain_input
from solvers.errors import DomainError, UnsupportedDomainError
from solvers.kernels import ImplicitEulerHeatKernel
from solvers.linalg import Backend
from solvers.validation import check_edge_weights, check_edges


class Graph(Domain):
    r"""An undirected graph with positive edge weights and uniform node weights.

    ``laplacian`` is the combinatorial :math:`L = D - W`; the heat kernel is
    :math:`(I + tL)^{-1}`.  Parallel edges are summed; self loops are refused.

    Parameters
    ----------
    n_nodes : number of nodes.
    edges : (m, 2) node index pairs.
    weights : (m,) positive edge weights (default 1).
    positions : optional (n_nodes, d) coordinates, for display and export.
    """

    kind = "graph"
    capabilities = frozenset({"hop_metric", "histogram_propagation"})

    def __init__(self, n_nodes: int, edges, weights=None, positions=None):
        super().__init__()
        try:
            n_nodes = int(n_nodes)
        except (TypeError, ValueError, OverflowError) as exc:
            raise DomainError("n_nodes must be an integer", field="n_nodes") from exc
        if n_nodes < 1:
            raise DomainError(f"a graph needs at least one node, got {n_nodes}", field="n_nodes")
        with domain_input():
            e = check_edges(edges, n_nodes, "edges")
            w = check_edge_weights(weights, len(e), "weights")
        with np.errstate(over="ignore"):
            degree = np.bincount(e.ravel(), weights=np.repeat(w, 2), minlength=n_nodes)
        if not np.all(np.isfinite(degree)):
            bad = int(np.flatnonzero(~np.isfinite(degree))[0])
            raise DomainError(f"the weights of the edges at node {bad} sum to infinity",
                              field="weights")
        if positions is not None:
            try:
                positions = np.asarray(positions, dtype=np.float64)
            except (TypeError, ValueError, OverflowError) as exc:
                raise DomainError(f"positions must have shape ({n_nodes}, d) of numbers",
                                  field="positions") from exc
            if positions.ndim != 2 or len(positions) != n_nodes or positions.shape[1] == 0:
                raise DomainError(f"positions must have shape ({n_nodes}, d)", field="positions")
            if not np.all(np.isfinite(positions)):
                raise DomainError("positions must be finite", field="positions")
        self.n_nodes = n_nodes
        self.edges = e
        self.weights = w
        self.positions = positions

    @property
    def n(self) -> int:
        return self.n_nodes

    @property
    def extent(self) -> float:
        """Largest possible hop distance, ``n - 1`` (at least 1): graph units are hops."""
        return float(max(self.n_nodes - 1, 1))

    @cached_property
    def adjacency(self) -> sp.csr_matrix:
        e, w = self.edges, self.weights
        adj = sp.coo_matrix(
            (np.concatenate([w, w]), (np.concatenate([e[:, 0], e[:, 1]]),
                                      np.concatenate([e[:, 1], e[:, 0]]))),
            shape=(self.n, self.n),
        )
        return adj.tocsr()

    def _adjacency(self):
        return self.adjacency

    @cached_property
    def areas(self) -> np.ndarray:
        return np.full(self.n, 1.0 / self.n)

    @cached_property
    def laplacian(self) -> sp.csr_matrix:
        adj = self.adjacency
        return (sp.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj).tocsr()

    @property
    def coordinates(self) -> np.ndarray | None:
        """The node ``positions`` as given (None without)."""
        return self.positions

    @property
    def heat_mass(self) -> np.ndarray:
        """Ones: a graph's heat equation counts nodes."""
        return np.ones(self.n)

    def export_geometry(self) -> ExportGeometry:
        """The node positions and the edges; a graph without positions has none."""
        if self.positions is None:
            raise UnsupportedDomainError(
                "this graph has no node positions, so it has no geometry to export as glTF; "
                "use the JSON result", field="format")
        return ExportGeometry(self.positions, edges=self.edges)

    @classmethod
    def stored_geometry(cls, arrays: dict, summary: dict, points) -> dict:
        """The positions (if any) and the edges."""
        return {"points": points, "edges": arrays["edges"]}

    @property
    def is_connected(self) -> bool:
        return self.n_components == 1

    def _build_heat_kernel(self, t: float, substeps: int, backend: Backend):
        return ImplicitEulerHeatKernel(np.ones(self.n), self.laplacian, t, substeps, backend)

    def to_arrays(self) -> dict[str, np.ndarray]:
        arrays = {
            "n_nodes": np.asarray([self.n_nodes], dtype=np.int64),
            "edges": self.edges,
            "weights": self.weights,
        }
        if self.positions is not None:
            arrays["positions"] = self.positions
        return arrays

    def summary(self) -> dict:
        return {
            "kind": self.kind,
            "n": self.n,
            "nodes": self.n,
            "edges": int(len(self.edges)),
            "components": self.n_components,
            "connected": self.is_connected,
        }


def domain_graph(domain: Domain, laplacian: str = "auto") -> Graph:
    """A :class:`Graph` with the positive off-diagonal weights ``-L_uv`` of the domain's
    Laplacian ``laplacian`` (``Domain.laplacian_variant``; negative cotangent weights
    dropped), at its :attr:`~Domain.coordinates`; a graph is returned as it is (its
    ``laplacian`` is not read)."""
    if isinstance(domain, Graph):
        return domain
    return graph_of_laplacian(domain.laplacian_variant(laplacian), domain.coordinates)


def graph_of_laplacian(L: sp.spmatrix, positions=None) -> Graph:
    """The :class:`Graph` with the positive off-diagonal weights ``-L_uv`` of a Laplacian
    (non-negative off-diagonals dropped), at ``positions`` (None: none)."""
    upper = sp.triu(L, k=1).tocoo()
    keep = upper.data < 0
    return Graph(upper.shape[0], np.c_[upper.row[keep], upper.col[keep]], -upper.data[keep],
                 positions=positions)
