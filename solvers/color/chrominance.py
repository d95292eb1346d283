r"""Chrominance histograms, their Wasserstein barycenters and the color maps (thesis §3.7).

The chrominance plane :math:`M = [-128, 128]^2` (CIE a*, b*) carries a regular grid of
``bins × bins`` nodes :math:`x_{ij} = (-128 + h i, -128 + h j)`, :math:`h = 256/(bins-1)`
(:class:`AbGrid`).  An image's histogram splits every pixel's unit mass bilinearly over
the 4 nodes around its ab value (:func:`ab_histogram`: ``np.bincount`` with weights over
precomputed indices; the fused pass in :mod:`solvers.color._kernels` computes the same
while converting to Lab).

Barycenters (:func:`chrominance_barycenters`): for each weight vector :math:`\alpha` the
barycenter :math:`\mu_\alpha = \arg\min \sum_i \alpha_i W^2_{2,\gamma}(\mu, \mu_i)` by
Alg. 2 on a :class:`~solvers.Grid` with the exact Gaussian kernel
:math:`K = e^{-|x - y|^2/\gamma}` (``gamma`` in squared ab units;
:func:`solvers.convolutional.barycenter.barycenters_log`, all weight vectors in one
block).  Its scalings give the plans :math:`\pi_i = D_{v_i} K D_{w_i}` with marginals
:math:`\mu_\alpha` (side ``v``) and :math:`\mu_i` (side ``w``), and the color map of
input ``i`` is the barycentric projection

.. math::  T_i(y) = \frac{1}{\mu_i(y)} \int \pi_i(x, y)\, x\, dx
                  = \frac{H(v_i \, x)(y)}{H(v_i)(y)},

two more (separable, log-domain) kernel applications per input and coordinate; no
``n × n`` plan is formed.  A pixel's new ab is the average of :math:`T_i` over the nodes
its mass was splatted to, with the same bilinear weights: the barycentric projection of
the plan restricted to that pixel's mass.  (The right-hand side also extends
:math:`T_i` to nodes where :math:`\mu_i = 0`, but that extension tilts steeply near
isolated support; the consistent weights never use it.)

The computation runs on the *window* of the grid that holds every input's support plus
a margin of :math:`4\sqrt{\gamma/2} + 2h` (the kernel's standard deviation is
:math:`\sqrt{\gamma/2}`): nodes farther out carry no mass and kernel values below
:math:`e^{-16}` relative, so results agree with the full grid to that order at a
fraction of the cost (photographs use a small part of the ab plane).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from solvers.convolutional.barycenter import barycenters_log
from solvers.convolutional.common import entropy, masses_from_log, prepare
from solvers.domains.grid import Grid
from solvers.errors import InputError

AB_RANGE = 128.0


@dataclass(frozen=True)
class AbGrid:
    """The ``bins × bins`` node grid over ``[-128, 128]^2`` (axis 0: a*, axis 1: b*)."""

    bins: int

    @property
    def spacing(self) -> float:
        return 2.0 * AB_RANGE / (self.bins - 1)

    @property
    def nodes(self) -> np.ndarray:
        return -AB_RANGE + self.spacing * np.arange(self.bins)

    def splat(self, ab: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Bilinear ("cloud in cell") weights of ``(..., 2)`` ab values: four flat node
        indices (C order, a major) and their weights, summing to 1 per value."""
        ab = np.asarray(ab, dtype=np.float64).reshape(-1, 2)
        u = np.clip((ab + AB_RANGE) / self.spacing, 0.0, self.bins - 1)
        ij = np.minimum(np.floor(u), self.bins - 2).astype(np.int64)
        f = u - ij
        q = ij[:, 0] * self.bins + ij[:, 1]
        fu, fv = f[:, 0], f[:, 1]
        return ([q, q + 1, q + self.bins, q + self.bins + 1],
                [(1 - fu) * (1 - fv), (1 - fu) * fv, fu * (1 - fv), fu * fv])


def check_bins(bins) -> int:
    try:
        b = int(bins)
    except (TypeError, ValueError) as exc:
        raise InputError("bins must be an integer", field="bins") from exc
    if b != bins or not 8 <= b <= 1024:
        raise InputError(f"bins must be an integer in [8, 1024], got {bins!r}", field="bins")
    return b


def ab_histogram(ab, bins: int) -> np.ndarray:
    """Normalized histogram of ab values on the ``bins × bins`` chrominance grid.

    Each value's unit mass is split bilinearly over the 4 nodes around it
    (``np.bincount`` with weights).

    Parameters
    ----------
    ab : (..., 2) array
        CIE a*, b* values, in [-128, 128].
    bins : int
        Nodes per axis of the grid (spacing :math:`h = 256/(bins-1)`).

    Returns
    -------
    (bins, bins) array
        Masses summing to 1 (axis 0: a*, axis 1: b*).
    """
    grid = AbGrid(check_bins(bins))
    index, weight = grid.splat(ab)
    counts = sum(np.bincount(i, weights=w, minlength=grid.bins**2)
                 for i, w in zip(index, weight, strict=True))
    total = counts.sum()
    if total == 0:
        raise InputError("no pixels to histogram", field="ab")
    return (counts / total).reshape(grid.bins, grid.bins)


def support_window(hists: np.ndarray, margin: int) -> tuple[slice, slice]:
    """Index window ``(rows, cols)`` holding every histogram's support plus ``margin``."""
    occupied = np.any(hists > 0, axis=0)
    rows = np.flatnonzero(occupied.any(axis=1))
    cols = np.flatnonzero(occupied.any(axis=0))
    n = hists.shape[-1]
    return (slice(max(0, rows[0] - margin), min(n, rows[-1] + margin + 1)),
            slice(max(0, cols[0] - margin), min(n, cols[-1] + margin + 1)))


def _kernel_window(hists: np.ndarray, gamma: float) -> tuple[slice, slice]:
    """The window of the ab grid on which the barycenters are solved: the histograms'
    support plus four kernel standard deviations (and 2 nodes), at least two nodes wide
    on each axis (a valid :class:`Grid`)."""
    bins = hists.shape[-1]
    sigma = np.sqrt(float(gamma) / 2.0)
    margin = int(np.ceil(4.0 * sigma / AbGrid(bins).spacing)) + 2
    rows, cols = support_window(hists, margin)
    if rows.stop - rows.start < 2 or cols.stop - cols.start < 2:  # a single node wide
        rows = slice(max(0, rows.start - 1), min(bins, rows.stop + 1))
        cols = slice(max(0, cols.start - 1), min(bins, cols.stop + 1))
    return rows, cols


@dataclass
class ChrominanceBarycenters:
    """Barycenters ``(B, bins, bins)`` (masses, sum 1), maps ``(B, k, 2, bins, bins)``
    (the ab value each node is sent to; NaN outside ``window``), the window, and the
    solver's ``iterations``, ``residual`` (largest L1 marginal violation over all plans)
    and ``converged``; ``entropy_bounds`` ``(B,)`` used by sharpening, if any."""

    barycenters: np.ndarray
    maps: np.ndarray
    window: tuple[slice, slice]
    iterations: int
    residual: float
    converged: bool
    entropy_bounds: np.ndarray | None
    gamma: float


def chrominance_barycenters(
    hists: np.ndarray,
    alphas: np.ndarray,
    *,
    gamma: float,
    sharpen: bool = False,
    debiased: bool = False,
    tol: float = 1e-4,
    max_iter: int = 3000,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> ChrominanceBarycenters:
    r"""Barycenters of ``k`` ab histograms for ``B`` weight vectors, and the maps :math:`T_i`.

    For each weight vector :math:`\alpha` (Alg. 2, eq. 3.13)

    .. math:: \mu_\alpha = \arg\min_\mu \sum_i \alpha_i W^2_{2,\gamma}(\mu, \mu_i),

    and the map of input ``i`` is the barycentric projection of its plan
    :math:`\pi_i = D_{v_i} K D_{w_i}` (see the module doc). Every input's plan to every
    barycenter is converged (``measure_all``), also for inputs of weight 0, whose maps are
    what "transfer image i to the colors of image j" uses.

    Parameters
    ----------
    hists : (k, bins, bins) array
        Input ab masses, each summing to 1.
    alphas : (B, k) array
        Weight vectors (rows non-negative, summing to 1).
    gamma : float
        Entropic regularization, in squared ab units.
    sharpen : bool
        Entropic sharpening (Alg. 3) of each barycenter to the largest entropy among its
        weighted inputs.
    debiased : bool
        The debiased barycenter (see :func:`solvers.convolutional.barycenter`).
    tol : float
        Stop when the largest L1 marginal violation is below ``tol``.
    max_iter : int
        Iteration budget.
    progress : callable, optional
        ``progress(iteration, residual)``, called once per iteration.
    should_cancel : callable, optional
        ``should_cancel() -> bool``; True stops with
        :class:`~solvers.errors.CancelledError`.

    Returns
    -------
    ChrominanceBarycenters
        ``barycenters`` ``(B, bins, bins)``, ``maps`` ``(B, k, 2, bins, bins)`` (the ab
        value each node is sent to; NaN outside ``window``), ``window``, ``iterations``,
        ``residual``, ``converged`` and ``entropy_bounds`` ``(B,)`` (sharpening only).
    """
    hists = np.asarray(hists, dtype=np.float64)
    k, bins, _ = hists.shape
    alphas = np.asarray(alphas, dtype=np.float64)
    B = alphas.shape[0]
    rows, cols = _kernel_window(hists, gamma)
    nodes = AbGrid(bins).nodes
    ra, rb = nodes[rows], nodes[cols]
    domain = Grid((len(ra), len(rb)), bounds=[(ra[0], ra[-1]), (rb[0], rb[-1])])
    setup = prepare(domain, gamma=gamma, t=None, substeps=1, tol=tol, max_iter=max_iter,
                    progress=progress, should_cancel=should_cancel)
    sub = hists[:, rows, cols].reshape(k, -1)
    sub = sub / sub.sum(axis=1, keepdims=True)
    # Column b*k + i: input i for barycenter b.
    inputs = np.tile(sub.T, (1, B))
    weights = np.zeros((k * B, B))
    owners = np.repeat(np.arange(B), k)
    for b in range(B):
        weights[b * k:(b + 1) * k, b] = alphas[b]
    bounds = None
    if sharpen:
        ent = np.asarray(entropy(sub.T, setup.areas))
        bounds = np.array([float(np.max(ent[alphas[b] > 0])) for b in range(B)])
    scal: dict = {}
    lbar, it, res, conv = barycenters_log(
        setup.logk, setup.areas, inputs, weights, tol=setup.tol, max_iter=setup.max_iter,
        monitor=setup.monitor, entropy_bounds=bounds, debiased=debiased, owners=owners,
        relax=not sharpen and not debiased, measure_all=True, scalings=scal)
    lv = scal["log_v"]
    # T(y) = H(v x)(y) / H(v)(y) with x measured from the window's first node (>= 0,
    # log 0 = -inf is fine in the log-domain kernel).
    pa, pb = np.meshgrid(ra - ra[0], rb - rb[0], indexing="ij")
    with np.errstate(divide="ignore"):
        la, lb = np.log(pa.ravel())[:, None], np.log(pb.ravel())[:, None]
    block = np.concatenate([lv, lv + la, lv + lb], axis=1)
    out = setup.logk(block)
    C = k * B
    base = out[:, :C]
    ta = ra[0] + np.exp(out[:, C:2 * C] - base)
    tb = rb[0] + np.exp(out[:, 2 * C:] - base)
    shape = (len(ra), len(rb))
    maps = np.full((B, k, 2, bins, bins), np.nan)
    bary = np.zeros((B, bins, bins))
    masses = masses_from_log(lbar, setup.areas)
    for b in range(B):
        bary[b, rows, cols] = masses[:, b].reshape(shape)
        for i in range(k):
            c = b * k + i
            maps[b, i, 0, rows, cols] = ta[:, c].reshape(shape)
            maps[b, i, 1, rows, cols] = tb[:, c].reshape(shape)
    return ChrominanceBarycenters(barycenters=bary, maps=maps, window=(rows, cols),
                                  iterations=int(it), residual=float(res), converged=conv,
                                  entropy_bounds=bounds, gamma=float(setup.gamma))
