r"""A coarse version of a soft map's target and the prolongation back to every vertex.

A soft map of ``N`` source samples needs no more target points than about ``N`` to resolve
its rows: the default regularization blurs each row over a few sample spacings.  So eq.
3.18 can be solved over a coarse target :math:`\tilde M` of about ``N`` vertices and each
row prolonged to the fine target :math:`M` afterwards.

* **Coarse mesh.** Quadric edge-collapse decimation of the target (``fast-simplification``,
  the library behind trimesh's ``simplify_quadric_decimation``) to about ``points``
  vertices, kept in the target's unit-area coordinates; as a domain it is a
  :class:`~solvers.TriangleMesh` of its own (unit area, its own heat kernel).
* **Restriction** (what the coarse points see of the fine target): every coarse vertex is
  projected onto the fine mesh (closest point) and reads fine per-vertex data -- the
  descriptors of the compatibility cost -- by barycentric interpolation there.
* **Prolongation** (masses on :math:`\tilde M` to masses on :math:`M`): every fine vertex
  ``y`` is projected onto the coarse mesh, giving barycentric weights :math:`\beta_j(y)` on
  three coarse vertices.  The density of a coarse row is interpolated,
  :math:`\rho(y) = \sum_j \beta_j(y) \rho_j`, and each coarse vertex's share is normalized
  so that its mass is redistributed exactly:

  .. math::  P_{yj} = \frac{a(y)\, \beta_j(y)}{\sum_{y'} a(y')\, \beta_j(y')},
             \qquad \sum_y P_{yj} = 1,

  so a prolonged row :math:`P\mu` keeps unit mass.  ``P`` has three entries per fine vertex
  (``indices``/``weights`` ``(n, 3)``): a 1,024-sample map is stored as its coarse rows
  plus ``P``, and a row is prolonged when asked for.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from solvers.errors import InputError
from solvers.validation import check_int

# Candidate triangles per projected point: its nearest triangle centroids.
_CANDIDATES = 16
# fast-simplification keeps the mesh being simplified in module state: one call at a time.
_DECIMATION_LOCK = threading.Lock()
# Rows prolonged at once (a block's gathered temporary: rows x n_fine x 3 floats).
APPLY_ROWS = 64


@dataclass
class Prolongation:
    r"""``P`` ``(n_fine, n_coarse)`` with three entries per fine vertex: ``indices`` ``(n, 3)``
    coarse vertices and ``weights`` ``(n, 3)`` (columns of ``P`` sum to 1)."""

    indices: np.ndarray
    weights: np.ndarray
    n_coarse: int

    @property
    def n_fine(self) -> int:
        return len(self.indices)

    @property
    def nbytes(self) -> int:
        return int(self.indices.nbytes + self.weights.nbytes)

    def matrix(self) -> sp.csr_matrix:
        rows = np.repeat(np.arange(self.n_fine), self.indices.shape[1])
        return sp.csr_matrix((self.weights.ravel(), (rows, self.indices.ravel())),
                             shape=(self.n_fine, self.n_coarse))

    def apply(self, rows) -> np.ndarray:
        """Fine masses ``(..., n_fine)`` of coarse masses ``rows`` ``(..., n_coarse)``
        (float32 for float32 rows).  Rows are prolonged in blocks of :data:`APPLY_ROWS`,
        so the gathered ``(rows, n_fine, 3)`` temporary stays small."""
        r = np.asarray(rows)
        if r.shape[-1] != self.n_coarse:
            raise InputError(f"rows must have {self.n_coarse} coarse masses, got "
                             f"{r.shape[-1]}", field="rows")
        dtype = np.float32 if r.dtype == np.float32 else np.float64
        w = self.weights.astype(dtype, copy=False)
        if r.ndim == 1:
            return np.einsum("yk,yk->y", r[self.indices], w)
        flat = r.reshape(-1, self.n_coarse)
        out = np.empty((len(flat), self.n_fine), dtype)
        for r0 in range(0, len(flat), APPLY_ROWS):
            block = flat[r0:r0 + APPLY_ROWS]
            np.einsum("iyk,yk->iy", block[:, self.indices], w, out=out[r0:r0 + APPLY_ROWS])
        return out.reshape(*r.shape[:-1], self.n_fine)

    def blocks(self, rows):
        """``(first row, fine masses of a block of rows)`` for the coarse ``rows``
        ``(N, n_coarse)``, :data:`APPLY_ROWS` rows at a time: the prolonged rows without
        the ``(N, n_fine)`` matrix."""
        for r0 in range(0, len(rows), APPLY_ROWS):
            yield r0, self.apply(rows[r0:r0 + APPLY_ROWS])

    def transpose_apply(self, fine) -> np.ndarray:
        r""":math:`P^\top` ``fine`` for ``fine`` ``(n_fine, ...)``: ``(n_coarse, ...)``."""
        f = np.asarray(fine, np.float64)
        return self.matrix().T @ f


@dataclass
class CoarseTarget:
    """A decimated target (``mesh``, a TriangleMesh at unit area), the ``restriction``
    ``(n_coarse, n_fine)`` (rows: barycentric weights of each coarse vertex on the fine
    mesh, sum 1) and the ``prolongation`` (:class:`Prolongation`); ``spacing`` the coarse
    mesh's mean edge length in the fine target's units."""

    mesh: object
    restriction: sp.csr_matrix
    prolongation: Prolongation
    spacing: float

    @property
    def n(self) -> int:
        return self.mesh.n

    @property
    def nbytes(self) -> int:
        r = self.restriction
        return int(self.mesh.vertices.nbytes + self.mesh.faces.nbytes + r.data.nbytes
                   + r.indices.nbytes + r.indptr.nbytes + self.prolongation.nbytes
                   + self.mesh.operators.nbytes)

    def restrict(self, values) -> np.ndarray:
        """Fine per-vertex ``values`` ``(n_fine, ...)`` read at the coarse vertices."""
        return self.restriction @ np.asarray(values, np.float64)

    def landmark_masses(self, vertex: int) -> np.ndarray:
        """``(n_coarse,)`` unit mass at fine vertex ``vertex``: its barycentric weights on the
        coarse mesh (the coarse distribution whose barycenter is that vertex)."""
        p = self.prolongation
        m = np.zeros(p.n_coarse)
        np.add.at(m, p.indices[vertex], p.weights[vertex])
        return m / m.sum()


def closest_points(points, vertices, faces, candidates: int = _CANDIDATES):
    """For every point, the nearest point of the triangle mesh ``(vertices, faces)``:
    ``(face (m,), barycentric weights (m, 3), distance (m,))``.  Candidate triangles are
    the ``candidates`` whose centroids are nearest to the point."""
    p = np.asarray(points, np.float64)
    k = min(candidates, len(faces))
    _, cand = cKDTree(vertices[faces].mean(axis=1)).query(p, k)
    cand = cand.reshape(len(p), k)
    best = np.full(len(p), np.inf)
    face = np.zeros(len(p), np.int64)
    bary = np.zeros((len(p), 3))
    for j in range(k):
        f = faces[cand[:, j]]
        w, d2 = _closest_on_triangles(p, vertices[f[:, 0]], vertices[f[:, 1]],
                                      vertices[f[:, 2]])
        better = d2 < best
        best[better], face[better], bary[better] = d2[better], cand[better, j], w[better]
    return face, bary, np.sqrt(best)


def _closest_on_triangles(p, a, b, c):
    """Barycentric weights ``(m, 3)`` of the closest point to ``p`` on each triangle
    ``(a, b, c)`` and the squared distance (Ericson, Real-Time Collision Detection 5.1.5:
    the Voronoi regions of the vertices, then the edges, then the face)."""
    ab, ac = b - a, c - a

    def dots(q):
        return np.einsum("ij,ij->i", ab, q), np.einsum("ij,ij->i", ac, q)

    d1, d2 = dots(p - a)
    d3, d4 = dots(p - b)
    d5, d6 = dots(p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    w = np.zeros((len(p), 3))
    done = np.zeros(len(p), bool)

    def put(mask, weights):
        mask = mask & ~done
        w[mask] = weights[mask]
        done[mask] = True

    eye = np.eye(3)
    with np.errstate(divide="ignore", invalid="ignore"):
        put((d1 <= 0) & (d2 <= 0), np.broadcast_to(eye[0], w.shape))
        put((d3 >= 0) & (d4 <= d3), np.broadcast_to(eye[1], w.shape))
        t = d1 / (d1 - d3)
        put((vc <= 0) & (d1 >= 0) & (d3 <= 0), np.stack([1 - t, t, 0 * t], 1))
        put((d6 >= 0) & (d5 <= d6), np.broadcast_to(eye[2], w.shape))
        t = d2 / (d2 - d6)
        put((vb <= 0) & (d2 >= 0) & (d6 <= 0), np.stack([1 - t, 0 * t, t], 1))
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        put((va <= 0) & (d4 >= d3) & (d5 >= d6), np.stack([0 * t, 1 - t, t], 1))
        s = va + vb + vc
        v, u = vb / s, vc / s
        put(np.ones(len(p), bool), np.stack([1 - v - u, v, u], 1))
    w = np.nan_to_num(w, nan=1.0 / 3.0)  # degenerate (zero-area) triangles: their centroid
    q = w[:, :1] * a + w[:, 1:2] * b + w[:, 2:] * c
    return w, ((p - q) ** 2).sum(axis=1)


def decimate(target, points: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric decimation of ``target`` to about ``points`` vertices (unit-area
    coordinates of the target): ``(vertices, faces)``."""
    import fast_simplification

    faces = int(round(points * target.n_faces / target.n))
    with _DECIMATION_LOCK:
        v, f = fast_simplification.simplify(np.ascontiguousarray(target.vertices),
                                            np.ascontiguousarray(target.faces, np.int64),
                                            target_count=max(faces, 4))
    used = np.unique(f)
    remap = np.full(len(v), -1, np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]


def coarse_target(target, points: int) -> CoarseTarget:
    """The target decimated to about ``points`` vertices with its restriction and
    prolongation; cached in ``target.operators`` per ``points``."""
    points = check_int(points, "target_points", low=4, high=target.n)
    return target.operators.get(("softmaps.coarse_target", points),
                                lambda: _build(target, points))


def _build(target, points: int) -> CoarseTarget:
    from solvers.domains.mesh import TriangleMesh

    v, f = decimate(target, points)
    mesh = TriangleMesh(v, f)
    if mesh.n_components > 1:
        raise InputError(f"the target decimated to {points} points falls apart into "
                         f"{mesh.n_components} pieces; ask for more target_points or for "
                         "the full resolution (target_points=None)", field="target_points")
    # Restriction: coarse vertices on the fine mesh.
    face, bary, _ = closest_points(v, target.vertices, target.faces)
    rows = np.repeat(np.arange(len(v)), 3)
    restriction = sp.csr_matrix((bary.ravel(), (rows, target.faces[face].ravel())),
                                shape=(len(v), target.n))
    # Prolongation: fine vertices on the coarse mesh, densities interpolated, each coarse
    # vertex's mass redistributed exactly (columns sum to 1).
    face, bary, _ = closest_points(target.vertices, v, f)
    idx = f[face]
    share = target.areas[:, None] * bary
    total = np.bincount(idx.ravel(), weights=share.ravel(), minlength=len(v))
    empty = np.flatnonzero(total <= 0)
    if len(empty):
        # A coarse vertex no fine vertex projects near: its mass goes to its nearest one.
        _, near = cKDTree(target.vertices).query(v[empty])
        idx, share = _with_columns(idx, share, near, empty, target.areas)
        total = np.bincount(idx.ravel(), weights=share.ravel(), minlength=len(v))
    weights = share / total[idx]
    return CoarseTarget(mesh=mesh, restriction=restriction,
                        prolongation=Prolongation(idx, weights, len(v)),
                        spacing=float(np.linalg.norm(v[mesh.edges[:, 0]] - v[mesh.edges[:, 1]],
                                                     axis=1).mean()))


def _with_columns(idx, share, fine, coarse, areas):
    """Add one entry (``fine[i]``, ``coarse[i]``) per empty column: a fourth slot."""
    extra_idx = np.zeros((len(idx), 1), np.int64)
    extra = np.zeros((len(idx), 1))
    for y, j in zip(fine, coarse, strict=True):
        extra_idx[y, 0], extra[y, 0] = j, areas[y]
    return np.concatenate([idx, extra_idx], 1), np.concatenate([share, extra], 1)
