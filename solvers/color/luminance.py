r"""Luminance transfer: 1-D optimal transport in closed form (quantile matching).

On the line the Wasserstein-2 barycenter of :math:`\nu_1..\nu_k` with weights
:math:`\alpha` has quantile function :math:`Q_\alpha = \sum_j \alpha_j Q_j`, and the optimal
map from :math:`\nu_i` to it is :math:`T_i = Q_\alpha \circ F_i` (:math:`F_i` the CDF).
Here the :math:`\nu_i` are the L* channels, counted in ``lbins`` equal bins over
``[0, 100]`` (all pixels); CDFs and quantile functions are piecewise linear between bin
edges (mass spread uniformly inside a bin; every bin gets a floor of 1e-8 of the mass),
so :math:`T_i` is exact up to the bin width (100/4096 L* units by default, well below
one 8-bit code) and is returned as a table at
the bin edges, applied per pixel by linear interpolation.
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


def luminance_maps(counts: np.ndarray, alphas: np.ndarray, lmax: float = L_MAX) -> np.ndarray:
    r"""Tables ``(B, k, M + 1)``: :math:`T_{b,i} = Q_{\alpha_b} \circ F_i` at the bin edges.

    ``counts`` ``(k, M)`` L* bin counts of the inputs, ``alphas`` ``(B, k)`` weights.
    """
    cdf = cdf_at_edges(counts)
    k, e = cdf.shape
    alphas = np.asarray(alphas, dtype=np.float64)
    out = np.empty((alphas.shape[0], k, e))
    for i in range(k):
        qs = np.stack([quantiles(cdf[j], cdf[i], lmax) for j in range(k)])  # (k, e)
        out[:, i, :] = alphas @ qs
    return out
