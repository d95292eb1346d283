r"""Validation and normalization of distributions on a domain.

Conventions used by every solver: a distribution is given either as
*masses* ``m`` (per point, summing to 1) or as a *density* ``mu`` with
respect to the area weights, ``m = a * mu`` and :math:`a^\top \mu = 1`.
"""

from __future__ import annotations

import numpy as np

from solvers.errors import InputError


def check_masses(values, n: int, field: str = "masses") -> np.ndarray:
    """Return ``values`` as a float ``(n,)`` or ``(n, k)`` array; finite, non-negative, non-zero.

    Raises ``InputError`` naming ``field`` otherwise.
    """
    try:
        x = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{field} must be numeric: {exc}", field=field) from exc
    if x.ndim not in (1, 2) or x.shape[0] != n:
        raise InputError(f"{field} must have length {n} (one value per point), got shape "
                         f"{x.shape}", field=field)
    if not np.all(np.isfinite(x)):
        bad = int(np.argwhere(~np.isfinite(x))[0, 0])
        raise InputError(f"{field}[{bad}] is NaN or infinite", field=field)
    if np.any(x < 0):
        bad = int(np.argwhere(x < 0)[0, 0])
        raise InputError(f"{field}[{bad}] is negative ({x.flat[np.argmax(x < 0)]:g})",
                         field=field)
    totals = x.sum(axis=0)
    if np.any(totals <= 0):
        raise InputError(f"{field} has zero total mass", field=field)
    return x


def normalize_masses(values, n: int, field: str = "masses") -> np.ndarray:
    """Validated masses rescaled to sum to 1 (per column)."""
    x = check_masses(values, n, field)
    return x / x.sum(axis=0)


def density_from_masses(masses: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Density ``mu = m / a`` (per column), so that ``a @ mu == m.sum()``."""
    a = areas if masses.ndim == 1 else areas[:, None]
    return masses / a


def masses_from_density(density: np.ndarray, areas: np.ndarray) -> np.ndarray:
    a = areas if density.ndim == 1 else areas[:, None]
    return density * a
