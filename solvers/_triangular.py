"""Compiled triangular solves of :class:`solvers.linalg.TriangularFactor` (GIL released).

The factor is ``Pr A Pc = L U`` (SuperLU, symmetric mode, no pivoting); the right-hand
sides are a C-ordered ``(n, k)`` block, so each nonzero of ``L`` or ``U`` updates ``k``
contiguous values (vectorized) and the factor is read once per block.
"""

from __future__ import annotations

import numpy as np

from solvers.jit import cached_njit


@cached_njit(nogil=True)
def lu_solve_block(l_ptr, l_idx, l_val, u_ptr, u_idx, u_val, u_diag, perm_r, perm_c, b,
                   x):  # pragma: no cover - compiled
    """``x = Pc U^{-1} L^{-1} Pr b`` for ``b, x`` ``(n, k)``; ``L`` strictly lower (unit
    diagonal implied) and ``U`` strictly upper in CSC, ``u_diag`` the diagonal of ``U``."""
    n, k = b.shape
    y = np.empty((n, k))
    for i in range(n):
        y[perm_r[i], :] = b[i, :]
    for j in range(n):
        for p in range(l_ptr[j], l_ptr[j + 1]):
            i = l_idx[p]
            v = l_val[p]
            for c in range(k):
                y[i, c] -= v * y[j, c]
    for j in range(n - 1, -1, -1):
        d = 1.0 / u_diag[j]
        for c in range(k):
            y[j, c] *= d
        for p in range(u_ptr[j], u_ptr[j + 1]):
            i = u_idx[p]
            v = u_val[p]
            for c in range(k):
                y[i, c] -= v * y[j, c]
    for i in range(n):
        x[i, :] = y[perm_c[i], :]
