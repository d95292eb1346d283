r"""Luminance transfer: 1-D optimal transport in closed form (quantile matching).

On the line the Wasserstein-2 barycenter of :math:`\nu_1..\nu_k` with weights
:math:`\alpha` has quantile function :math:`Q_\alpha = \sum_j \alpha_j Q_j`, and the optimal
map from :math:`\nu_i` to it is :math:`T_i = Q_\alpha \circ F_i` (:math:`F_i` the CDF).
Here the :math:`\nu_i` are the L* channels, counted in ``lbins`` equal bins over
``[0, 100]`` (all pixels); CDFs and quantile functions are piecewise linear between bin
edges (every bin gets a floor of 1e-8 of the mass, so both are continuous).  All pixels of
bin ``m`` go to the barycentric projection of the 1-D plan restricted to that bin,

.. math::  T_{i,m} = \frac{1}{F_i(e_{m+1}) - F_i(e_m)} \int_{F_i(e_m)}^{F_i(e_{m+1})}
           Q_\alpha(p)\, dp

(exact: :math:`Q_\alpha` is piecewise linear), the same construction as the chrominance
maps.  This is quantile matching to within one bin (100/4096 L* units by default, well
below one 8-bit code), and it stays right when all pixels of a bin share one value (a flat
image goes to the target's mean L*, not to wherever its value sits inside the bin).
"""

from __future__ import annotations

import numpy as np

L_MAX = 100.0
LBINS = 4096


# Mass added to every bin (relative to the total) so that CDFs are strictly increasing
# and quantile functions continuous: T is then well defined at every bin edge (Q would
# jump across empty bins otherwise); it moves results by ~1e-8 of the L* range.
FLOOR = 1e-8


def cdf_at_edges(counts: np.ndarray) -> np.ndarray:
    """``(k, M)`` bin counts -> ``(k, M + 1)`` CDF values at the bin edges (each bin
    holding at least ``FLOOR`` of the total, so the CDF is strictly increasing)."""
    counts = np.asarray(counts, dtype=np.float64)
    total = counts.sum(axis=-1, keepdims=True)
    counts = counts + FLOOR * total / counts.shape[-1]
    c = np.cumsum(counts, axis=-1)
    c = np.concatenate([np.zeros(c.shape[:-1] + (1,)), c], axis=-1)
    return c / c[..., -1:]


def quantiles(cdf: np.ndarray, probs: np.ndarray, lmax: float = L_MAX) -> np.ndarray:
    """Quantile function ``Q(p)`` of a strictly increasing piecewise-linear CDF given at
    equal edges over ``[0, lmax]`` (linear across each bin)."""
    edges = np.linspace(0.0, lmax, cdf.shape[-1])
    return np.interp(probs, cdf, edges)


def _integral_of_quantiles(cdf: np.ndarray, probs: np.ndarray, lmax: float) -> np.ndarray:
    """``G(p) = \\int_0^p Q`` for the piecewise-linear quantile function of ``cdf``."""
    edges = np.linspace(0.0, lmax, cdf.shape[-1])
    dc = np.diff(cdf)
    de = np.diff(edges)
    knots = np.concatenate([[0.0], np.cumsum(dc * (edges[:-1] + 0.5 * de))])
    k = np.clip(np.searchsorted(cdf, probs, side="right") - 1, 0, len(dc) - 1)
    x = np.clip(probs - cdf[k], 0.0, dc[k])
    return knots[k] + x * edges[k] + 0.5 * x * x * de[k] / dc[k]


def luminance_maps(counts: np.ndarray, alphas: np.ndarray, lmax: float = L_MAX) -> np.ndarray:
    """1-D optimal transport of L* in closed form (quantile matching).

    Tables of the L* value :math:`T_{b,i,m}` that bin ``m`` of input ``i`` is sent to for
    weights ``alphas[b]`` (see the module doc).

    Parameters
    ----------
    counts : (k, M) array
        L* bin counts of the ``k`` inputs.
    alphas : (B, k) array
        Weight vectors.
    lmax : float
        Upper end of the L* axis (bins cover ``[0, lmax]``).

    Returns
    -------
    (B, k, M) array
        The L* value of each bin of each input, per weight vector.
    """
    cdf = cdf_at_edges(counts)
    k, e = cdf.shape
    alphas = np.asarray(alphas, dtype=np.float64)
    out = np.empty((alphas.shape[0], k, e - 1))
    for i in range(k):
        width = np.diff(cdf[i])
        means = np.stack([np.diff(_integral_of_quantiles(cdf[j], cdf[i], lmax)) / width
                          for j in range(k)])  # (k, M): mean of Q_j over bin m of input i
        out[:, i, :] = alphas @ means
    return out


def limit_slope(table: np.ndarray, counts: np.ndarray, limit: float,
                lmax: float = L_MAX) -> np.ndarray:
    r"""Contrast-limited version of a monotone L* table ``(M,)`` (bins of equal width over
    ``[0, lmax]``, ``counts`` ``(M,)`` the source's pixels per bin).

    The exact 1-D map :math:`T` stretches some L* ranges and compresses others, which
    changes local contrast.  Here its slope between consecutive occupied source bins is
    clipped to :math:`[g / c, g c]` (:math:`c` = ``limit`` >= 1, :math:`g` the ratio of the
    standard deviations of :math:`T(L)` and :math:`L` over the source's pixels), the
    table re-integrated over the occupied bins (linear in between), and shifted so the
    source's mean L* goes where :math:`T` sends it.  ``limit = inf`` keeps :math:`T`;
    ``limit = 1`` is the affine map that matches mean and standard deviation.  The result
    is clipped to ``[0, lmax]``.
    """
    if not np.isfinite(limit):
        return table
    w = np.asarray(counts, dtype=np.float64)
    w = w / w.sum()
    centres = (np.arange(len(table)) + 0.5) * lmax / len(table)
    mean_src, mean_out = w @ centres, w @ table
    g = np.sqrt(max(w @ (table - mean_out) ** 2, 0.0)
                / max(w @ (centres - mean_src) ** 2, 1e-12))
    occ = np.flatnonzero(w > 0)
    x = centres[occ]
    slope = np.clip(np.diff(table[occ]) / np.diff(x), g / limit, g * limit)
    at = np.concatenate([[0.0], np.cumsum(slope * np.diff(x))])
    at += mean_out - w[occ] @ at
    # outside the occupied range: the clipped slope carried on (no pixel sits there)
    out = np.interp(centres, x, at)
    out[centres < x[0]] = at[0] - (x[0] - centres[centres < x[0]]) * g
    out[centres > x[-1]] = at[-1] + (centres[centres > x[-1]] - x[-1]) * g
    return np.clip(out, 0.0, lmax)
