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

from solvers.errors import InputError
from solvers.linalg import Backend, factorize_spd


def heat_time(gamma: float) -> float:
    r"""Heat time :math:`t` whose kernel approximates :math:`\exp(-d^2/\gamma)` (Varadhan).

    Parameters
    ----------
    gamma : float
        Entropic regularization.

    Returns
    -------
    float
        :math:`t = \gamma / 4`.
    """
    return gamma / 4.0


class HeatKernel(Protocol):
    """What every heat kernel offers the solvers (a protocol).

    Attributes
    ----------
    n : int
        Points of the domain.
    t : float
        Heat time.
    supports_log : bool
        Whether :meth:`log_apply` is exact at any ``t``.
    """
    n: int
    t: float
    supports_log: bool

    def apply(self, block: np.ndarray) -> np.ndarray:
        r"""Apply the kernel to a block: :math:`H_t x` per column.

        Parameters
        ----------
        block : (n,) or (n, k) array
            Densities (functions) on the domain, one per column.

        Returns
        -------
        (n,) or (n, k) array
        """
        ...

    def log_apply(self, log_block: np.ndarray) -> np.ndarray:
        r"""Apply the kernel in the log domain: :math:`\log H_t \exp(x)` per column.

        Parameters
        ----------
        log_block : (n,) or (n, k) array
            Logarithms (``-inf`` for zeros).

        Returns
        -------
        (n,) or (n, k) array
        """
        ...


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
    backend : sparse factorization backend (:func:`~solvers.linalg.factorize_spd`).
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
            raise InputError(f"heat time t must be positive and finite, got {t}", field="t")
        if int(substeps) < 1:
            raise InputError(f"substeps must be >= 1, got {substeps}", field="substeps")
        self.n = len(mass)
        self.t = float(t)
        self.substeps = int(substeps)
        self.mass = np.asarray(mass, dtype=np.float64)
        step = self.t / self.substeps
        system = sp.diags(self.mass) + step * sp.csc_matrix(laplacian)
        self.factor = factorize_spd(system.tocsc(), backend=backend)

    def apply(self, block: np.ndarray) -> np.ndarray:
        r"""``substeps`` sparse solves :math:`(D_m + \tau L)\, y = m \odot x`, one block.

        Parameters
        ----------
        block : (n,) or (n, k) array, as in :meth:`HeatKernel.apply`
        """
        x = np.asarray(block, dtype=np.float64)
        weights = self.mass if x.ndim == 1 else self.mass[:, None]
        for _ in range(self.substeps):
            x = self.factor.solve(weights * x)
        return x

    def log_apply(self, log_block: np.ndarray) -> np.ndarray:
        """Not offered: raises ``NotImplementedError`` (no exact log-domain form).

        Parameters
        ----------
        log_block : (n,) or (n, k) array, as in :meth:`HeatKernel.log_apply`
        """
        raise NotImplementedError("implicit Euler kernels have no exact log-domain form")


# Subnormal floats make BLAS products 5-10x slower (microcode assists), so the
# log-domain products below are arranged so that no operand or product is subnormal.
_TINY = np.finfo(np.float64).tiny  # smallest normal float, e^-708.4
_LOG_TINY = float(np.log(_TINY))
# Largest log-range (natural units) a stabilized block of kernel rows may span; see
# _log_contract.  With spread s every row sum is >= 1 and at most n e^s (no overflow),
# and the inputs flushed to avoid subnormal products add < n e^(s - 708.4) relative:
# below 1e-22 for s <= 650 and n <= 1000.
_LOG_SPREAD = 650.0


def _stabilized_row_blocks(log_k: np.ndarray, spread: float = _LOG_SPREAD) -> list[tuple]:
    """Split the rows of a log-kernel into contiguous blocks ``I`` of bounded spread.

    For each block returns ``(start, stop, shift, scaled, s)``: the block's spread
    ``s = max_l (shift[l] - min_{i in I} log_k[i, l]) <= spread`` with
    ``shift[l] = max_{i in I} log_k[i, l]`` (a scalar when constant), and
    ``scaled = exp(log_k[I] - shift + s)`` in ``[1, e^s]``.
    """
    n = log_k.shape[0]
    blocks = []
    start = 0
    while start < n:
        hi = log_k[start].copy()
        lo = hi.copy()
        stop = start + 1
        while stop < n:
            new_hi = np.maximum(hi, log_k[stop])
            new_lo = np.minimum(lo, log_k[stop])
            if np.max(new_hi - new_lo) > spread:
                break
            hi, lo = new_hi, new_lo
            stop += 1
        width = float(np.max(hi - lo))
        scaled = np.exp(log_k[start:stop] - hi + width)
        shift = float(hi[0]) if np.all(hi == hi[0]) else hi
        blocks.append((start, stop, shift, scaled, width))
        start = stop
    return blocks


def _log_contract(y: np.ndarray, blocks: list[tuple], last: bool, owned: bool) -> np.ndarray:
    r"""``out[.., i, ..] = log sum_l exp(log_k[i, l] + y[.., l, ..])`` by shifted BLAS products.

    ``y`` is ``(B, n, C)`` (contract the middle axis) or, if ``last``, ``(B, n)``;
    ``owned`` allows overwriting ``y``.  Per row block ``I`` (spread ``s``) the
    shift is ``c = max_l (shift_I[l] + y[l])`` (per column) and
    ``exp(log_k[i, l] + y[l] - c + s) = scaled[i, l] * z[l]`` with
    ``z = exp(shift_I + y - c)`` in ``[0, 1]`` (1 at the maximizer) and ``scaled`` in
    ``[1, e^s]`` (block construction).  Every row sum is thus in ``[1, n e^s]``;
    exponents of ``z`` are clamped to the smallest normal float (one pass, no mask),
    so no product is subnormal, which changes a sum by less than ``n e^(s - 708.4)``
    relative; columns that are entirely ``-inf`` give ``-inf`` (log 0).  The sums are
    exact to relative ``n * eps``: the result is the exact log-sum-exp.
    """
    n = y.shape[1]
    single = len(blocks) == 1
    out = None
    for start, stop, shift, scaled, width in blocks:
        if np.ndim(shift) == 0:
            c = np.max(y, axis=1, keepdims=True)
            empty = ~np.isfinite(c)
            c[empty] = 0.0  # all -inf column: result is -inf (log 0), set below
            if single and owned:
                z = y
                z -= c
            else:
                z = y - c
            c += shift - width
        else:
            z = y + (shift if last else shift[:, None])
            c = np.max(z, axis=1, keepdims=True)
            empty = ~np.isfinite(c)
            c[empty] = 0.0
            z -= c
            c -= width
        np.maximum(z, _LOG_TINY, out=z)
        np.exp(z, out=z)
        s = z @ scaled.T if last else np.matmul(scaled, z)
        with np.errstate(divide="ignore"):
            np.log(s, out=s)
        s += c
        if empty.any():
            s[np.broadcast_to(empty, s.shape)] = -np.inf
        if stop - start == n:
            return s
        if out is None:
            out = np.empty_like(y)
        if last:
            out[:, start:stop] = s
        else:
            out[:, start:stop, :] = s
    return out


class GaussianGridHeatKernel:
    r"""Exact heat kernel on a regular grid: a separable Gaussian convolution.

    Along each axis the 1-D kernel is
    :math:`K_{ij} = \frac{h}{\sqrt{4\pi t}} \exp\!\big(-\frac{(x_i-x_j)^2}{4t}\big)`
    (distance wrapped on periodic axes), so ``apply`` is one dense matrix
    product per axis on the block reshaped to the grid.  Internally blocks are
    laid out as ``(k, *shape)`` so that every axis is a single BLAS call
    (batched over the ``k`` columns for leading axes); ``apply`` returns an
    ``(n, k)`` array whose transpose is C-contiguous, so feeding results back
    in costs no copy.

    ``log_apply`` computes :math:`\log K \exp(\cdot)` exactly (to relative
    ``n·eps``, no underflow at any ``t``) at nearly the cost of ``apply``:
    along each axis, rows of the kernel are grouped into blocks whose
    log-kernel spread is at most ``_LOG_SPREAD`` (one block when
    :math:`D^2/4t \le 650`, ``D`` the axis length, e.g. all of ``[0,1]`` for
    :math:`\gamma = 4t \ge 1/650`), and each block is one max-shifted BLAS product
    (:func:`_log_contract`).  :meth:`log_apply_exact` is the straightforward
    nested log-sum-exp, kept as the reference.

    Parameters
    ----------
    grid : Grid
        The grid.
    t : float
        Heat time.
    """

    supports_log = True

    def __init__(self, grid, t: float):
        if not (np.isfinite(t) and t > 0):
            raise InputError(f"heat time t must be positive and finite, got {t}", field="t")
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
        # Entries below the smallest normal float (only at small t) are flushed to
        # zero: they change no sum by more than 1e-308 and would slow BLAS 5-10x.
        self.factors = [np.where(lk < _LOG_TINY, 0.0, np.exp(lk)) for lk in self.log_factors]
        self.log_blocks = [_stabilized_row_blocks(lk) for lk in self.log_factors]

    def _along_axes(self, block: np.ndarray, step) -> np.ndarray:
        x = np.asarray(block, dtype=np.float64)
        if x.ndim not in (1, 2) or x.shape[0] != self.n:
            raise ValueError(f"expected a block of shape ({self.n},) or ({self.n}, k), "
                             f"got {x.shape}")
        vector = x.ndim == 1
        cols = x[None, :] if vector else x.T
        grid = np.ascontiguousarray(cols).reshape((cols.shape[0],) + self.shape)
        owned = not np.may_share_memory(grid, x)  # may the steps overwrite their input?
        for axis, size in enumerate(self.shape):
            before = grid.shape[0] * int(np.prod(self.shape[:axis], dtype=np.int64))
            after = int(np.prod(self.shape[axis + 1:], dtype=np.int64))
            view = grid.reshape(before, size) if after == 1 else grid.reshape(before, size, after)
            grid = step(axis, view, after == 1, owned).reshape(grid.shape)
            owned = True
        flat = grid.reshape(grid.shape[0], self.n)
        return flat[0] if vector else flat.T

    def apply(self, block: np.ndarray) -> np.ndarray:
        """One dense 1-D Gaussian product per axis.

        Parameters
        ----------
        block : (n,) or (n, k) array, as in :meth:`HeatKernel.apply`
        """
        def convolve(axis, y, last, owned):
            factor = self.factors[axis]
            return y @ factor.T if last else np.matmul(factor, y)

        return self._along_axes(block, convolve)

    def log_apply(self, log_block: np.ndarray) -> np.ndarray:
        """Max-shifted BLAS products per axis, in row blocks of bounded log-spread.

        Parameters
        ----------
        log_block : (n,) or (n, k) array, as in :meth:`HeatKernel.log_apply`
        """
        def log_convolve(axis, y, last, owned):
            return _log_contract(y, self.log_blocks[axis], last, owned)

        return self._along_axes(log_block, log_convolve)

    def log_apply_exact(self, log_block: np.ndarray) -> np.ndarray:
        """Reference ``log_apply``: nested log-sum-exp along each axis (slow, O(n·n_axis) exps).

        Parameters
        ----------
        log_block : (n,) or (n, k) array
            Logarithms.
        """

        def log_convolve(axis, y, last, owned):
            log_k = self.log_factors[axis]
            y3 = y[:, :, None] if last else y
            out = np.empty_like(y3)
            # Chunk rows so the (B, rows, n_axis, C) temporary stays small.
            chunk = max(1, int(2**24 // max(1, y3.size)))
            for start in range(0, log_k.shape[0], chunk):
                rows = slice(start, start + chunk)
                terms = log_k[None, rows, :, None] + y3[:, None, :, :]
                out[:, rows, :] = logsumexp(terms, axis=2)
            return out[:, :, 0] if last else out

        return self._along_axes(log_block, log_convolve)


# Meshes up to this many vertices offer the geodesic Gaussian kernel (method "geodesic"):
# its all-pairs distances and log-kernel blocks are two dense n x n float64 arrays (576 MB at
# this size), and one application reads n^2 entries.
GEODESIC_KERNEL_VERTICES = 6144


def _log_contract_columns(y: np.ndarray, blocks: list[tuple]) -> np.ndarray:
    """:func:`_log_contract` of a dense kernel on ``(n, C)`` columns: ``out[i, c] = log sum_l
    exp(log_k[i, l] + y[l, c])``, one ``(rows, n) @ (n, C)`` BLAS product per row block (the
    product in this orientation is the fast one for few columns)."""
    out = np.empty((blocks[-1][1], y.shape[1]))
    for start, stop, shift, scaled, width in blocks:
        z = y + (shift if np.ndim(shift) == 0 else shift[:, None])
        c = np.max(z, axis=0, keepdims=True)
        empty = ~np.isfinite(c)
        c[empty] = 0.0  # an all -inf column gives -inf (log 0), set below
        z -= c
        np.maximum(z, _LOG_TINY, out=z)
        np.exp(z, out=z)
        block = scaled @ z
        with np.errstate(divide="ignore"):
            np.log(block, out=block)
        block += c - width
        block[np.broadcast_to(empty, block.shape)] = -np.inf
        out[start:stop] = block
    return out


def morton_order(points: np.ndarray, bits: int = 10) -> np.ndarray:
    """A permutation visiting ``(n, d)`` points along a Z-order (Morton) curve, so that
    consecutive points are near each other (row blocks of a dense kernel stay compact).

    Parameters
    ----------
    points : (n, d) array
        Positions.
    bits : int
        Bits per coordinate of the curve.

    Returns
    -------
    (n,) int array
        The permutation.
    """
    p = np.asarray(points, dtype=np.float64)
    lo, span = p.min(axis=0), np.ptp(p, axis=0)
    cells = ((p - lo) / np.where(span > 0, span, 1.0) * (2**bits - 1)).astype(np.int64)
    code = np.zeros(len(p), dtype=np.int64)
    dims = p.shape[1]
    for bit in range(bits):
        for axis in range(dims):
            code |= ((cells[:, axis] >> bit) & 1) << (bit * dims + axis)
    return np.argsort(code, kind="stable")


class GeodesicGaussianKernel:
    r"""The Gibbs kernel of squared geodesic distances, applied exactly in the log domain.

    .. math::  (K x)_i = \sum_j \frac{a_j}{4\pi t}\, e^{-d_{ij}^2 / 4t}\, x_j ,

    with :math:`d` the ``(n, n)`` geodesic distances (for meshes the heat method's,
    :func:`solvers.heat_geodesics.all_pairs_heat_distances`): the kernel that
    :math:`(D_a + tL)^{-k}` approximates, with its Gaussian tail at every distance.  An
    implicit-Euler kernel's tail beyond :math:`\sqrt{k t}` is exponential, so its
    :math:`-4t\log K` grows linearly there and barycenters smear along the direction of travel
    (W1-like); this kernel's :math:`-4t \log K = d^2` (up to the constant normalization)
    everywhere.  ``log_apply`` is exact to relative ``n·eps`` at any ``t`` (row blocks of
    bounded log-spread, one shifted BLAS product each, as the grid's Gaussian); rows are
    visited in a spatially coherent order so that the blocks stay few.

    Parameters
    ----------
    areas : ``(n,)`` positive area weights ``a``.
    squared_distances : ``(n, n)`` symmetric squared ground distances.
    t : heat time (``gamma / 4``), > 0.
    order : optional ``(n,)`` permutation visiting nearby points consecutively.
    """

    supports_log = True

    def __init__(self, areas: np.ndarray, squared_distances: np.ndarray, t: float,
                 order: np.ndarray | None = None):
        if not (np.isfinite(t) and t > 0):
            raise InputError(f"heat time t must be positive and finite, got {t}", field="t")
        self.t = float(t)
        self.n = len(areas)
        self.order = np.arange(self.n) if order is None else np.asarray(order)
        self.inverse = np.argsort(self.order)
        log_k = squared_distances[np.ix_(self.order, self.order)] * (-1.0 / (4.0 * self.t))
        log_k += np.log(np.asarray(areas, dtype=np.float64)[self.order])[None, :]
        log_k -= np.log(4.0 * np.pi * self.t)
        self.blocks = _stabilized_row_blocks(log_k)

    def _permuted(self, block: np.ndarray, contract) -> np.ndarray:
        x = np.asarray(block, dtype=np.float64)
        if x.ndim not in (1, 2) or x.shape[0] != self.n:
            raise ValueError(f"expected a block of shape ({self.n},) or ({self.n}, k), "
                             f"got {x.shape}")
        out = contract((x[:, None] if x.ndim == 1 else x)[self.order])[self.inverse]
        return out[:, 0] if x.ndim == 1 else out

    def apply(self, block: np.ndarray) -> np.ndarray:
        """``exp(log_apply(log x))``: the exact log-domain product, exponentiated.

        Parameters
        ----------
        block : (n,) or (n, k) array, as in :meth:`HeatKernel.apply`
        """
        x = np.asarray(block, dtype=np.float64)
        with np.errstate(divide="ignore"):
            logs = self.log_apply(np.log(np.maximum(x, 0.0)))
        return np.exp(logs)

    def log_apply(self, log_block: np.ndarray) -> np.ndarray:
        """Shifted BLAS products over row blocks in the spatially coherent order.

        Parameters
        ----------
        log_block : (n,) or (n, k) array, as in :meth:`HeatKernel.log_apply`
        """
        return self._permuted(log_block, lambda y: _log_contract_columns(y, self.blocks))
