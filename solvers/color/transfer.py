r"""Color transfer between images by Wasserstein barycenters of chrominance (thesis §3.7).

:func:`color_transfer` recolors each of ``k >= 2`` images towards the barycenter of all
their color distributions, for one or several weight vectors :math:`\alpha`
(Fig. 3.12: :math:`\alpha = (1 - s, s)` interpolates between two palettes):

* chrominance (a*, b*): histograms on a regular grid over :math:`[-128, 128]^2`, their
  barycenter :math:`\mu_\alpha` by Alg. 2 with the exact Gaussian kernel, and the
  barycentric projection :math:`T_i` of each input's plan, applied to every pixel's ab by
  bilinear lookup (:mod:`solvers.color.chrominance`);
* luminance (L*): 1-D optimal transport to the barycenter of the L* distributions, in
  closed form by quantile matching (:mod:`solvers.color.luminance`); ``luminance=False``
  keeps each pixel's L*.

The corrected image :math:`f_i^\alpha = T_i \circ f_i` keeps the size, orientation,
dtype and alpha channel of the input.  Cost: two fused passes over the pixels (Lab and
histograms; map lookup and back to sRGB, :mod:`solvers.color._kernels`) plus a
barycenter on the histogram grid whose cost does not depend on the number of pixels.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from solvers.color import _kernels
from solvers.color.chrominance import AbGrid, check_bins, chrominance_barycenters
from solvers.color.lab import check_image, code_scale, lut_for, pixels
from solvers.color.luminance import L_MAX, LBINS, luminance_maps
from solvers.errors import InputError
from solvers.monitor import SolverResult
from solvers.validation import check_positive, check_weights

DEFAULT_GAMMA = 16.0
MAX_IMAGES = 16


@dataclass(kw_only=True)
class ColorTransferResult(SolverResult):
    r"""Result of :func:`color_transfer`.

    ``images[b][i]``: input ``i`` recolored for ``alphas[b]`` (same shape and dtype as
    the input; ``None`` when not requested through ``recolor``); ``alphas`` ``(B, k)``;
    ``barycenters`` ``(B, bins, bins)`` ab masses (axis 0: a*, axis 1: b*, nodes
    ``-128 + h·i``); ``histograms`` ``(k, bins, bins)`` the inputs' ab masses; ``maps``
    ``(B, k, 2, bins, bins)`` the ab value :math:`T_i` sends each node to (NaN outside
    the computed ``window``); ``luminance_maps`` ``(B, k, lbins)`` the L* each L bin
    goes to (``None`` with ``luminance=False``); ``residual``: largest L1 marginal
    violation over all plans; ``timings``: seconds per stage.
    """

    images: list[list[np.ndarray | None]]
    alphas: np.ndarray
    barycenters: np.ndarray
    histograms: np.ndarray
    maps: np.ndarray
    luminance_maps: np.ndarray | None
    window: tuple[slice, slice]
    bins: int
    gamma: float
    entropy_bounds: np.ndarray | None = None
    timings: dict = field(default_factory=dict)


def check_alphas(alphas, k: int) -> np.ndarray:
    """``None`` (uniform), one ``(k,)`` weight vector or a ``(B, k)`` list -> ``(B, k)``."""
    if alphas is None:
        return np.full((1, k), 1.0 / k)
    arr = np.asarray(alphas, dtype=object)
    rows = [alphas] if arr.ndim == 1 else list(alphas)
    if not rows:
        raise InputError("alphas must not be empty", field="alphas")
    out = []
    for b, row in enumerate(rows):
        try:
            out.append(check_weights(row, k))
        except InputError as exc:
            raise InputError(f"alphas[{b}]: {exc}", field="alphas") from exc
    return np.stack(out)


def color_transfer(
    images: Sequence[np.ndarray],
    alphas=None,
    *,
    bins: int = 256,
    gamma: float = DEFAULT_GAMMA,
    luminance: bool = True,
    sharpen: bool = False,
    debiased: bool = False,
    recolor: Sequence[int] | None = None,
    tol: float = 1e-4,
    max_iter: int = 3000,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> ColorTransferResult:
    r"""Recolor ``images`` towards Wasserstein barycenters of their colors (thesis §3.7).

    .. math::  f_i^\alpha = (T^L_{i}, T^{ab}_{i}) \circ f_i, \qquad
               T^{ab}_i(y) = \frac{1}{\mu_i(y)} \int \pi_i(x, y)\, x\, dx,

    :math:`\pi_i = D_{v_i} K D_{w_i}` the plan between the ab histogram :math:`\mu_i` and
    the barycenter :math:`\arg\min_\mu \sum_j \alpha_j W^2_{2,\gamma}(\mu, \mu_j)`
    (eq. 3.13, Alg. 2) and :math:`T^L_i = (\sum_j \alpha_j Q_j) \circ F_i` the 1-D
    optimal map of the L* channel.

    Parameters
    ----------
    images : ``k >= 2`` (at most 16) images ``(H_i, W_i, 3|4)``, uint8, uint16 or float
        in [0, 1] (sizes may differ; a fourth channel is alpha, copied through).
    alphas : ``(k,)`` weights or a ``(B, k)`` list of them (each row normalized); default
        uniform.  ``(0, 1)`` recolors image 0 with image 1's colors; ``(1 - s, s)`` for a
        sequence of ``s`` interpolates (Fig. 3.12).
    bins : nodes per axis of the ab grid over ``[-128, 128]^2`` (8..1024).
    gamma : entropic regularization in squared ab units (kernel ``exp(-|x-y|^2/gamma)``,
        blur of standard deviation ``sqrt(gamma/2)``).
    luminance : also transfer L* (1-D OT); ``False`` keeps each pixel's L*.
    sharpen, debiased : entropic sharpening (Alg. 3) / debiased barycenters, against the
        desaturation by entropic blur.
    recolor : indices of the images to recolor (default all); the others only contribute
        their histograms.
    tol, max_iter : stopping rule of the barycenter (L1 marginal violation of every plan).
    progress, should_cancel : called every barycenter iteration.

    Returns
    -------
    ColorTransferResult
    """
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    if isinstance(images, np.ndarray) and images.ndim == 3:
        images = [images]
    images = list(images)
    k = len(images)
    if not 2 <= k <= MAX_IMAGES:
        raise InputError(f"color transfer needs 2 to {MAX_IMAGES} images, got {k}",
                         field="images")
    images = [check_image(img, f"images[{i}]") for i, img in enumerate(images)]
    A = check_alphas(alphas, k)
    bins = check_bins(bins)
    gamma = check_positive(gamma, "gamma")
    todo = list(range(k)) if recolor is None else sorted({int(i) for i in recolor})
    if any(not 0 <= i < k for i in todo):
        raise InputError(f"recolor indices must lie in [0, {k})", field="recolor")
    grid = AbGrid(bins)
    lbins = LBINS if luminance else 0

    labs, hists, lcounts = [], [], []
    for i, img in enumerate(images):
        px = pixels(img)
        lut, scale = lut_for(px.dtype)
        lab, counts, lc = _kernels.analyze(px, lut, scale, bins, -128.0, grid.spacing,
                                           lbins, L_MAX, keep_lab=i in todo)
        labs.append(lab)
        hists.append(counts.reshape(bins, bins) / px.shape[0])
        lcounts.append(lc)
    H = np.stack(hists)
    times["analyze"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    cb = chrominance_barycenters(H, A, gamma=gamma, sharpen=sharpen, debiased=debiased,
                                 tol=tol, max_iter=max_iter, progress=progress,
                                 should_cancel=should_cancel)
    lmaps = luminance_maps(np.stack(lcounts), A) if luminance else None
    times["barycenter"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    rows, cols = cb.window
    nodes = grid.nodes
    empty1 = np.zeros(0, dtype=np.float32)
    out_images: list[list[np.ndarray | None]] = [[None] * k for _ in range(A.shape[0])]
    for b in range(A.shape[0]):
        for i in todo:
            img = images[i]
            src = pixels(img)
            out = np.empty_like(src)
            ta = np.ascontiguousarray(cb.maps[b, i, 0, rows, cols], dtype=np.float32)
            tb = np.ascontiguousarray(cb.maps[b, i, 1, rows, cols], dtype=np.float32)
            lut_l = empty1 if lmaps is None else lmaps[b, i].astype(np.float32)
            scale = code_scale(img.dtype)
            offset = 0.5 if img.dtype.kind in "ui" else 0.0
            _kernels.apply(labs[i], src, out, lut_l, L_MAX / LBINS, ta, tb,
                           nodes[rows.start], nodes[cols.start], grid.spacing, scale, offset)
            out_images[b][i] = out.reshape(img.shape).astype(img.dtype, copy=False)
    times["apply"] = time.perf_counter() - t2
    times["total"] = time.perf_counter() - t0
    return ColorTransferResult(
        images=out_images, alphas=A, barycenters=cb.barycenters, histograms=H, maps=cb.maps,
        luminance_maps=lmaps, window=cb.window, bins=bins, gamma=cb.gamma,
        entropy_bounds=cb.entropy_bounds, timings=times, iterations=cb.iterations,
        residual=cb.residual, converged=cb.converged)
