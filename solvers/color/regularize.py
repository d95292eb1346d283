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

import numpy as np
from scipy import ndimage

from solvers.color import _split_kernels as K


def guided_coefficients(lab: np.ndarray, disp: np.ndarray, shape: tuple[int, int], *,
                        strength: float, s: int, radius: int, nguide: int = 3) -> np.ndarray:
    """Box-filtered coefficients ``(2 nguide + 2, h, w)`` of the guided filter of ``disp``
    ``(N, 2)`` with guide ``lab[:, :nguide] / 100`` (``lab`` ``(N, 3)``), on ``s × s``
    blocks, window radius ``radius`` blocks, regularization ``strength``."""
    H, W = shape
    h, w = -(-H // s), -(-W // s)
    mom = np.zeros((K.n_moments(nguide), h, w))
    K.block_moments(lab, disp, W, s, nguide, mom)
    return guided_solve_moments(mom, nguide, strength, radius)


def guided_solve_moments(mom: np.ndarray, nguide: int, strength: float,
                         radius: int, weighted: bool = False,
                         max_gain: float = np.inf) -> np.ndarray:
    """Box-filtered guided-filter coefficients ``(2 nguide + 2, h, w)`` from block sums
    ``mom`` (:func:`~solvers.color._split_kernels.n_moments` layout; normalized here in
    place), window radius ``radius`` blocks, regularization ``strength``.  ``max_gain``
    (one guide channel only): each window's gain ``a`` clipped to ``[-max_gain,
    max_gain]`` and ``b = mean D - a mean I`` recomputed (the filtered field's slope
    along the guide bounded, whatever ``strength``)."""
    size = 2 * radius + 1
    if weighted:  # window sums of the weighted moments over the window's weight
        sums = np.stack([ndimage.uniform_filter(m, size, mode="nearest") for m in mom])
        means = sums[:-1] / np.maximum(sums[-1], 1e-12)
    else:
        mom[:-1] /= np.maximum(mom[-1], 1.0)
        means = np.stack([ndimage.uniform_filter(m, size, mode="nearest") for m in mom[:-1]])
    h, w = mom.shape[1:]
    coef = np.empty((2 * nguide + 2, h, w))
    K.guided_solve(means, nguide, float(strength), coef)
    if np.isfinite(max_gain):
        if nguide != 1:
            raise ValueError("max_gain needs one guide channel")
        np.clip(coef[:2], -max_gain, max_gain, out=coef[:2])
        coef[2:] = means[2:4] - coef[:2] * means[0]
    return np.stack([ndimage.uniform_filter(c, size, mode="nearest") for c in coef])
