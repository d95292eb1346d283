r"""Curvature of a triangle mesh per vertex: normals, signed mean curvature, and the angle
of the principal direction.

Geometry of the surface alone, below the solvers that weight or histogram it: the
mean-curvature face weights of :mod:`solvers.emd.anisotropy` (Fig. 2.15b) and the
per-vertex histograms of :mod:`solvers.histograms.features` (§5.6).
"""

from __future__ import annotations

import numpy as np


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals ``(V, 3)``."""
    fn = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                  vertices[faces[:, 2]] - vertices[faces[:, 0]])
    n = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def mean_curvature(mesh) -> np.ndarray:
    r"""Signed mean curvature :math:`H = \tfrac12 (M^{-1} L x) \cdot n` per vertex (cotangent
    Laplacian, lumped areas; unit-area units)."""
    hn = (mesh.cotan_laplacian @ mesh.vertices) / mesh.areas[:, None]
    return 0.5 * np.einsum("ij,ij->i", hn, vertex_normals(mesh.vertices, mesh.faces))


def principal_direction_angles(mesh) -> np.ndarray:
    """Angle in ``[0, π)`` of the direction of largest ``|curvature|`` per vertex.

    A quadric ``z = a x² + b xy + c y² + d x + e y`` is fitted over the 2-ring in a tangent
    frame whose first axis is the global z axis projected on the tangent plane (the x axis
    where the normal is near z); the angle is that of the shape operator's eigenvector of
    largest ``|eigenvalue|``.  Vertices with fewer than 5 neighbours get 0.
    """
    v, nrm = mesh.vertices, vertex_normals(mesh.vertices, mesh.faces)
    adj = (abs(mesh.cotan_laplacian) > 0).astype(np.float64)
    ring2 = (adj @ adj).tocsr()
    out = np.zeros(len(v))
    ez, ex = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    for i in range(len(v)):
        nb = ring2.indices[ring2.indptr[i]:ring2.indptr[i + 1]]
        nb = nb[nb != i]
        if len(nb) < 5:
            continue
        n = nrm[i]
        ref = ez if abs(n @ ez) < 0.9 else ex
        t1 = ref - (ref @ n) * n
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        d = v[nb] - v[i]
        x, y, z = d @ t1, d @ t2, d @ n
        a, b, c = np.linalg.lstsq(np.c_[x * x, x * y, y * y, x, y], z, rcond=None)[0][:3]
        w, vec = np.linalg.eigh(np.array([[2 * a, b], [b, 2 * c]]))
        e = vec[:, np.argmax(np.abs(w))]
        out[i] = np.mod(np.arctan2(e[1], e[0]), np.pi)
    return out
