r"""Descriptor soft map (§4.5.2): :math:`\rho(x, y) \propto \exp(-\|f_0(x) - f(y)\|^2/\sigma^2)`.

The baseline soft map and a starting point: each source point's distribution over the
target weighs target vertices by descriptor similarity.  With the normalized compatibility
cost ``c`` (:mod:`solvers.softmaps.compatibility`, ``norm="l2"`` for the squared distance of
the formula), the masses are :math:`\mu_x(y) \propto a(y) \exp(-c(x, y)/\sigma^2)`.
"""

from __future__ import annotations

import numpy as np

from solvers.softmaps.compatibility import compatibility_cost
from solvers.validation import check_positive


def descriptor_soft_map(f0, f1, *, areas0, areas1, sigma: float = 0.1, rows=None,
                        norm: str = "l2") -> np.ndarray:
    r"""§4.5.2 descriptor soft map: :math:`\mu_x(y) \propto a(y)\, e^{-c(x, y)/\sigma^2}`.

    :math:`c` is the normalized :func:`compatibility_cost` (mean 1).

    Parameters
    ----------
    f0, f1, areas0, areas1 : array
        Descriptors ``(n0, d)``, ``(n1, d)`` and vertex areas, as in
        :func:`compatibility_cost`.
    sigma : float
        Width in units of the normalized cost (mean 1): :math:`\sigma^2 = ` ``sigma``.
    rows : (r,) int array, optional
        Source vertices to return.
    norm : {"l1", "l2"}
        L1, or squared L2, descriptor distance (:func:`compatibility_cost`).

    Returns
    -------
    (len(rows) or n0, n1) float32 array
        Masses, each row summing to 1.
    """
    sigma = check_positive(sigma, "sigma")
    c = compatibility_cost(f0, f1, areas0=areas0, areas1=areas1, rows=rows, norm=norm)
    c -= c.min(axis=1, keepdims=True)
    np.exp(-c / sigma, out=c)
    c *= np.asarray(areas1)[None, :]
    c /= c.sum(axis=1, keepdims=True)
    return c.astype(np.float32)
