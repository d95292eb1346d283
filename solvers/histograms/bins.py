r"""Bins of the value axis and validation of histograms over them.

A :class:`Bins` is ``B + 1`` strictly increasing edges :math:`e_0 < \dots < e_B`; bin
``j`` is :math:`[e_j, e_{j+1})`.  A histogram is ``B`` non-negative masses; within a bin
its density is taken constant (mass / width), so its CDF is piecewise linear.  With
``periodic=True`` the axis is a circle of period :math:`e_B - e_0` (angles, §5.4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from solvers.errors import InputError
from solvers.validation import check_finite, check_int


@dataclass(frozen=True, eq=False)
class Bins:
    """Bins of a 1-D value axis (§5.5), or of the circle.

    Parameters
    ----------
    edges : (B + 1,) array
        Strictly increasing bin edges.
    periodic : bool
        The axis is a circle (``edges[-1]`` wraps to ``edges[0]``).
    """

    edges: np.ndarray
    periodic: bool = False

    @property
    def count(self) -> int:
        return len(self.edges) - 1

    @property
    def lo(self) -> float:
        return float(self.edges[0])

    @property
    def hi(self) -> float:
        return float(self.edges[-1])

    @property
    def widths(self) -> np.ndarray:
        return np.diff(self.edges)

    @property
    def centers(self) -> np.ndarray:
        return 0.5 * (self.edges[:-1] + self.edges[1:])

    @property
    def period(self) -> float:
        return self.hi - self.lo

    def to_dict(self) -> dict:
        return {"edges": self.edges.tolist(), "periodic": bool(self.periodic)}


def make_bins(edges=None, *, lo=None, hi=None, count=None, periodic: bool = False,
              field: str = "bins") -> Bins:
    """Validated bins from ``edges`` or from ``lo``, ``hi`` and ``count`` (equal widths).

    Parameters
    ----------
    edges : (B + 1,) array, optional
        Strictly increasing edges; else give ``lo``, ``hi`` and ``count``.
    lo, hi : float, optional
        Ends of the axis.
    count : int, optional
        Number of bins ``B``.
    periodic : bool
        The axis is a circle.
    field : str
        Input name: ``InputError`` names ``field.edges``, ``field.lo``, ``field.hi`` or
        ``field.count``.

    Returns
    -------
    Bins
    """
    if isinstance(edges, Bins):
        return edges
    if edges is not None:
        if lo is not None or hi is not None or count is not None:
            raise InputError(f"give either {field}.edges or {field}.lo/hi/count, not both",
                             field=f"{field}.edges")
        try:
            e = np.asarray(edges, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{field}.edges must be numbers", field=f"{field}.edges") from exc
        if e.ndim != 1 or len(e) < 2:
            raise InputError(f"{field}.edges needs at least 2 values (one bin), got shape "
                             f"{e.shape}", field=f"{field}.edges")
        if not np.all(np.isfinite(e)):
            bad = int(np.flatnonzero(~np.isfinite(e))[0])
            raise InputError(f"{field}.edges[{bad}] is NaN or infinite", field=f"{field}.edges")
        steps = np.diff(e)
        if np.any(steps <= 0):
            bad = int(np.flatnonzero(steps <= 0)[0])
            raise InputError(f"{field}.edges must be strictly increasing: edges[{bad + 1}] = "
                             f"{e[bad + 1]:g} <= edges[{bad}] = {e[bad]:g}",
                             field=f"{field}.edges")
        return Bins(e, bool(periodic))
    if lo is None or hi is None or count is None:
        missing = next(n for n, v in (("lo", lo), ("hi", hi), ("count", count)) if v is None)
        raise InputError(f"{field} needs edges, or lo, hi and count ({field}.{missing} is "
                         "missing)", field=f"{field}.{missing}")
    lo = check_finite(lo, f"{field}.lo")
    hi = check_finite(hi, f"{field}.hi")
    count = check_int(count, f"{field}.count", low=1, high=100_000)
    if not hi > lo:
        raise InputError(f"{field}.hi ({hi:g}) must be greater than {field}.lo ({lo:g})",
                         field=f"{field}.hi")
    if not math.isfinite((hi - lo) / count) or (hi - lo) / count <= 0:
        raise InputError(f"{field}: bins of width (hi - lo) / count must be positive",
                         field=f"{field}.count")
    return Bins(np.linspace(lo, hi, count + 1), bool(periodic))


def check_histograms(values, n_bins: int, field: str = "histograms") -> np.ndarray:
    """Validate ``k`` histograms: finite, non-negative, each with positive mass; normalize them.

    A single ``(B,)`` histogram is accepted as ``k = 1`` (errors then name ``field``);
    otherwise ``InputError`` names ``field[i]``, the offending histogram.

    Parameters
    ----------
    values : (k, B) or (B,) array
        Histograms.
    n_bins : int
        Expected number of bins ``B``.
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised.

    Returns
    -------
    (k, B) array
        Rows summing to 1.
    """
    try:
        h = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{field} must be numbers", field=field) from exc
    single = h.ndim == 1
    if single:
        h = h[None, :]

    def name(i: int) -> str:  # a single histogram is named by the field itself
        return field if single else f"{field}[{i}]"

    if h.ndim != 2 or h.shape[1] != n_bins:
        raise InputError(f"{field} must have one value per bin ({n_bins}), got shape "
                         f"{np.shape(values)}", field=field)
    if not np.all(np.isfinite(h)):
        i, j = (int(v) for v in np.argwhere(~np.isfinite(h))[0])
        raise InputError(f"{name(i)}[{j}] is NaN or infinite", field=name(i))
    if np.any(h < 0):
        i, j = (int(v) for v in np.argwhere(h < 0)[0])
        raise InputError(f"{name(i)}[{j}] is negative ({h[i, j]:g})", field=name(i))
    mass = h.sum(axis=1)
    if np.any(mass <= 0):
        i = int(np.flatnonzero(mass <= 0)[0])
        raise InputError(f"{name(i)} has zero total mass", field=name(i))
    return h / mass[:, None]


def check_samples(values, bins: Bins | None = None, field: str = "samples") -> np.ndarray:
    """One node's samples ``(N,)``: finite, at least one, inside the bins' range if given."""
    try:
        x = np.asarray(values, dtype=np.float64).ravel()
    except (TypeError, ValueError) as exc:
        raise InputError(f"{field} must be numbers", field=field) from exc
    if x.size == 0:
        raise InputError(f"{field} needs at least one sample", field=field)
    if not np.all(np.isfinite(x)):
        bad = int(np.flatnonzero(~np.isfinite(x))[0])
        raise InputError(f"{field}[{bad}] is NaN or infinite", field=field)
    if bins is not None and not bins.periodic:
        out = np.flatnonzero((x < bins.lo) | (x > bins.hi))
        if len(out):
            raise InputError(f"{field}[{int(out[0])}] = {x[out[0]]:g} lies outside the bins "
                             f"[{bins.lo:g}, {bins.hi:g}]", field=field)
    return x


def histogram_of_samples(samples: np.ndarray, bins: Bins) -> np.ndarray:
    """Normalized histogram of samples (periodic bins wrap samples into range).

    Parameters
    ----------
    samples : (N,) array
        Values on the axis.
    bins : Bins
        The bins.

    Returns
    -------
    (B,) array
        Masses summing to 1.
    """
    x = np.asarray(samples, dtype=np.float64)
    if bins.periodic:
        x = bins.lo + np.mod(x - bins.lo, bins.period)
    idx = np.clip(np.searchsorted(bins.edges, x, side="right") - 1, 0, bins.count - 1)
    h = np.bincount(idx, minlength=bins.count).astype(np.float64)
    return h / h.sum()
