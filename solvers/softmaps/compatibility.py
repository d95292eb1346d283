r"""Compatibility cost between two meshes from descriptor differences (§3.7, §4.5.2).

:math:`c(x, y) = \|f_0(x) - f(y)\|_1` (the thesis' choice) or the squared L2 distance
(``norm="l2"``), divided by its area-weighted mean over :math:`M_0 \times M`

.. math::  \bar c = \sum_{x, y} a_0(x)\, a(y)\, c(x, y),

so the cost has mean 1 whatever the meshes' resolution or the descriptors' units (a weight
such as the soft maps' :math:`\tau` means the same on every pair).
"""

from __future__ import annotations

import numpy as np

from solvers.errors import InputError
from solvers.jit import cached_njit
from solvers.parallel import run_blocks
from solvers.validation import check_choice

NORMS = ("l1", "l2")


def _check_descriptors(f, name: str) -> np.ndarray:
    x = np.asarray(f, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or not np.all(np.isfinite(x)):
        raise InputError(f"{name} must be a finite (n, d) array", field=name)
    return x


def _check_pair(f0, f1) -> tuple[np.ndarray, np.ndarray]:
    f0 = _check_descriptors(f0, "f0")
    f1 = _check_descriptors(f1, "f1")
    if f0.shape[1] != f1.shape[1]:
        raise InputError(f"descriptor dimensions differ: {f0.shape[1]} vs {f1.shape[1]}",
                         field="descriptors")
    return f0, f1


def pairwise_cost(f0, f1, norm: str = "l1", dtype=np.float64) -> np.ndarray:
    """``(n0, n1)`` unnormalized ``sum_d |f0 - f1|`` (l1) or ``sum_d (f0 - f1)^2`` (l2)."""
    f0, f1 = _check_pair(f0, f1)
    check_choice(norm, NORMS, "norm")
    if norm == "l2":
        c = (f0**2).sum(1)[:, None] + (f1**2).sum(1)[None, :] - 2.0 * f0 @ f1.T
        return np.maximum(c, 0.0).astype(dtype, copy=False)
    out = np.empty((len(f0), len(f1)), dtype=dtype)
    a, b = np.ascontiguousarray(f0), np.ascontiguousarray(f1)
    run_blocks(lambda rows: _l1_rows(a[rows], b, out[rows]), len(a), 64)
    return out


@cached_njit(nogil=True)
def _l1_rows(a, b, out):  # pragma: no cover - compiled
    # Rows of a against rows of b: the inner sum runs along contiguous memory (SIMD).
    for i in range(a.shape[0]):
        for j in range(b.shape[0]):
            s = 0.0
            for d in range(a.shape[1]):
                s += abs(a[i, d] - b[j, d])
            out[i, j] = s


def mean_cost(f0, f1, areas0, areas1, norm: str = "l1") -> float:
    r"""Exact :math:`\bar c = \sum_{x,y} a_0(x) a(y) c(x, y) / (\sum a_0 \sum a)`.

    L1 splits by dimension into 1-D sums :math:`\sum_{x,y} a_0(x) a(y) |u_x - v_y|`, each
    from the sorted ``v`` and cumulative sums (:math:`O(n \log n)`); squared L2 from the
    weighted means and centered second moments.  No pairwise matrix is formed.
    """
    w0 = areas0 / areas0.sum()
    w1 = areas1 / areas1.sum()
    if norm == "l2":
        # Centered moments (no cancellation): E|f0 - f1|^2 = var0 + var1 + |m0 - m1|^2.
        m0, m1 = w0 @ f0, w1 @ f1
        return float(w0 @ ((f0 - m0) ** 2).sum(1) + w1 @ ((f1 - m1) ** 2).sum(1)
                     + ((m0 - m1) ** 2).sum())
    total = 0.0
    for d in range(f0.shape[1]):
        order = np.argsort(f1[:, d])
        v, wv = f1[order, d], w1[order]
        below_w = np.r_[0.0, np.cumsum(wv)]  # weight of v[:k]
        below_s = np.r_[0.0, np.cumsum(wv * v)]
        u = f0[:, d]
        k = np.searchsorted(v, u)
        # sum_y w(y)|u - v_y| = u (W_below - W_above) - (S_below - S_above)
        per_x = u * (2.0 * below_w[k] - below_w[-1]) - (2.0 * below_s[k] - below_s[-1])
        total += float(w0 @ per_x)
    return total


def compatibility_cost(f0, f1, *, areas0, areas1, rows=None, columns=None, norm: str = "l1",
                       dtype=np.float64) -> np.ndarray:
    r"""Normalized compatibility cost :math:`c(x, y) / \bar c` (mean 1 over :math:`M_0 \times M`).

    :math:`c(x, y) = \|f_0(x) - f_1(y)\|_1` (the thesis' choice) or the squared L2
    distance, divided by :math:`\bar c = \sum_{x, y} a_0(x)\, a(y)\, c(x, y)`.

    Parameters
    ----------
    f0 : (n0, d) array
        Source descriptors.
    f1 : (n1, d) array
        Target descriptors.
    areas0 : (n0,) array
        Source vertex areas.
    areas1 : (n1,) array
        Target vertex areas.
    rows : (r,) int array, optional
        Source vertices to return (the mean is still over all of :math:`M_0`).
    columns : (m, d) array, optional
        Target descriptors where the cost is evaluated instead of ``f1`` (e.g. at the points
        of a coarse target; the mean is still over :math:`M`).
    norm : {"l1", "l2"}
        L1 distance, or squared L2 distance.
    dtype : dtype
        Output dtype.

    Returns
    -------
    (len(rows) or n0, len(columns) or n1) array
    """
    f0, f1 = _check_pair(f0, f1)
    a0 = np.asarray(areas0, dtype=np.float64)
    a1 = np.asarray(areas1, dtype=np.float64)
    if a0.shape != (len(f0),) or a1.shape != (len(f1),):
        raise InputError("areas must have one entry per descriptor row", field="areas")
    check_choice(norm, NORMS, "norm")
    mean = mean_cost(f0, f1, a0, a1, norm)
    if not mean > 0:
        raise InputError("descriptors do not distinguish any pair of points",
                         field="descriptors")
    at = f1 if columns is None else _check_descriptors(columns, "columns")
    c = pairwise_cost(f0 if rows is None else f0[np.asarray(rows)], at, norm, dtype)
    c /= mean
    return c
