"""What a default decision may read of a domain: sizes and stored arrays, never operators.

A :class:`DomainSketch` holds the parts of a domain that automatic choices (the route and
regularization of a distance, :mod:`solvers.transport.decision`) are computed from: the
kind, the number of points, component labels, unit-area coordinates and the edges (mesh
edges, graph edges) or grid spacing.  It is built from a domain's stored arrays
(:meth:`DomainSketch.from_stored`, what ``Domain.to_arrays()`` gives plus the unit-area
points and labels), by the library from a built domain (:meth:`DomainSketch.of`) and by the
service from its stored copy, through the same code: both get the same sketch, so the same
decision.  Building one costs a pass over the edges; no Laplacian, factorization or heat
kernel is built.

What differs by kind lives here: the length scale ``h`` and the cheap ground distances of
estimates (:meth:`DomainSketch.distances`: shortest edge paths on meshes, which bound the
geodesic from above; hops on graphs; straight lines, wrapped on periodic grid axes, on grids
and point clouds).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from solvers.domains import DOMAIN_CLASSES, kind_supports

_SKETCHES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """``(m, 2)`` unique undirected edges of ``faces`` (sorted pairs, as ``TriangleMesh.edges``)."""
    f = np.asarray(faces, dtype=np.int64)
    half = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    return np.unique(np.sort(half, axis=1), axis=0)


@dataclass(eq=False)
class DomainSketch:
    """Kind, size, labels, unit-area ``points`` (None on graphs without coordinates),
    ``edges`` (meshes and graphs), on meshes the number of ``junctions`` (non-manifold
    vertices, which the exact geodesics split: ``MeshDiagnostics.nonmanifold_vertices``) and,
    on grids, the largest ``spacing`` and the width of each periodic axis (0 on the
    others)."""

    kind: str
    n: int
    component_labels: np.ndarray
    points: np.ndarray | None = None
    edges: np.ndarray | None = None
    spacing: float | None = None
    periodic_widths: np.ndarray | None = None
    junctions: int = 0
    _memo: dict = field(default_factory=dict, repr=False)

    def supports(self, capability: str) -> bool:
        """Whether the sketched domain has ``capability`` (as ``Domain.supports``)."""
        return kind_supports(self.kind, capability)

    @property
    def geodesic_kernel_available(self) -> bool:
        """Whether the domain offers the geodesic Gaussian kernel (method ``"geodesic"``):
        its kind's rule (``Domain.offers_geodesic_kernel``) on the sketched size."""
        cls = DOMAIN_CLASSES.get(self.kind)
        components = len(np.unique(self.component_labels))
        return cls is not None and cls.offers_geodesic_kernel(self.n, components)

    # -- construction ---------------------------------------------------------------
    @classmethod
    def from_stored(cls, kind: str, arrays: dict[str, np.ndarray], points, component_labels,
                    junctions: int = 0) -> DomainSketch:
        """From ``Domain.to_arrays()`` of a ``kind`` domain, its unit-area ``points`` (None
        for graphs), ``component_labels`` and (meshes) non-manifold vertex count."""
        labels = np.asarray(component_labels)
        pts = None if points is None else np.asarray(points, dtype=np.float64)
        n = len(labels)
        if kind == "mesh":
            return cls(kind, n, labels, pts, mesh_edges(arrays["faces"]),
                       junctions=int(junctions))
        if kind == "graph":
            return cls(kind, n, labels, None, np.asarray(arrays["edges"], dtype=np.int64))
        if kind == "grid":
            from solvers.domains.grid import Grid

            grid = Grid(np.asarray(arrays["shape"]).tolist(), arrays["bounds"],
                        np.asarray(arrays["periodic"]).tolist())
            width = grid.bounds[:, 1] - grid.bounds[:, 0]
            widths = np.where(np.asarray(grid.periodic), width, 0.0)
            return cls(kind, n, labels, pts, None, float(max(grid.spacing)), widths)
        return cls(kind, n, labels, pts)

    @classmethod
    def of(cls, domain) -> DomainSketch:
        """The sketch of a built domain (memoized per domain object; not an operator)."""
        def build():
            points = getattr(domain, "vertices", None)
            if points is None and domain.kind != "graph":
                points = domain.points
            diagnostics = getattr(domain, "diagnostics", None)
            return cls.from_stored(domain.kind, domain.to_arrays(), points,
                                   domain.component_labels,
                                   getattr(diagnostics, "nonmanifold_vertices", 0))

        try:
            return _SKETCHES[domain]
        except KeyError:
            pass
        except TypeError:  # not weakly referenceable: no memo
            return build()
        sketch = _SKETCHES[domain] = build()
        return sketch

    # -- what estimates read ------------------------------------------------------------
    @property
    def length_scale(self) -> float:
        """``h``: mean edge length on meshes (unit area), largest spacing on grids, one hop
        on graphs, ``sqrt(1/n)`` (unit area) on point clouds."""
        if "h" not in self._memo:
            if self.kind == "mesh":
                e, p = self.edges, self.points
                h = float(np.linalg.norm(p[e[:, 0]] - p[e[:, 1]], axis=1).mean())
            elif self.kind == "grid":
                h = float(self.spacing)
            elif self.kind == "graph":
                h = 1.0
            else:
                h = float(math.sqrt(1.0 / max(self.n, 1)))
            self._memo["h"] = h
        return self._memo["h"]

    @property
    def edge_graph(self) -> sp.csr_matrix:
        """Symmetric sparse graph of edge lengths (meshes) or unit hops (graphs)."""
        if "graph" not in self._memo:
            e = self.edges
            if self.kind == "mesh":
                w = np.linalg.norm(self.points[e[:, 0]] - self.points[e[:, 1]], axis=1)
            else:
                w = np.ones(len(e))
            rows, cols = np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]])
            graph = sp.coo_matrix((np.concatenate([w, w]), (rows, cols)),
                                  shape=(self.n, self.n)).tocsr()
            graph.sum_duplicates()
            self._memo["graph"] = graph
        return self._memo["graph"]

    def path_lengths(self, sources) -> np.ndarray:
        """``(len(sources), n)`` shortest edge-path lengths (meshes: upper bounds of the
        geodesic distances) or hop counts (graphs); ``inf`` across components."""
        from scipy.sparse.csgraph import dijkstra

        src = np.asarray(sources, dtype=np.int64)
        rows = self._memo.get("path_rows")
        if rows is None:
            return np.atleast_2d(dijkstra(self.edge_graph, directed=True, indices=src))
        missing = [int(s) for s in dict.fromkeys(src.tolist()) if int(s) not in rows]
        if missing:  # one Dijkstra per source: the same rows as a batched call
            found = np.atleast_2d(dijkstra(self.edge_graph, directed=True, indices=missing))
            rows.update(zip(missing, found, strict=True))
            while len(rows) > self._memo["path_rows_limit"]:
                rows.pop(next(iter(rows)))
        return np.stack([rows[int(s)] for s in src]) if len(src) else np.zeros((0, self.n))

    def remembering_paths(self, budget_bytes: int = 256 * 2**20) -> DomainSketch:
        """A copy of this sketch that keeps the edge-path rows it computes (up to
        ``budget_bytes``, oldest dropped first): many decisions over the same distributions
        (a distance matrix) then search each source once.  Same values as the sketch."""
        from dataclasses import replace

        copy = replace(self, _memo=dict(self._memo))
        copy._memo["path_rows"] = {}
        copy._memo["path_rows_limit"] = max(1, int(budget_bytes) // max(8 * self.n, 1))
        return copy

    def distances(self, sources, targets) -> np.ndarray:
        """``(len(sources), len(targets))`` cheap ground distances for estimates (module
        docstring); ``inf`` between components."""
        src, dst = np.asarray(sources, dtype=np.int64), np.asarray(targets, dtype=np.int64)
        if self.edges is not None:
            return self.path_lengths(src)[:, dst]
        diff = self.points[src][:, None, :] - self.points[dst][None, :, :]
        if self.periodic_widths is not None:
            for axis, width in enumerate(self.periodic_widths):
                if width > 0:
                    diff[..., axis] -= width * np.round(diff[..., axis] / width)
        out = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
        labels = self.component_labels
        return np.where(labels[src][:, None] == labels[dst][None, :], out, np.inf)
