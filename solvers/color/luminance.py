r"""Luminance transfer: 1-D optimal transport in closed form (quantile matching).

On the line the Wasserstein-2 barycenter of :math:`\nu_1..\nu_k` with weights
:math:`\alpha` has quantile function :math:`Q_\alpha = \sum_j \alpha_j Q_j`, and the optimal
map from :math:`\nu_i` to it is :math:`T_i = Q_\alpha \circ F_i` (:math:`F_i` the CDF).
Here the :math:`\nu_i` are the L* channels, counted in ``lbins`` equal bins over
``[0, 100]`` (all pixels); CDFs and quantile functions are piecewise linear between bin
edges (mass spread uniformly inside a bin), so :math:`T_i` is exact up to the bin width
(100/4096 L* units by default, well below one 8-bit code) and is returned as a table at
the bin edges, applied per pixel by linear interpolation.
"""

from __future__ import annotations

import numpy as np

L_MAX = 100.0
LBINS = 4096


def cdf_at_edges(counts: np.ndarray) -> np.ndarray:
    """``(k, M)`` bin counts -> ``(k, M + 1)`` CDF values at the bin edges."""
    counts = np.asarray(counts, dtype=np.float64)
    c = np.cumsum(counts, axis=-1)
    c = np.concatenate([np.zeros(c.shape[:-1] + (1,)), c], axis=-1)
    return c / c[..., -1:]


def quantiles(cdf: np.ndarray, probs: np.ndarray, lmax: float = L_MAX) -> np.ndarray:
    """Quantile function ``Q(p)`` of a piecewise-linear CDF given at equal edges.

    ``Q`` is linear across each non-empty bin ``[e_m, e_{m+1}]`` (from ``F(e_m)`` to
    ``F(e_{m+1})``) and jumps over empty bins.
    """
    edges = np.linspace(0.0, lmax, cdf.shape[-1])
    full = np.flatnonzero(np.diff(cdf) > 0)
    xp = np.stack([cdf[full], cdf[full + 1]], axis=1).ravel()
    fp = np.stack([edges[full], edges[full + 1]], axis=1).ravel()
    return np.interp(probs, xp, fp)


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
