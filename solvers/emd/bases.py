r"""Divergence-free flow bases ``Ψ`` for the Beckmann problem (thesis eq. 2.5, §2.5).

A basis maps coefficients ``c`` to a divergence-free (F, 3) field ``Ψ c`` and
provides the adjoint ``Ψᵀ A y`` and solves with the normal matrix
``Ψᵀ A Q Ψ`` for per-face metrics ``Q`` (``Q = I`` for ADMM, whose system is
prefactored once per mesh; ``Q = w I`` for Weiszfeld; ``Q = MᵀM`` for
anisotropic costs).  Coefficients are ``[stream coefficients, harmonic
coefficients]``.

* :class:`CurlBasis` — rotated gradients of every vertex hat function (the
  "full" per-vertex basis), plus the harmonic fields when ``genus > 0``.
* :class:`SpectralBasis` — rotated gradients of the first ``k`` Laplacian
  eigenfunctions (truncated basis for speed), plus the harmonic fields.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.linalg import factorize_spd


def _face_metric_matrix(ops, metric: np.ndarray | None) -> sp.csr_matrix:
    """Block-diagonal ``diag(A_f Rᵀ Q_f R)`` (3F × 3F); ``metric`` is (F,) or (F, 3, 3)."""
    n_f = ops.n_faces
    area = ops.face_areas
    if metric is None:
        return sp.diags(np.repeat(area, 3))
    if metric.ndim == 1:
        return sp.diags(np.repeat(area * metric, 3))
    nx = np.zeros((n_f, 3, 3))  # cross-product matrices [N]x, R = [N]x, Rᵀ = -[N]x
    n = ops.normals
    nx[:, 0, 1], nx[:, 0, 2] = -n[:, 2], n[:, 1]
    nx[:, 1, 0], nx[:, 1, 2] = n[:, 2], -n[:, 0]
    nx[:, 2, 0], nx[:, 2, 1] = -n[:, 1], n[:, 0]
    blocks = -np.einsum("fij,fjk,fkl->fil", nx, metric, nx) * area[:, None, None]
    rows = np.repeat(3 * np.arange(n_f)[:, None] + np.arange(3), 3, axis=1).ravel()
    cols = np.tile(3 * np.arange(n_f)[:, None] + np.arange(3), (1, 3)).ravel()
    return sp.csr_matrix((blocks.ravel(), (rows, cols)), shape=(3 * n_f, 3 * n_f))


def _apply_metric(metric: np.ndarray | None, field: np.ndarray) -> np.ndarray:
    if metric is None:
        return field
    if metric.ndim == 1:
        return metric[:, None] * field
    return np.einsum("fij,fj->fi", metric, field)


class _Basis:
    harmonic: np.ndarray  # (h, F, 3)

    def __init__(self, ops, harmonic: bool):
        self.ops = ops
        self.harmonic = ops.harmonic_fields if harmonic else np.zeros((0, ops.n_faces, 3))
        self.n_harmonic = len(self.harmonic)

    # stream part, implemented by subclasses
    def _stream_field(self, c):  # pragma: no cover - abstract
        raise NotImplementedError

    def _stream_adjoint(self, field):  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def size(self) -> int:
        return self.n_stream + self.n_harmonic

    def apply(self, coef: np.ndarray) -> np.ndarray:
        """``Ψ coef`` (F, 3)."""
        field = self._stream_field(coef[: self.n_stream])
        if self.n_harmonic:
            field = field + np.einsum("h,hfc->fc", coef[self.n_stream:], self.harmonic)
        return field

    def adjoint(self, field: np.ndarray) -> np.ndarray:
        """``Ψᵀ A field`` (size,)."""
        out = self._stream_adjoint(field)
        if self.n_harmonic:
            hv = np.einsum("hfc,f,fc->h", self.harmonic, self.ops.face_areas, field)
            out = np.concatenate([out, hv])
        return out

    def solve_normal(self, rhs: np.ndarray) -> np.ndarray:
        """``(Ψᵀ A Ψ)⁻¹ rhs`` with the prefactored system (harmonic part is orthonormal)."""
        out = self._solve_stream_normal(rhs[: self.n_stream])
        if self.n_harmonic:
            out = np.concatenate([out, rhs[self.n_stream:]])
        return out

    def weighted_solver(self, metric: np.ndarray | None):
        """A callable ``rhs -> (Ψᵀ A Q Ψ)⁻¹ rhs`` for per-face metrics ``Q`` (F,) or (F,3,3)."""
        stream_solve = self._stream_weighted_solver(metric)
        if not self.n_harmonic:
            return stream_solve
        ops = self.ops
        qh = np.stack([_apply_metric(metric, h) for h in self.harmonic])
        b = np.stack([self._stream_adjoint(x) for x in qh], axis=1)  # (n_s, h)
        c = np.einsum("gfc,f,hfc->gh", self.harmonic, ops.face_areas, qh)
        kb = stream_solve(b)
        schur = c - b.T @ kb
        ns = self.n_stream

        def solve(rhs):
            r1, r2 = rhs[:ns], rhs[ns:]
            y1 = stream_solve(r1)
            x2 = np.linalg.solve(schur, r2 - b.T @ y1)
            return np.concatenate([y1 - kb @ x2, x2])

        return solve


class CurlBasis(_Basis):
    """Rotated gradients of the per-vertex stream functions ``P`` (+ harmonic fields)."""

    name = "full"

    def __init__(self, ops, harmonic: bool = True):
        ops.require_curl_basis()
        super().__init__(ops, harmonic)
        self.n_stream = ops.stream_map.shape[1]

    def _stream_field(self, c):
        return self.ops.curl_field(c)

    def _stream_adjoint(self, field):
        return self.ops.curl_adjoint(field)

    def _solve_stream_normal(self, rhs):
        return self.ops.curl_factor.solve(rhs)

    def _stream_weighted_solver(self, metric):
        ops = self.ops
        if metric is None:
            return ops.curl_factor.solve
        gp = (ops.gradient_matrix @ ops.stream_map).tocsr()
        system = (gp.T @ _face_metric_matrix(ops, metric) @ gp).tocsc()
        return factorize_spd(system).solve


class SpectralBasis(_Basis):
    """Rotated gradients of the first ``k`` Laplacian eigenfunctions (+ harmonic fields)."""

    name = "spectral"

    def __init__(self, ops, k: int, harmonic: bool = True):
        ops.require_curl_basis()
        super().__init__(ops, harmonic)
        self.eigenvalues, vecs = ops.stream_eigenbasis(k)
        self.n_stream = k
        self.stream_values = ops.stream_map @ vecs  # (V, k)
        grads = ops.grad(self.stream_values)  # (F, 3, k)
        self.fields = np.cross(ops.normals[:, :, None], grads, axis=1)  # (F, 3, k)

    def _stream_field(self, c):
        return np.einsum("fck,k->fc", self.fields, c)

    def _stream_adjoint(self, field):
        weighted = self.ops.face_areas[:, None] * field
        return np.einsum("fc,fck->k", weighted, self.fields)

    def _solve_stream_normal(self, rhs):
        return rhs / self.eigenvalues

    def _stream_weighted_solver(self, metric):
        if metric is None:
            return self._solve_stream_normal
        a = self.ops.face_areas
        if metric.ndim == 1:
            gram = np.einsum("fck,f,fcl->kl", self.fields, a * metric, self.fields)
        else:
            qf = np.einsum("fij,fjk->fik", metric, self.fields)
            gram = np.einsum("fck,f,fcl->kl", self.fields, a, qf)
        chol = np.linalg.cholesky(gram)

        def solve(rhs):
            return np.linalg.solve(chol.T, np.linalg.solve(chol, rhs))

        return solve
