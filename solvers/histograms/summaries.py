r"""Per-node summaries of histograms: mean, standard deviation, entropy, mode.

Histograms are ``(n, B)`` masses over :class:`~solvers.histograms.bins.Bins` with constant
density inside each bin, so moments are exact for that density (a bin of width ``w``
adds :math:`w^2/12` of variance).  On periodic bins (S¹) the mean is the circular mean
:math:`\arg \sum_j p_j e^{i\theta_j}` and the spread the circular standard deviation
:math:`\sqrt{-2 \ln R}` (``R`` the mean resultant length), in the bins' units.
"""

from __future__ import annotations

import numpy as np

from solvers.histograms.bins import Bins


def _normalized(h: np.ndarray) -> np.ndarray:
    h = np.atleast_2d(np.asarray(h, dtype=np.float64))
    s = h.sum(axis=1, keepdims=True)
    return h / np.where(s > 0, s, 1.0)


def mean(histograms, bins: Bins) -> np.ndarray:
    p = _normalized(histograms)
    if bins.periodic:
        return circular_mean(p, bins)
    return p @ bins.centers


def std(histograms, bins: Bins) -> np.ndarray:
    p = _normalized(histograms)
    if bins.periodic:
        return circular_std(p, bins)
    c = bins.centers
    mu = p @ c
    var = p @ (c**2) - mu**2 + p @ (bins.widths**2 / 12.0)
    return np.sqrt(np.maximum(var, 0.0))


def entropy(histograms, bins: Bins) -> np.ndarray:
    r"""Differential entropy :math:`-\sum_j p_j \ln(p_j / w_j)` of the piecewise-constant
    density (nats)."""
    p = _normalized(histograms)
    w = bins.widths
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(p > 0, p * np.log(p / w), 0.0)
    return -terms.sum(axis=1)


def mode(histograms, bins: Bins) -> np.ndarray:
    """Center of the bin of largest density (mass / width)."""
    p = _normalized(histograms)
    return bins.centers[np.argmax(p / bins.widths, axis=1)]


def _angles(bins: Bins) -> np.ndarray:
    return 2.0 * np.pi * (bins.centers - bins.lo) / bins.period


def circular_mean(histograms, bins: Bins) -> np.ndarray:
    """Circular mean in ``[lo, hi)`` (the bins' units)."""
    p = _normalized(histograms)
    th = _angles(bins)
    z = p @ np.exp(1j * th)
    ang = np.mod(np.angle(z), 2.0 * np.pi)
    return bins.lo + ang * bins.period / (2.0 * np.pi)


def circular_std(histograms, bins: Bins) -> np.ndarray:
    r"""Circular standard deviation :math:`\sqrt{-2\ln R}`, in the bins' units."""
    p = _normalized(histograms)
    R = np.abs(p @ np.exp(1j * _angles(bins)))
    return np.sqrt(-2.0 * np.log(np.clip(R, 1e-300, 1.0))) * bins.period / (2.0 * np.pi)


def summarize(histograms, bins: Bins) -> dict[str, np.ndarray]:
    """Summary statistics of histograms (§5.6).

    Parameters
    ----------
    histograms : (n, B) array
        Histograms over ``bins``.
    bins : Bins
        The bins (periodic bins give the circular mean and std).

    Returns
    -------
    dict of str to (n,) array
        ``"mean"``, ``"std"``, ``"entropy"``, ``"mode"``.
    """
    return {"mean": mean(histograms, bins), "std": std(histograms, bins),
            "entropy": entropy(histograms, bins), "mode": mode(histograms, bins)}


def _abs_integral(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Exact integral of |linear from a to b| over widths w (elementwise)."""
    same = a * b >= 0
    s = np.abs(a) + np.abs(b)
    cross = np.where(s > 0, (a * a + b * b) / (2.0 * np.where(s > 0, s, 1.0)), 0.0)
    return w * np.where(same, 0.5 * s, cross)


def w1_distance(h0, h1, bins: Bins) -> np.ndarray:
    r"""Row-wise :math:`W_1` between histograms on ``bins``: :math:`\int |F - G|`.

    CDFs are piecewise linear (constant density per bin), so the integral is exact on the
    line.  On periodic bins :math:`W_1 = \min_c \int |F - G - c|`, with ``c`` the
    width-weighted median of ``F - G`` at the bin centers.

    Parameters
    ----------
    h0, h1 : (n, B) array
        Histograms.
    bins : Bins
        The bins.

    Returns
    -------
    (n,) array
    """
    p, q = _normalized(h0), _normalized(h1)
    D = np.concatenate([np.zeros((len(p), 1)), np.cumsum(p - q, axis=1)], axis=1)
    w = bins.widths
    if bins.periodic:
        mid = 0.5 * (D[:, :-1] + D[:, 1:])
        order = np.argsort(mid, axis=1)
        cw = np.cumsum(w[order], axis=1)
        k = np.argmax(cw >= 0.5 * w.sum(), axis=1)
        c = np.take_along_axis(mid, np.take_along_axis(order, k[:, None], axis=1), axis=1)
        D = D - c
    return _abs_integral(D[:, :-1], D[:, 1:], w[None, :]).sum(axis=1)
