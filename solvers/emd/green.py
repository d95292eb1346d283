r"""Dense Green's matrix of the cotangent Laplacian and the compiled ``d_W^0`` face pass.

``d_W^0(x, y) = Σ_f a_f |∇(G_x - G_y)|_f`` (thesis §2.5) needs the Green's function
``G_y`` of every target ``y``: exact one-to-all evaluation is a pass over the dense
pseudo-inverse ``L⁺`` of the cotangent Laplacian.  This module

* builds ``L⁺`` once per mesh (:func:`build_green_matrix`, cached by
  :meth:`EMDOperators.green_matrix`): ``V`` unit right-hand sides solved in blocks with
  the prefactored pinned Laplacian (one pinned vertex per component), then centred per
  component, ``L⁺ = (I - J) G_pin (I - J)`` (``J`` the component-wise averaging
  matrix), and stored in single precision as column panels ``(⌈V/32⌉, V, 32)`` so the
  face pass reads 32 targets of one vertex as one contiguous run.  Only differences
  within a column enter a gradient and the gradient kills constants, so any gauge
  would do; the centred one has the smallest entries, hence the smallest float32
  rounding.  Memory is ``4 V²`` bytes (0.4 GB at 10k vertices), hence the limit
  :data:`GREEN_MAX_VERTICES`.
* evaluates the face sum for all targets in parallel (:func:`dw0_from_green`, numba):
  per face ``f = (i, j, k)`` with ``d1 = u_j - u_i``, ``d2 = u_k - u_i`` and
  ``u = G_s - G_q``, ``a_f |∇u| = sqrt([d1 d2] M_f [d1 d2]ᵀ)`` where
  ``M_f = a_f² [[g1·g1, g1·g2], [g1·g2, g2·g2]]`` and ``g1, g2`` are the gradients of the
  hat functions of ``j`` and ``k`` taken from ``mesh.gradient`` (the same operator as the
  Poisson-solve path; ``g_i = -g1 - g2``).

Accuracy: float32 storage of ``L⁺`` and float32 face sums (flushed to float64 every 64
faces) agree with the float64 evaluation to ≤ 1e-7 relative on average; the worst case,
up to ~5e-5, is a nearest neighbour of the source across a short edge, where the old
blocked-solve path is worse (measured: tests/test_emd_pointwise.py, bench/results/emd.md).
"""

from __future__ import annotations

import time

import numpy as np

from solvers.emd.green_panels import PANEL, GreenMatrix
from solvers.errors import InputError

#: Largest mesh (vertex count) for which the dense Green's matrix is built
#: (4·V² bytes: 1.6 GB at 20k vertices).  Larger meshes use blocked Poisson solves.
GREEN_MAX_VERTICES = 20000
_SOLVE_BLOCK = 256  # unit right-hand sides per multi-RHS solve (a multiple of PANEL)


def face_metric(ops) -> tuple[np.ndarray, np.ndarray]:
    """``(tri (F, 3) int32, metric (F, 3) float32)`` from ``ops.gradient_matrix``."""
    faces = np.asarray(ops.mesh.faces, dtype=np.int64)
    n_f = len(faces)
    rows = 3 * np.arange(n_f)[:, None, None] + np.arange(3)[None, :, None]  # (F, 3 comps, 1)
    rows, cols = np.broadcast_arrays(rows, faces[:, None, :])  # (F, 3 comps, 3 corners)
    grads = np.asarray(ops.gradient_matrix[rows.ravel(), cols.ravel()]).reshape(n_f, 3, 3)
    g1, g2 = grads[:, :, 1], grads[:, :, 2]
    a2 = np.asarray(ops.face_areas, dtype=np.float64) ** 2
    metric = np.stack([a2 * np.einsum("fc,fc->f", g1, g1), 2.0 * a2 * np.einsum("fc,fc->f", g1, g2),
                       a2 * np.einsum("fc,fc->f", g2, g2)], axis=1)
    return faces.astype(np.int32), metric.astype(np.float32)


def build_green_matrix(ops, check=None, max_vertices: int | None = None) -> GreenMatrix:
    """Dense ``L⁺`` of ``ops.laplacian`` (see the module docstring); ``check()`` is called
    between solve blocks (cancellation)."""
    n = ops.n_vertices
    limit = GREEN_MAX_VERTICES if max_vertices is None else max_vertices
    if n > limit:
        raise InputError(
            f"the dense Green's matrix needs {4 * n * n / 1e9:.1f} GB for {n} vertices; the "
            f"limit is {limit} vertices (use method='solve')", field="method")
    from solvers.emd import _green_kernels as kernels

    start = time.perf_counter()
    keep = ops._keep.astype(np.int64)
    pins = ops.pins.astype(np.int64)
    labels = ops.labels
    sizes = np.bincount(labels, minlength=ops.n_components).astype(np.float64)
    # c = G_pin w with w_j = 1 / |component(j)|: row means of G_pin within components
    c = np.zeros(n)
    c[keep] = ops._poisson.solve(1.0 / sizes[labels[keep]])
    mu = np.bincount(labels, weights=c, minlength=ops.n_components) / sizes
    mu_row = mu[labels]
    n_panels = -(-n // PANEL)
    c_padded = np.zeros(n_panels * PANEL)
    c_padded[:n] = c
    panels = np.empty((n_panels, n, PANEL), dtype=np.float32)
    position = np.full(n_panels * PANEL, -1, dtype=np.int64)
    position[keep] = np.arange(len(keep))
    for lo in range(0, n_panels * PANEL, _SOLVE_BLOCK):
        if check is not None:
            check()
        cols = np.arange(lo, min(n_panels * PANEL, lo + _SOLVE_BLOCK))
        rhs = np.zeros((len(keep), len(cols)))
        inside = position[cols] >= 0
        rhs[position[cols[inside]], np.flatnonzero(inside)] = 1.0
        sol = np.ascontiguousarray(ops._poisson.solve(rhs))
        kernels.store_block(sol, keep, pins, c_padded, mu_row, lo, panels)
    panels[-1, :, n - (n_panels - 1) * PANEL:] = 0.0  # padding columns
    tri, metric = face_metric(ops)
    return GreenMatrix(panels=panels, n=n, tri=tri, metric=metric,
                       build_seconds=time.perf_counter() - start)


def dw0_from_green(green: GreenMatrix, source: int, targets: np.ndarray | None) -> np.ndarray:
    """``d_W^0(source, q)`` for ``q`` in ``targets`` (all vertices if None), float64."""
    from solvers.emd import _green_kernels as kernels

    col = green.column(source).astype(np.float64)
    tri = green.tri
    s1 = (col[tri[:, 1]] - col[tri[:, 0]]).astype(np.float32)
    s2 = (col[tri[:, 2]] - col[tri[:, 0]]).astype(np.float32)
    if targets is None or 2 * len(targets) > green.n:
        out = np.empty(green.panels.shape[0] * PANEL)
        kernels.face_pass(green.panels, s1, s2, tri, green.metric, out)
        return out[:green.n] if targets is None else out[targets]
    panels = green.target_panels(np.asarray(targets, dtype=np.int64))
    out = np.empty(panels.shape[0] * PANEL)
    kernels.face_pass(panels, s1, s2, tri, green.metric, out)
    return out[:len(targets)]
