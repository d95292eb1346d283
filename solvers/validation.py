r"""The only validators of solver inputs: distributions, weights, scalars, graph edges.

The library's solvers and the service's submission checks call these same functions, so a
request accepted at the door passes the worker's checks too. Each raises
:class:`~solvers.errors.InputError` naming the offending ``field``.

Conventions used by every solver: a distribution is given either as
*masses* ``m`` (per point, summing to 1) or as a *density* ``mu`` with
respect to the area weights, ``m = a * mu`` and :math:`a^\top \mu = 1`.
"""

from __future__ import annotations

import math

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


def check_weights(weights, k: int, field: str = "weights") -> np.ndarray:
    """Barycentric weights: ``(k,)`` finite, non-negative, positive sum; normalized to 1.

    ``None`` gives uniform weights.
    """
    if weights is None:
        return np.full(k, 1.0 / k)
    try:
        w = np.asarray(weights, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{field} must be numbers", field=field) from exc
    if w.shape != (k,):
        raise InputError(f"{field} must have one value per distribution ({k}), got shape "
                         f"{w.shape}", field=field)
    if not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise InputError(f"{field} must be finite, non-negative, with a positive sum",
                         field=field)
    return w / w.sum()


def check_positive(value, field: str) -> float:
    """A finite number > 0."""
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be a number", field=field) from exc
    if not (math.isfinite(x) and x > 0):
        raise InputError(f"{field} must be positive and finite, got {value}", field=field)
    return x


def check_finite(value, field: str) -> float:
    """A finite number (any sign)."""
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be a number", field=field) from exc
    if not math.isfinite(x):
        raise InputError(f"{field} must be finite, got {value}", field=field)
    return x


def check_int(value, field: str, *, low: int | None = None, high: int | None = None) -> int:
    """An integer in ``[low, high]`` (bounds optional)."""
    if isinstance(value, bool):
        raise InputError(f"{field} must be an integer", field=field)
    try:
        x = int(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be an integer", field=field) from exc
    if x != value:
        raise InputError(f"{field} must be an integer, got {value}", field=field)
    if low is not None and x < low:
        raise InputError(f"{field} must be >= {low}, got {x}", field=field)
    if high is not None and x > high:
        raise InputError(f"{field} must be <= {high}, got {x}", field=field)
    return x


def check_edges(edges, n: int, field: str = "edges") -> np.ndarray:
    """``(m, 2)`` int64 node pairs with endpoints in ``[0, n)`` and no self-loops.

    Values beyond int64 or non-integers are refused before any conversion can overflow.
    """
    try:
        e = np.asarray(edges if len(edges) else np.zeros((0, 2)), dtype=object)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{field} must be a list of node pairs", field=field) from exc
    if e.ndim != 2 or e.shape[1] != 2:
        raise InputError(f"{field} must be a list of node pairs (m, 2), got shape {e.shape}",
                         field=field)
    for i, v in enumerate(e.ravel()):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 0 <= v < n:
            raise InputError(f"{field}[{i // 2}] has endpoint {v!r}, outside [0, {n - 1}]",
                             field=field)
    out = e.astype(np.int64)
    loops = np.flatnonzero(out[:, 0] == out[:, 1])
    if len(loops):
        raise InputError(f"{field}[{int(loops[0])}] is a self-loop", field=field)
    return out


def check_edge_weights(weights, m: int, field: str = "edge_weights") -> np.ndarray:
    """``(m,)`` positive finite weights, one per edge (``None``: all ones)."""
    if weights is None:
        return np.ones(m)
    try:
        w = np.asarray(weights, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be numbers", field=field) from exc
    if w.shape != (m,):
        raise InputError(f"{field} must have one value per edge ({m}), got shape {w.shape}",
                         field=field)
    bad = np.flatnonzero(~(np.isfinite(w) & (w > 0)))
    if len(bad):
        raise InputError(f"{field}[{int(bad[0])}] must be positive and finite, got "
                         f"{w[bad[0]]:g}", field=field)
    return w
