r"""Edge-aware regularization of a colour displacement field (guided filter).

The split transfer (:mod:`solvers.color.split`) gives each pixel an ab displacement
:math:`D(p)` that is piecewise constant and jumps where a pixel's ab crosses a bin
boundary or where a source bin's pixels are split between targets.  Following the
transport-map regularization of Rabin, Delon and Gousseau (colour and contrast transfer),
the field is replaced by its guided filter (He, Sun and Tang) with the input's
luminance :math:`I = L^*/100` as guide: in every window :math:`\omega` of radius ``r``

.. math::  D(p) \approx a_\omega I(p) + b_\omega, \qquad
           a_\omega = \frac{\operatorname{cov}_\omega(I, D)}{\operatorname{var}_\omega(I)
           + \varepsilon}, \quad b_\omega = \bar D_\omega - a_\omega \bar I_\omega,

and :math:`\tilde D(p) = \bar a(p) I(p) + \bar b(p)` with the coefficients averaged over
the windows holding ``p``.  So the displacement varies only where the luminance does
(flat regions get one colour shift, edges stay where the input has them), and
:math:`\varepsilon` (``strength``, in squared units of :math:`I`) sets how much of the
field's variation that :math:`I` does not explain is smoothed away.  Large images use the
fast guided filter (moments and coefficients on ``s × s`` block means, coefficients
bilinear at full resolution, :func:`solvers.color._split_kernels.guided_field`).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from scipy import ndimage

from solvers.color import _split_kernels as K


def box_filter(fields, size: int):
    """Each 2-D array of ``fields`` (a list, or the first axis of a 3-D array) replaced in
    place by its average over ``size × size`` windows (edges: nearest); returns ``fields``.
    The filters run on as many threads as numba's (scipy releases the GIL), each exactly
    as alone (scipy's second axis is filtered in place anyway)."""
    def one(f):
        ndimage.uniform_filter(f, size, output=f, mode="nearest")

    workers = min(len(fields), numba.get_num_threads())
    if workers <= 1:
        for f in fields:
            one(f)
    else:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(one, fields))
    return fields


def guided_coefficients(lab: np.ndarray, disp: np.ndarray, shape: tuple[int, int], *,
                        strength: float, s: int, radius: int, nguide: int = 3,
                        moments: np.ndarray | None = None) -> np.ndarray:
    """Box-filtered coefficients ``(2 nguide + 2, h, w)`` of the guided filter of ``disp``
    ``(N, 2)`` with guide ``lab[:, :nguide] / 100`` (``lab`` ``(N, 3)``), on ``s × s``
    blocks, window radius ``radius`` blocks, regularization ``strength``; ``moments``: a
    :func:`moment_buffer` to reuse (overwritten)."""
    W = shape[1]
    if moments is None:
        moments = moment_buffer(shape, s, nguide)
    moments.fill(0.0)
    K.block_moments(lab, disp, W, s, nguide, moments)
    return guided_solve_moments(moments, nguide, strength, radius)


def moment_buffer(shape: tuple[int, int], s: int, nguide: int) -> np.ndarray:
    """A ``(n_moments, h, w)`` buffer of block moments (:func:`~solvers.color.
    _split_kernels.n_moments`) for an image of ``shape`` reduced by ``s``."""
    H, W = shape
    return np.zeros((K.n_moments(nguide), -(-H // s), -(-W // s)))


def guided_solve_moments(mom: np.ndarray, nguide: int, strength: float,
                         radius: int, weighted: bool = False,
                         max_gain: float = np.inf) -> np.ndarray:
    """Box-filtered guided-filter coefficients ``(2 nguide + 2, h, w)`` from block sums
    ``mom`` (:func:`~solvers.color._split_kernels.n_moments` layout; normalized and
    filtered here in place), window radius ``radius`` blocks, regularization ``strength``.
    ``max_gain`` (one guide channel only): each window's gain ``a`` clipped to
    ``[-max_gain, max_gain]`` and ``b = mean D - a mean I`` recomputed (the filtered
    field's slope along the guide bounded, whatever ``strength``)."""
    size = 2 * radius + 1
    if weighted:  # window sums of the weighted moments over the window's weight
        box_filter(mom, size)
        mom[:-1] /= np.maximum(mom[-1], 1e-12)
    else:
        mom[:-1] /= np.maximum(mom[-1], 1.0)
        box_filter(mom[:-1], size)
    means = mom[:-1]
    h, w = mom.shape[1:]
    coef = np.empty((2 * nguide + 2, h, w))
    K.guided_solve(means, nguide, float(strength), coef)
    if np.isfinite(max_gain):
        if nguide != 1:
            raise ValueError("max_gain needs one guide channel")
        np.clip(coef[:2], -max_gain, max_gain, out=coef[:2])
        coef[2:] = means[2:4] - coef[:2] * means[0]
    return box_filter(coef, size)
