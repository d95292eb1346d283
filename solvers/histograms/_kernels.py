"""numba kernels of :mod:`solvers.histograms.quantiles` (imported on first use).

Compiled with ``cache=True`` (the first call in a fresh environment compiles for about a
second; later processes load the cache); without a writable cache location they are
compiled once per process.
"""

from __future__ import annotations

import numba
import numpy as np

from solvers.jit import cached_njit


@cached_njit()
def sort_rows_inplace(q):  # pragma: no cover - compiled
    """Sort every row of ``q`` in place; an already sorted row costs one pass."""
    n, m = q.shape
    for i in range(n):
        for k in range(1, m):
            if q[i, k] < q[i, k - 1]:
                q[i] = np.sort(q[i])
                break


@cached_njit()
def histograms_from_sorted_rows(q, levels, edges, out):  # pragma: no cover - compiled
    """``out[i, j]``: the measure of ``{s : g_i(s) in [e_j, e_{j+1})}`` (first and last
    bins also take the mass outside the edges).

    ``g_i`` is piecewise linear through ``(levels[k], q[i, k])`` (rows non-decreasing),
    constant beyond the end levels; the CDF at an inner edge ``e`` is read off between the
    levels ``k - 1`` and ``k``, ``k`` the number of values ``<= e`` (one merge pass of the
    row with the edges).
    """
    n, m = q.shape
    nb = edges.shape[0] - 1
    for i in range(n):
        prev = 0.0
        k = 0
        for j in range(1, nb):
            e = edges[j]
            while k < m and q[i, k] <= e:
                k += 1
            if k <= 0:
                cdf = 0.0
            elif k >= m:
                cdf = 1.0
            else:
                q0 = q[i, k - 1]
                gap = q[i, k] - q0
                frac = (e - q0) / gap if gap > 0 else 0.0
                frac = min(max(frac, 0.0), 1.0)
                cdf = levels[k - 1] + frac * (levels[k] - levels[k - 1])
            out[i, j - 1] = max(cdf - prev, 0.0)
            prev = cdf
        out[i, nb - 1] = max(1.0 - prev, 0.0)


@cached_njit(parallel=True)
def block_residual_parts(indptr, indices, data, X, B):  # pragma: no cover - compiled
    """``(Σ (A X − B)², Σ B²)`` over a block of columns, ``A`` in CSR arrays, without the
    ``n × w`` product: one column per thread (a Fortran-ordered ``X``, as PARDISO returns
    it, is read contiguously)."""
    n = indptr.shape[0] - 1
    w = X.shape[1]
    num = np.zeros(w)
    den = np.zeros(w)
    for j in numba.prange(w):
        sn = 0.0
        sd = 0.0
        for i in range(n):
            acc = -B[i, j]
            for k in range(indptr[i], indptr[i + 1]):
                acc += data[k] * X[indices[k], j]
            sn += acc * acc
            sd += B[i, j] * B[i, j]
        num[j] = sn
        den[j] = sd
    return num.sum(), den.sum()
