r"""Pull functions and colors from the target back to the source through a soft map.

For a function :math:`g` on the target, :math:`(\mu^* g)(x) = \int_M g(y)\, d\mu_x(y)`:
with rows of target masses ``P`` (``N × n``, rows summing to 1) this is ``P @ g`` on the
source nodes, then spread to every source vertex through the cells (``labels``).
"""

from __future__ import annotations

import numpy as np

from solvers.errors import InputError


def pull_back(rows, values, labels=None) -> np.ndarray:
    """Pull target values back to the source: their expectation under each distribution.

    Parameters
    ----------
    rows : (N, n) array
        Target masses per source node (dense).
    values : (n,) or (n, c) array
        Target values (e.g. RGB colors).
    labels : (n_source,) int array, optional
        Node of each source vertex (default: rows are vertices).

    Returns
    -------
    (n_source,) or (n_source, c) array
    """
    P = np.asarray(rows)
    g = np.asarray(values, dtype=np.float64)
    if g.shape[0] != P.shape[1]:
        raise InputError(f"values must have one entry per target vertex ({P.shape[1]})",
                         field="values")
    totals = np.asarray(P.sum(axis=1), np.float64)
    out = (P @ g.astype(P.dtype)).astype(np.float64)
    out /= np.maximum(totals, 1e-300).reshape((-1,) + (1,) * (g.ndim - 1))
    return out if labels is None else out[np.asarray(labels, np.int64)]


def pull_back_top_k(indices, masses, values, labels=None) -> np.ndarray:
    """:func:`pull_back` for a top-k soft map (``indices``/``masses`` ``(N, k)``), renormalized."""
    g = np.asarray(values, dtype=np.float64)
    m = np.asarray(masses, np.float64)
    vals = g[np.asarray(indices)]
    w = m / np.maximum(m.sum(axis=1, keepdims=True), 1e-300)
    out = np.einsum("ik,ik...->i...", w, vals)
    return out if labels is None else out[np.asarray(labels, np.int64)]


def coordinate_colors(target) -> np.ndarray:
    """``(n, 3)`` RGB in ``[0, 1]`` from the target's vertex positions (for visual transfer)."""
    v = np.asarray(target.vertices, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    return (v - lo) / np.maximum(hi - lo, 1e-12)
