r"""Harmonic flows of surfaces with handles (the ``2g`` fields the curl basis misses).

By the Hodge decomposition, a divergence-free tangent field on a closed
surface of genus ``g`` is a rotated gradient plus a harmonic field, and the
harmonic fields form a ``2g``-dimensional space (thesis §2.3).  We compute
them from the null space of the combinatorial Hodge Laplacian on edges,
``Δ₁ = d₁ᵀd₁ + d₀d₀ᵀ``, whose kernel is the first cohomology (closed,
non-exact edge 1-forms; ``2g + b - 1`` per component with ``b ≥ 1`` boundary
loops), then

1. turn each closed edge 1-form ω into a piecewise-constant face field (the
   gradient of the per-face linear function with edge differences ω),
2. make it divergence-free, ``X ← X + ∇α`` with ``L α = D X``,
3. remove its component along the curl basis (classes already represented by
   the boundary-loop stream functions nearly vanish here; what is left of them is a
   discretization residue, still divergence-free, kept) and A-orthonormalize.

Genus-0 surfaces skip all of this: their boundary-loop classes are the loop stream
functions.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.linalg import eigsh, factorize_spd


def _face_edges(mesh) -> tuple[np.ndarray, np.ndarray]:
    """Edge index and orientation sign of each face's half-edges (v0v1, v1v2, v2v0)."""
    f = mesh.faces
    n = mesh.n
    keys = mesh.edges[:, 0] * n + mesh.edges[:, 1]
    idx = np.empty((len(f), 3), dtype=np.int64)
    sign = np.empty((len(f), 3))
    for k in range(3):
        a, b = f[:, k], f[:, (k + 1) % 3]
        idx[:, k] = np.searchsorted(keys, np.minimum(a, b) * n + np.maximum(a, b))
        sign[:, k] = np.where(a < b, 1.0, -1.0)
    return idx, sign


def cohomology_basis(mesh) -> np.ndarray:
    """(E, h) closed, co-closed edge 1-forms spanning the first cohomology."""
    genus = mesh.component_genus
    loops = mesh.component_boundary_loops
    h = int(np.sum(2 * genus + np.maximum(loops - 1, 0)))
    if h == 0 or int(np.sum(genus)) == 0:
        # genus 0: the boundary-loop classes are the loop stream functions of the curl
        # basis already; nothing is missing
        return np.zeros((len(mesh.edges), 0))
    e = mesh.edges
    n_e = len(e)
    d0 = sp.csr_matrix((np.concatenate([-np.ones(n_e), np.ones(n_e)]),
                        (np.tile(np.arange(n_e), 2), np.concatenate([e[:, 0], e[:, 1]]))),
                       shape=(n_e, mesh.n))
    idx, sign = _face_edges(mesh)
    d1 = sp.csr_matrix((sign.ravel(), (np.repeat(np.arange(mesh.n_faces), 3), idx.ravel())),
                       shape=(mesh.n_faces, n_e))
    hodge = (d1.T @ d1 + d0 @ d0.T).tocsc()
    shift = 1e-8 * float(hodge.diagonal().mean())
    factor = factorize_spd((hodge + shift * sp.identity(n_e)).tocsc())
    op_inv = spla.LinearOperator(hodge.shape, matvec=factor.solve, dtype=np.float64)
    vals, vecs = eigsh(hodge, k=h, sigma=-shift, OPinv=op_inv, which="LM")
    return vecs


def harmonic_fields(ops) -> np.ndarray:
    """(h, F, 3) A-orthonormal divergence-free fields, A-orthogonal to the curl basis."""
    mesh = ops.mesh
    forms = cohomology_basis(mesh)
    if forms.shape[1] == 0:
        return np.zeros((0, ops.n_faces, 3))
    v, f = mesh.vertices, mesh.faces
    idx, sign = _face_edges(mesh)
    # hat-function gradients of local vertices 1 and 2 on each face
    two_area = 2.0 * ops.face_areas[:, None]
    g1 = np.cross(ops.normals, v[f[:, 0]] - v[f[:, 2]]) / two_area
    g2 = np.cross(ops.normals, v[f[:, 1]] - v[f[:, 0]]) / two_area
    kept = []
    for w in forms.T:
        u1 = sign[:, 0] * w[idx[:, 0]]  # value at v1 minus value at v0
        u2 = -sign[:, 2] * w[idx[:, 2]]  # value at v2 minus value at v0
        x = u1[:, None] * g1 + u2[:, None] * g2
        alpha = ops.solve_poisson(ops.weak_divergence(x))
        x = x + ops.grad(alpha)
        before = ops.norm(x)
        coef = ops.curl_factor.solve(ops.curl_adjoint(x))
        x = x - ops.curl_field(coef)
        for y in kept:
            x = x - ops.inner(x, y) * y
        size = ops.norm(x)
        if size > 1e-6 * max(before, 1e-300):
            kept.append(x / size)
    if not kept:
        return np.zeros((0, ops.n_faces, 3))
    return np.stack(kept)
