r"""Hodge decomposition of a piecewise-constant tangent field on a triangle mesh.

A flow :math:`J` (one tangent vector per face, e.g. an optimal W1 flow) splits as

.. math::
    J = \nabla f + R\nabla g + h ,

with :math:`f` piecewise linear on the vertices (natural boundary conditions), :math:`g`
piecewise linear *non-conforming* (Crouzeix–Raviart: one value per edge midpoint, zero on
boundary edges), :math:`R` the rotation by 90° in each face (:math:`Rv = n \times v`) and
:math:`h` harmonic.  The three parts are :math:`L^2`-orthogonal and, for piecewise-constant
fields, the splitting is exact (Polthier & Preuß, *Identifying vector field singularities
using a discrete Hodge decomposition*, 2003): on a simply connected surface :math:`h = 0`.
The thesis shows :math:`f` and :math:`g` of the path-planning flow in Fig. 2.12.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.emd.harmonic import _face_edges
from solvers.linalg import factorize_spd


@dataclass
class HodgeDecomposition:
    r"""``f`` (V,) vertex potential, ``g`` (E,) stream function on the edge midpoints of
    ``mesh.edges`` (0 on boundary edges), ``g_vertices`` (V,) its mean over each vertex's
    edges (for display), the face fields ``gradient_part`` = ∇f, ``rotated_part`` = R∇g and
    ``harmonic`` = J − ∇f − R∇g, all (F, 3), and ``residual`` = ‖harmonic‖ / ‖J‖ (area
    weighted L2), 0 up to rounding on simply connected surfaces.

    Attributes
    ----------
    f : (V,) array
        Vertex potential.
    g : (E,) array
        Stream function on the edge midpoints of ``mesh.edges``.
    g_vertices : (V,) array
        Its mean over each vertex's edges.
    gradient_part, rotated_part, harmonic : (F, 3) array
        :math:`\nabla f`, :math:`R\nabla g` and :math:`J - \nabla f - R\nabla g`.
    residual : float
        :math:`\|h\| / \|J\|` (area-weighted L2).
    """

    f: np.ndarray
    g: np.ndarray
    g_vertices: np.ndarray
    gradient_part: np.ndarray
    rotated_part: np.ndarray
    harmonic: np.ndarray
    residual: float


def crouzeix_raviart_gradient(mesh) -> sp.csr_matrix:
    """(3F, E) face gradients of edge-midpoint (Crouzeix–Raviart) functions: the basis
    function of edge e is ``1 - 2 φ_o`` on a face with opposite vertex o, so its gradient is
    ``-2 ∇φ_o``."""
    edge_of, _ = _face_edges(mesh)  # edge of half-edge k = (v_k, v_{k+1})
    grad = mesh.gradient.tocoo()
    face, comp = np.divmod(grad.row, 3)
    slot = np.argmax(mesh.faces[face] == grad.col[:, None], axis=1)
    opposite_edge = edge_of[face, (slot + 1) % 3]
    return sp.csr_matrix((-2.0 * grad.data, (grad.row, opposite_edge)),
                         shape=(3 * mesh.n_faces, len(mesh.edges)))


def _rotate(mesh, J: np.ndarray) -> np.ndarray:
    return np.cross(mesh.face_normals, J)


def _least_squares(G: sp.csr_matrix, mass: sp.dia_matrix, target: np.ndarray,
                   free: np.ndarray) -> np.ndarray:
    """``x`` (zero off ``free``) minimizing ``‖G x − target‖²`` in the face-area norm."""
    Gf = G[:, free]
    x = np.zeros(G.shape[1])
    x[free] = factorize_spd((Gf.T @ mass @ Gf).tocsc()).solve(Gf.T @ (mass @ target))
    return x


def hodge_decomposition(mesh, J) -> HodgeDecomposition:
    """Split a face field ``J`` (F, 3) into ∇f + R∇g + h (module docstring).

    ``f`` has zero at one vertex per component; ``g`` is zero on boundary edges (and at one
    edge of each closed component).

    Parameters
    ----------
    mesh : TriangleMesh
        The surface.
    J : (F, 3) array
        A face field.

    Returns
    -------
    HodgeDecomposition
    """
    J = np.asarray(J, dtype=np.float64).reshape(mesh.n_faces, 3)
    mass = sp.diags(np.repeat(mesh.face_areas, 3))
    labels = mesh.component_labels
    _, pinned = np.unique(labels, return_index=True)
    f = _least_squares(mesh.gradient, mass, J.ravel(), np.setdiff1d(np.arange(mesh.n), pinned))
    gradient_part = (mesh.gradient @ f).reshape(-1, 3)

    edges = mesh.edges
    edge_of, _ = _face_edges(mesh)
    count = np.bincount(edge_of.ravel(), minlength=len(edges))
    fixed = count == 1  # boundary edges
    edge_label = labels[edges[:, 0]]
    for c in np.unique(labels):  # closed components: pin one edge (g is defined up to a constant)
        mine = np.flatnonzero(edge_label == c)
        if not fixed[mine].any():
            fixed[mine[0]] = True
    G_cr = crouzeix_raviart_gradient(mesh)
    remainder = J - gradient_part
    # R∇g ≈ r  ⇔  ∇g ≈ Rᵀ r = −n × r
    g = _least_squares(G_cr, mass, -_rotate(mesh, remainder).ravel(), np.flatnonzero(~fixed))
    rotated_part = _rotate(mesh, (G_cr @ g).reshape(-1, 3))
    harmonic = J - gradient_part - rotated_part
    a = mesh.face_areas
    norm = np.sqrt(a @ (J**2).sum(axis=1))
    residual = float(np.sqrt(a @ (harmonic**2).sum(axis=1)) / norm) if norm > 0 else 0.0
    ends = edges.ravel()
    g_vertices = np.bincount(ends, np.repeat(g, 2), minlength=mesh.n) / np.maximum(
        np.bincount(ends, minlength=mesh.n), 1)
    return HodgeDecomposition(f=f, g=g, g_vertices=g_vertices, gradient_part=gradient_part,
                              rotated_part=rotated_part, harmonic=harmonic, residual=residual)
