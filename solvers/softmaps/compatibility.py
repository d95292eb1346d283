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

NORMS = ("l1", "l2")


def _check_descriptors(f, name: str) -> np.ndarray:
    x = np.asarray(f, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or not np.all(np.isfinite(x)):
        raise InputError(f"{name} must be a finite (n, d) array", field=name)
    return x


def pairwise_cost(f0, f1, norm: str = "l1", dtype=np.float64) -> np.ndarray:
    """``(n0, n1)`` unnormalized ``sum_d |f0 - f1|`` (l1) or ``sum_d (f0 - f1)^2`` (l2)."""
    f0 = _check_descriptors(f0, "f0")
    f1 = _check_descriptors(f1, "f1")
    if f0.shape[1] != f1.shape[1]:
        raise InputError(f"descriptor dimensions differ: {f0.shape[1]} vs {f1.shape[1]}",
                         field="descriptors")
    if norm not in NORMS:
        raise InputError(f"norm must be one of {NORMS}, got {norm!r}", field="norm")
    if norm == "l2":
        c = (f0**2).sum(1)[:, None] + (f1**2).sum(1)[None, :] - 2.0 * f0 @ f1.T
        return np.maximum(c, 0.0).astype(dtype, copy=False)
    out = np.zeros((len(f0), len(f1)), dtype=dtype)
    a, b = f0.astype(dtype), f1.astype(dtype)
    tmp = np.empty_like(out)
    for d in range(f0.shape[1]):
        np.subtract(a[:, d:d + 1], b[None, :, d], out=tmp)
        np.abs(tmp, out=tmp)
        out += tmp
    return out


def compatibility_cost(f0, f1, *, areas0, areas1, rows=None, norm: str = "l1",
                       dtype=np.float64) -> np.ndarray:
    r"""Normalized cost :math:`c(x, y) / \bar c` (mean 1 over :math:`M_0 \times M`).

    ``f0`` ``(n0, d)`` source descriptors, ``f1`` ``(n1, d)`` target descriptors, ``areas0``
    and ``areas1`` their vertex areas; ``rows``: optional source vertices to return (the
    mean is still over all of :math:`M_0`).  Returns ``(len(rows) or n0, n1)``.
    """
    f0 = _check_descriptors(f0, "f0")
    a0 = np.asarray(areas0, dtype=np.float64)
    a1 = np.asarray(areas1, dtype=np.float64)
    if a0.shape != (len(f0),) or a1.shape != (len(np.atleast_2d(f1.T).T),):
        raise InputError("areas must have one entry per descriptor row", field="areas")
    # The mean over M0 x M: exact up to 2,048 source rows, else from 2,048 evenly spaced
    # rows (area-weighted); 256 rows at a time so the temporaries stay small.
    if len(f0) > 2048:
        pick = np.linspace(0, len(f0) - 1, 2048).astype(np.int64)
    else:
        pick = np.arange(len(f0))
    w = a0[pick] / a0[pick].sum()
    mean = sum(float(w[s:s + 256] @ pairwise_cost(f0[pick[s:s + 256]], f1, norm) @ a1)
               for s in range(0, len(pick), 256)) / float(a1.sum())
    if not mean > 0:
        raise InputError("descriptors do not distinguish any pair of points",
                         field="descriptors")
    c = pairwise_cost(f0 if rows is None else f0[np.asarray(rows)], f1, norm, dtype)
    c /= mean
    return c
