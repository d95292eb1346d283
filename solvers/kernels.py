r"""Heat kernels :math:`H_t` for every domain kind, applied to ``n×k`` blocks.

Every kernel follows one protocol:

``apply(block)``
    ``block`` is ``(n,)`` or ``(n, k)``; returns :math:`H_t` applied to each
    column, i.e. :math:`(H_t x)(p) \approx \int p_t(p, q)\, x(q)\, dq`, the
    diffusion of a *function* (density) ``x`` with respect to the domain's
    area weights ``a``.  It conserves mass in the ``a``-weighted sense,
    :math:`a^\top H_t x = a^\top x` (exactly for implicit Euler; up to boundary
    truncation for the Gaussian), and is symmetric in the ``a``-weighted inner
    product.
``log_apply(log_block)`` (only where exact, ``supports_log``)
    :math:`\log H_t \exp(\cdot)` evaluated without forming ``exp`` of large
    arguments, for log-domain Sinkhorn at small :math:`\gamma`.

Time convention: the heat equation :math:`\partial_t u = \Delta u`, whose kernel
in :math:`\mathbb{R}^d` is :math:`(4\pi t)^{-d/2}\exp(-d^2/4t)`.  By Varadhan's
formula :math:`d^2 = \lim_{t\to 0} -4t \log p_t`, so the Gibbs kernel
:math:`\exp(-d^2/\gamma)` of entropic transport with cost :math:`d^2` and
regularization :math:`\gamma` is the heat kernel at :math:`t = \gamma/4`
(:func:`heat_time`).  The thesis writes :math:`t = \gamma/2` for the kernel
:math:`\exp(-d^2/2\gamma)`, i.e. for the cost :math:`d^2/2`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import scipy.sparse as sp
from scipy.special import logsumexp

from solvers.linalg import Backend, factorize_spd


def heat_time(gamma: float) -> float:
    r"""Heat time :math:`t` whose kernel approximates :math:`\exp(-d^2/\gamma)` (Varadhan)."""
    return gamma / 4.0


class HeatKernel(Protocol):
    n: int
    t: float
    supports_log: bool

    def apply(self, block: np.ndarray) -> np.ndarray: ...

    def log_apply(self, log_block: np.ndarray) -> np.ndarray: ...


class ImplicitEulerHeatKernel:
    r"""Backward-Euler heat diffusion :math:`(D_m + \tau L)\, y = m \odot x`, repeated.

    Used for triangle meshes and point clouds (``m = a``, the lumped areas) and
    for graphs (``m = 1``: :math:`(I + tL)^{-1}`).  The time ``t`` is split into
    ``substeps`` equal steps :math:`\tau = t / \text{substeps}`; more substeps
    bring the kernel closer to the true heat kernel (thesis §3.5).  The matrix
    is factored once (sparse Cholesky) and every application is a multi-RHS
    triangular solve.

    Parameters
    ----------
    mass : (n,) positive lumped mass ``m``.
    laplacian : (n, n) sparse PSD weak Laplacian ``L`` with ``L·1 = 0``.
    t : heat time, > 0.
    substeps : number of implicit Euler steps, >= 1.
    """

    supports_log = False

    def __init__(
        self,
        mass: np.ndarray,
        laplacian: sp.spmatrix,
        t: float,
        substeps: int = 1,
        backend: Backend = "auto",
    ):
        if not (np.isfinite(t) and t > 0):
            raise ValueError(f"heat time t must be positive and finite, got {t}")
        if int(substeps) < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        self.n = len(mass)
        self.t = float(t)
        self.substeps = int(substeps)
        self.mass = np.asarray(mass, dtype=np.float64)
        step = self.t / self.substeps
        system = sp.diags(self.mass) + step * sp.csc_matrix(laplacian)
        self.factor = factorize_spd(system.tocsc(), backend=backend)

    def apply(self, block: np.ndarray) -> np.ndarray:
        x = np.asarray(block, dtype=np.float64)
        weights = self.mass if x.ndim == 1 else self.mass[:, None]
        for _ in range(self.substeps):
            x = self.factor.solve(weights * x)
        return x

    def log_apply(self, log_block: np.ndarray) -> np.ndarray:
        raise NotImplementedError("implicit Euler kernels have no exact log-domain form")


class GaussianGridHeatKernel:
    r"""Exact heat kernel on a regular grid: a separable Gaussian convolution.

    Along each axis the 1-D kernel is
    :math:`K_{ij} = \frac{h}{\sqrt{4\pi t}} \exp\!\big(-\frac{(x_i-x_j)^2}{4t}\big)`
    (distance wrapped on periodic axes), so ``apply`` is a product of small
    dense matrices, one per axis, on the block reshaped to the grid.
    """

    supports_log = True

    def __init__(self, grid, t: float):
        if not (np.isfinite(t) and t > 0):
            raise ValueError(f"heat time t must be positive and finite, got {t}")
        self.t = float(t)
        self.shape = tuple(grid.shape)
        self.n = int(np.prod(self.shape))
        self.log_factors = []
        for coords, spacing, periodic in zip(
            grid.axis_coordinates, grid.spacing, grid.periodic, strict=True
        ):
            diff = np.abs(coords[:, None] - coords[None, :])
            if periodic:
                period = spacing * len(coords)
                diff = np.minimum(diff, period - diff)
            log_norm = np.log(spacing) - 0.5 * np.log(4.0 * np.pi * self.t)
            self.log_factors.append(log_norm - diff**2 / (4.0 * self.t))
        self.factors = [np.exp(lk) for lk in self.log_factors]

    def _along_axes(self, block: np.ndarray, op) -> np.ndarray:
        x = np.asarray(block, dtype=np.float64)
        vector = x.ndim == 1
        k = 1 if vector else x.shape[1]
        grid = x.reshape(self.shape + (k,))
        for axis in range(len(self.shape)):
            grid = op(axis, grid)
        out = grid.reshape(self.n, k)
        return out[:, 0] if vector else out

    def apply(self, block: np.ndarray) -> np.ndarray:
        def convolve(axis, grid):
            moved = np.moveaxis(grid, axis, 0)
            flat = moved.reshape(moved.shape[0], -1)
            return np.moveaxis((self.factors[axis] @ flat).reshape(moved.shape), 0, axis)

        return self._along_axes(block, convolve)

    def log_apply(self, log_block: np.ndarray) -> np.ndarray:
        def log_convolve(axis, grid):
            moved = np.moveaxis(grid, axis, 0)
            flat = moved.reshape(moved.shape[0], -1)
            out = np.empty_like(flat)
            log_k = self.log_factors[axis]
            # Chunk rows so the (rows, n_axis, rest) temporary stays small.
            chunk = max(1, int(2**24 // max(1, flat.size)))
            for start in range(0, flat.shape[0], chunk):
                rows = slice(start, start + chunk)
                out[rows] = logsumexp(log_k[rows, :, None] + flat[None, :, :], axis=1)
            return np.moveaxis(out.reshape(moved.shape), 0, axis)

        return self._along_axes(log_block, log_convolve)
