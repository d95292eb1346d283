r"""Distributions on the line <-> their inverse CDFs sampled at ``m`` quantile levels.

On Prob(ℝ), :math:`W_2(\mu, \nu)^2 = \int_0^1 (F_\mu^{-1}(s) - F_\nu^{-1}(s))^2 ds`, so a
distribution is represented by its inverse CDF :math:`g = F^{-1}` at the midpoint levels
:math:`s_k = (k + 1/2)/m` (§5.3.1, §5.5).  Inputs:

* histograms over :class:`~solvers.histograms.bins.Bins` (constant density inside a bin:
  the CDF is piecewise linear and is inverted exactly),
* raw samples (the empirical inverse CDF, ``inverted_cdf``),
* continuous piecewise-linear densities on knots (the CDF is piecewise quadratic and is
  inverted exactly).

Back to histograms (§5.5): the inverse CDF is read as the piecewise-linear function
through :math:`(s_k, g_k)`, constant beyond the first and last level, and each bin's
mass is the measure of :math:`\{s : g(s) \in [e_j, e_{j+1})\}`, i.e. the reconstructed
density integrated over the bin's width.
"""

from __future__ import annotations

import numpy as np

from solvers.errors import InputError
from solvers.histograms.bins import Bins, check_histograms, check_samples
from solvers.validation import check_int


def quantile_levels(m: int) -> np.ndarray:
    """``m`` midpoint quantile levels ``(k + 1/2) / m`` in (0, 1).

    Parameters
    ----------
    m : int
        Number of levels.

    Returns
    -------
    (m,) array
    """
    m = check_int(m, "levels", low=2, high=100_000)
    return (np.arange(m) + 0.5) / m


def _rowwise_searchsorted(sorted_rows: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Per row ``i``: ``searchsorted(sorted_rows[i], queries[i], side='right')``.

    Rows of ``sorted_rows`` are non-decreasing; one flat ``searchsorted`` after shifting
    row ``i`` by ``i * span`` so rows do not overlap.
    """
    k, m = sorted_rows.shape
    lo = min(float(sorted_rows.min()), float(queries.min()))
    span = max(float(sorted_rows.max()), float(queries.max())) - lo + 1.0
    shift = (np.arange(k, dtype=np.float64) * span)[:, None]
    flat = ((sorted_rows - lo) + shift).ravel()
    pos = np.searchsorted(flat, ((queries - lo) + shift).ravel(), side="right")
    return pos.reshape(queries.shape) - (np.arange(k) * m)[:, None]


def inverse_cdf_from_histograms(histograms, bins: Bins, levels: np.ndarray,
                                field: str = "histograms") -> np.ndarray:
    """Inverse CDFs of histograms at ``levels`` (exact: the density is constant per bin).

    Parameters
    ----------
    histograms : (k, B) array
        Histograms over ``bins``.
    bins : Bins
        The bins.
    levels : (m,) array
        Quantile levels in (0, 1).
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised.

    Returns
    -------
    (k, m) array
    """
    h = check_histograms(histograms, bins.count, field)
    cdf = np.concatenate([np.zeros((len(h), 1)), np.cumsum(h, axis=1)], axis=1)
    cdf[:, -1] = 1.0
    s = np.broadcast_to(levels, (len(h), len(levels)))
    # bin j with cdf[j] < s <= cdf[j+1]: it has positive mass
    j = _rowwise_searchsorted(cdf, s - 0.0) - 1
    j = np.clip(j, 0, bins.count - 1)
    rows = np.arange(len(h))[:, None]
    c0 = cdf[rows, j]
    p = h[rows, j]
    frac = np.where(p > 0, (s - c0) / np.where(p > 0, p, 1.0), 0.0)
    frac = np.clip(frac, 0.0, 1.0)
    return bins.edges[j] + frac * bins.widths[j]


def inverse_cdf_from_samples(samples, levels: np.ndarray, bins: Bins | None = None,
                             field: str = "samples") -> np.ndarray:
    """Empirical inverse CDF of one node's samples at ``levels``.

    Parameters
    ----------
    samples : (N,) array
        Values.
    levels : (m,) array
        Quantile levels in (0, 1).
    bins : Bins, optional
        Periodic bins wrap the samples into range.
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised.

    Returns
    -------
    (m,) array
    """
    x = check_samples(samples, bins, field)
    return np.quantile(x, levels, method="inverted_cdf")


def inverse_cdf_from_density(knots, density, levels: np.ndarray,
                             field: str = "density") -> np.ndarray:
    r"""Inverse CDF at ``levels`` of a continuous piecewise-linear density.

    On a segment of width ``h`` with end values ``f0, f1`` the CDF is
    :math:`F(t) = f_0 t + (f_1 - f_0) t^2 / 2h`; :math:`F(t) = r` is solved in the stable
    form :math:`t = 2r / (f_0 + \sqrt{f_0^2 + 2 r (f_1 - f_0)/h})`.

    Parameters
    ----------
    knots : (P,) array
        Increasing abscissae.
    density : (P,) array
        Non-negative density values at ``knots``.
    levels, field : (m,) array, str
        Quantile levels in (0, 1); the input an error names.

    Returns
    -------
    (m,) array
    """
    x = np.asarray(knots, dtype=np.float64)
    f = np.asarray(density, dtype=np.float64)
    if x.ndim != 1 or len(x) < 2 or f.shape != x.shape:
        raise InputError(f"{field}: knots and values need the same length >= 2", field=field)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(f))):
        raise InputError(f"{field} must be finite", field=field)
    if np.any(np.diff(x) <= 0):
        raise InputError(f"{field}: knots must be strictly increasing", field=field)
    if np.any(f < 0):
        raise InputError(f"{field}: density values must be non-negative", field=field)
    h = np.diff(x)
    seg = 0.5 * h * (f[:-1] + f[1:])
    total = seg.sum()
    if total <= 0:
        raise InputError(f"{field} has zero total mass", field=field)
    f, seg = f / total, seg / total
    cdf = np.concatenate([[0.0], np.cumsum(seg)])
    cdf[-1] = 1.0
    s = np.asarray(levels, dtype=np.float64)
    j = np.clip(np.searchsorted(cdf, s, side="left") - 1, 0, len(h) - 1)
    r = s - cdf[j]
    f0, slope = f[j], (f[j + 1] - f[j]) / h[j]
    disc = np.sqrt(np.maximum(f0 * f0 + 2.0 * r * slope, 0.0))
    denom = f0 + disc
    t = np.where(denom > 0, 2.0 * r / np.where(denom > 0, denom, 1.0), 0.0)
    return x[j] + np.clip(t, 0.0, h[j])


def cdf_from_inverse_cdf(quantiles: np.ndarray, levels: np.ndarray,
                         points: np.ndarray) -> np.ndarray:
    r"""CDF at ``points`` of the distributions with the given inverse CDFs.

    The inverse CDF is piecewise linear through ``(levels[k], quantiles[:, k])`` and
    constant beyond the end levels (atoms of mass ``levels[0]`` and ``1 - levels[-1]`` at
    the end values), so :math:`F(x) = |\{s : g(s) \le x\}|`.

    Parameters
    ----------
    quantiles : (n, m) array
        Inverse CDFs, rows non-decreasing.
    levels : (m,) array
        Their levels.
    points : (P,) array
        Where to evaluate.

    Returns
    -------
    (n, P) array
    """
    q = np.sort(np.asarray(quantiles, dtype=np.float64), axis=1)
    n, m = q.shape
    x = np.broadcast_to(np.asarray(points, dtype=np.float64), (n, len(points)))
    k = _rowwise_searchsorted(q, x)  # number of levels with g_k <= x
    rows = np.arange(n)[:, None]
    km1 = np.clip(k - 1, 0, m - 1)
    kk = np.clip(k, 0, m - 1)
    q0, q1 = q[rows, km1], q[rows, kk]
    s0, s1 = levels[km1], levels[kk]
    gap = q1 - q0
    frac = np.where(gap > 0, (x - q0) / np.where(gap > 0, gap, 1.0), 0.0)
    inside = s0 + np.clip(frac, 0.0, 1.0) * (s1 - s0)
    return np.where(k <= 0, 0.0, np.where(k >= m, 1.0, inside))


def histograms_from_inverse_cdf(quantiles: np.ndarray, levels: np.ndarray,
                                bins: Bins, *, sorted_rows: bool = False) -> np.ndarray:
    """Histograms on ``bins`` of the distributions with the given inverse CDFs.

    The CDF at every inner edge is read off as in :func:`cdf_from_inverse_cdf`: with ``k``
    the number of levels whose value is at or below the edge, the piecewise-linear inverse
    CDF is inverted between levels ``k - 1`` and ``k`` (one merge pass of each row with
    the edges, compiled: :func:`solvers.histograms._kernels.histograms_from_sorted_rows`).
    Mass below ``e_0`` or above ``e_B`` (none when the labels lie in the bins) is put in
    the first / last bin, so every row sums to 1.

    Parameters
    ----------
    quantiles : (n, m) array
        Inverse CDFs.
    levels : (m,) array
        Their levels.
    bins : Bins
        The bins.
    sorted_rows : bool
        The rows are known to be non-decreasing (else a sorted copy is used).

    Returns
    -------
    (n, B) array
        CDF differences over each bin.
    """
    from solvers.histograms._kernels import histograms_from_sorted_rows

    q = np.asarray(quantiles, dtype=np.float64)
    if q.ndim != 2:
        raise InputError(f"quantiles must be (n, m), got {q.shape}", field="quantiles")
    if not sorted_rows:
        q = np.sort(q, axis=1)
    q = np.ascontiguousarray(q)
    lev = np.ascontiguousarray(levels, dtype=np.float64)
    if lev.shape != (q.shape[1],):
        raise InputError(f"levels must be ({q.shape[1]},), got {lev.shape}", field="levels")
    out = np.empty((len(q), bins.count))
    histograms_from_sorted_rows(q, lev, np.ascontiguousarray(bins.edges, dtype=np.float64),
                                out)
    return out


def sort_rows(quantiles: np.ndarray) -> np.ndarray:
    """Sort the rows of a float64 C-ordered ``(n, m)`` array in place (one pass over rows
    that are sorted already) and return it."""
    from solvers.histograms._kernels import sort_rows_inplace

    if quantiles.dtype != np.float64 or not quantiles.flags.c_contiguous:
        quantiles.sort(axis=1)
        return quantiles
    sort_rows_inplace(quantiles)
    return quantiles
