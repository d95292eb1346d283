r"""``d_W^k`` (k > 0) for many targets at once: spectral reduction + batched ADMM (§2.5).

For a source ``x`` and targets ``y`` the thesis' pointwise distance is the
``k``-dimensional problem

.. math::

    d_W^k(x, y) = \min_{c} \sum_f a_f \Big\| d^y_f + \sum_i c_i\, (R\nabla\phi_i)_f \Big\|,
    \qquad d^y = \nabla G_x - \nabla G_y ,

``φ_i`` the first ``k`` Laplacian eigenfunctions (plus the ``2g`` harmonic fields).

**Spectral reduction, once per mesh** (:func:`reduced_spectral_problem`, kept in the
mesh's operator store): every field is tangent, so it is written in a per-face
orthonormal frame (2 numbers per face instead of 3) and scaled by ``sqrt(a_f)``, which
turns the area-weighted inner product into the Euclidean one; the basis is then
orthonormalized (thin QR, ``Q`` of shape ``(2F, m)``).  Its span is unchanged, so the
minimum is the same; ``QᵀQ = I`` makes the ADMM coefficient update a plain product.

**Batched ADMM** (thesis Fig. 2.5, the splitting ``z = d + Qc``), all targets of a block
together: the coefficient update ``c = Qᵀ(z - u - d)`` and ``Qc`` are two dense products
with the shared ``Q`` for the whole block (float32 BLAS), the shrinkage and dual update
are one fused compiled pass (:mod:`solvers.emd._dwk_kernels`); over-relaxation 1.6.
The penalty of each target is ``ρ = RHO_SCALE / mean|d|`` (the inverse of the mean flow
magnitude of its particular flow).  Targets leave their block when converged.

**Certified stopping.**  Every ``check_every`` iterations each target gets an upper bound
(the objective at its current ``c``, a feasible point; the smallest seen is kept) and a
lower bound from the dual: ``y = ρu`` satisfies ``|y_f| ≤ w_f``; projected onto
``Qᵀy = 0`` and rescaled into the balls it is dual feasible, so ``yᵀd`` is below the
minimum (weak duality).  A target stops when ``(upper - lower) / upper ≤ tol``; the
reported distance is the upper bound and the reported residual this certified relative
gap, per target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.emd.bases import SpectralBasis

RHO_SCALE = 1.0
RELAXATION = 1.6
CHECK_EVERY = 10
_CHUNKS = 64  # face chunks of the fused pass (parallel, fixed for determinism)


@dataclass
class ReducedSpectralProblem:
    """The shared data of every target's ``d_W^k`` problem on one mesh.

    ``basis (2F, m)``/``basis_t (m, 2F)``: orthonormal reduced curl basis, float32;
    ``gradient (2F, V)`` sparse: ``sqrt(a_f)`` x frame components of the face gradient;
    ``weights (F,)``: ``sqrt(a_f)`` (the objective is ``Σ_f w_f |z_f|``).
    """

    basis: np.ndarray
    basis_t: np.ndarray
    gradient: sp.csr_matrix
    weights: np.ndarray

    @property
    def size(self) -> int:
        return self.basis.shape[1]


def _face_frames(ops) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal tangent frame per face: first edge direction and ``N × e1``."""
    mesh = ops.mesh
    p, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    e1 = p[f[:, 1]] - p[f[:, 0]]
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(ops.normals, e1)
    return e1, e2


def reduced_spectral_problem(ops, k: int, harmonic: bool = True) -> ReducedSpectralProblem:
    """The reduced problem for ``k`` eigenfunctions, built once per mesh and ``(k,
    harmonic)`` and kept in the mesh's operator store."""
    def build():
        basis = SpectralBasis(ops, k, harmonic=harmonic)
        fields = basis.fields
        if basis.n_harmonic:
            fields = np.concatenate([fields, basis.harmonic.transpose(1, 2, 0)], axis=2)
        e1, e2 = _face_frames(ops)
        w = np.sqrt(ops.face_areas)
        local = np.stack([np.einsum("fc,fck->fk", e1, fields),
                          np.einsum("fc,fck->fk", e2, fields)], axis=1) * w[:, None, None]
        q, _ = np.linalg.qr(local.reshape(2 * ops.n_faces, -1))
        q32 = np.ascontiguousarray(q, dtype=np.float32)
        return ReducedSpectralProblem(basis=q32, basis_t=np.ascontiguousarray(q32.T),
                                      gradient=frame_gradient(ops),
                                      weights=w.astype(np.float32))

    return ops._store.get(("emd", "dwk_reduced", int(k), bool(harmonic)), build)


def frame_gradient(ops) -> sp.csr_matrix:
    """``(2F, V)`` sparse: ``sqrt(a_f)`` x the per-face frame components of the face
    gradient (:func:`_face_frames`), so that ``Σ_f sqrt(a_f) |(G f)_f|`` is ``∫ |∇f| dA``;
    built once per mesh and kept in its operator store."""
    def build():
        e1, e2 = _face_frames(ops)
        w = np.sqrt(ops.face_areas)
        n_f = ops.n_faces
        rows = np.repeat(np.arange(2 * n_f), 3)
        cols = np.tile(np.arange(3), 2 * n_f) + 3 * np.repeat(np.arange(n_f), 6)
        frame = np.stack([e1, e2], axis=1) * w[:, None, None]  # (F, 2, 3)
        project = sp.csr_matrix((frame.ravel(), (rows, cols)), shape=(2 * n_f, 3 * n_f))
        return (project @ ops.gradient_matrix).tocsr()

    return ops._store.get(("emd", "dwk_frame_gradient"), build)


@dataclass
class BlockState:
    """ADMM state of one block of targets (columns): data ``d``, scaled dual ``u``,
    ``work = z - u - d``, penalty inverse, best bounds, iterations."""

    data: np.ndarray
    dual: np.ndarray
    work: np.ndarray
    inv_rho: np.ndarray
    upper: np.ndarray
    lower: np.ndarray
    iterations: np.ndarray
    index: np.ndarray  # positions of the columns in the caller's target list


def _bounds_check(problem, state: BlockState) -> None:
    """Raise ``state.lower`` with the certified dual bound of the current iterate."""
    from solvers.emd._dwk_kernels import dual_bound

    coef = problem.basis_t @ state.dual
    perp = state.dual - problem.basis @ coef
    dot = np.zeros(perp.shape[1])
    ratio = np.zeros(perp.shape[1])
    dual_bound(state.data, perp, problem.weights, _CHUNKS, dot, ratio)
    rho = 1.0 / state.inv_rho.astype(np.float64)
    bound = rho * dot / np.maximum(1.0, rho * ratio)
    np.maximum(state.lower, bound, out=state.lower)


def _start(problem, data: np.ndarray, index: np.ndarray) -> BlockState:
    """Initial state ``c = 0, z = d, u = 0``; ``ρ = RHO_SCALE / mean |d|``."""
    w = problem.weights.astype(np.float64)
    mags = np.sqrt(data[0::2].astype(np.float64) ** 2 + data[1::2].astype(np.float64) ** 2)
    mean_flow = (w @ mags) / (w @ w)
    mean_flow[mean_flow <= 0] = 1.0  # the source as its own target: d = 0, any penalty
    nb = data.shape[1]
    return BlockState(data=data, dual=np.zeros_like(data), work=np.zeros_like(data),
                      inv_rho=(mean_flow / RHO_SCALE).astype(np.float32),
                      upper=np.full(nb, np.inf), lower=np.zeros(nb),
                      iterations=np.zeros(nb, dtype=np.int64), index=index)


def _keep(state: BlockState, keep: np.ndarray) -> BlockState:
    """The state restricted to the columns ``keep`` (contiguous copies)."""
    def cols(a):
        return np.ascontiguousarray(a[:, keep])

    return BlockState(data=cols(state.data), dual=cols(state.dual), work=cols(state.work),
                      inv_rho=state.inv_rho[keep], upper=state.upper[keep],
                      lower=state.lower[keep], iterations=state.iterations[keep],
                      index=state.index[keep])


def gaps(upper: np.ndarray, lower: np.ndarray) -> np.ndarray:
    """Certified relative gap ``(upper - lower) / upper`` (0 for a zero distance)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        g = (upper - np.maximum(lower, 0.0)) / upper
    return np.where(upper > 0, g, 0.0)


def solve_block(problem: ReducedSpectralProblem, data: np.ndarray, *, tol: float,
                max_iter: int, check_every: int = CHECK_EVERY, monitor=None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched ADMM for the targets whose reduced data ``d`` are the columns of ``data``
    ``(2F, B)`` float32.  Returns per target ``(upper, lower, iterations)``: the value at
    the best coefficients found, a certified lower bound, and the iterations it ran."""
    from solvers.emd._dwk_kernels import admm_pass

    nb = data.shape[1]
    upper, lower = np.full(nb, np.inf), np.zeros(nb)
    iterations = np.zeros(nb, dtype=np.int64)
    state = _start(problem, data, np.arange(nb))
    alpha = np.float32(RELAXATION)
    for it in range(1, max_iter + 1):
        coef = problem.basis_t @ state.work
        proj = problem.basis @ coef
        obj = np.zeros(state.data.shape[1])
        admm_pass(state.data, proj, state.dual, state.work, problem.weights, state.inv_rho,
                  alpha, _CHUNKS, obj)
        np.minimum(state.upper, obj, out=state.upper)
        state.iterations += 1
        if it % check_every and it != max_iter:
            continue
        _bounds_check(problem, state)
        gap = gaps(state.upper, state.lower)
        done = gap <= tol
        if monitor is not None:
            monitor(it, float(gap.max()))
        if done.any() or it == max_iter or (monitor is not None and monitor.stalled):
            idx = state.index
            finished = np.ones_like(done) if (it == max_iter or (
                monitor is not None and monitor.stalled)) else done
            upper[idx[finished]] = state.upper[finished]
            lower[idx[finished]] = state.lower[finished]
            iterations[idx[finished]] = state.iterations[finished]
            if finished.all():
                break
            state = _keep(state, np.flatnonzero(~finished))
    return upper, lower, iterations
