r"""Shared machinery of the convolutional solvers (thesis ch. 3).

* :class:`LogKernel` evaluates :math:`\log H_t \exp(X)` column by column for any heat
  kernel, so every Sinkhorn-type loop can keep its scalings as logarithms
  (potentials) and never overflows at small :math:`\gamma`.
* :func:`prepare` validates the common arguments and builds (or fetches the cached)
  kernel; :class:`Monitor` runs the progress callback and the cancellation check.
* :class:`OverRelaxation` picks the over-relaxation parameter of the Sinkhorn
  updates from the measured convergence rate.

Conventions: inputs are *masses* ``m`` (non-negative, columns summing to 1); the
iterations work with densities :math:`\mu = m / a` (``a`` the area weights) as in
the thesis, and ``kernel.apply(x)`` is :math:`H_t(a \otimes x)`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from solvers.errors import InputError
from solvers.kernels import heat_time
from solvers.linalg import Backend
from solvers.monitor import Monitor
from solvers.regularization import kernel_substeps
from solvers.validation import check_choice, check_gamma, check_positive

# Width (in natural-log units) of one band of a log-domain kernel application for
# kernels whose smallest entry is unknown (implicit Euler): entries of the
# shifted input down to exp(-BAND) are applied exactly; wider inputs are split
# into several bands (extra columns of the same block solve).
DEFAULT_BAND = 350.0
MAX_BANDS = 32  # bands per column in LogKernel._banded (values further down underflow)
# exp() of anything below this is 0 or denormal in float64.
_LOG_TINY = -700.0
# Output logs this far below the column maximum are treated as "underflowed".
_UNDERFLOW_GAP = 1400.0


class LogKernel:
    r"""``X -> log H_t exp(X)`` for ``(n,)`` or ``(n, k)`` log-inputs (``-inf`` allowed).

    This is the absorption of the scalings into the kernel's input and output:
    each column is shifted by its maximum (absorbed exactly into the output), and
    columns whose dynamic range exceeds one band are split by value into bands,
    each applied with its own shift in the same block solve and recombined with a
    log-sum-exp.  Implicit Euler heat kernels :math:`(D_a + \tau L)^{-1} D_a` of
    M-matrices (robust/intrinsic-Delaunay Laplacians, graph Laplacians) are
    entrywise positive and their triangular solves add terms of one sign, so each
    band is computed to full relative precision; the only loss is underflow of
    kernel entries below ``exp(-700)`` relative to the band.  Kernels with an exact
    ``kernel.log_apply`` (Gaussian grids) use it instead, unless a ``band`` is given.
    """

    def __init__(self, kernel, band: float | None = None):
        self.kernel = kernel
        self.n = int(kernel.n)
        # Kernels with an exact log-domain form (Gaussian grids) use it: as fast as
        # apply() after banding and exact at every t (bench/results/convolutional.md).
        self.use_log_apply = bool(getattr(kernel, "supports_log", False)) and band is None
        if band is None:
            band = DEFAULT_BAND
            log_factors = getattr(kernel, "log_factors", None)
            if log_factors is not None:
                # Separable Gaussian: smallest log-entry of the full kernel is known.
                kmin = float(sum(np.min(f) for f in log_factors))
                band = max(-_LOG_TINY + kmin, 50.0)
        self.band = float(band)
        self.applications = 0
        self.columns = 0

    def __call__(self, X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=np.float64)
        vector = X.ndim == 1
        X2 = X[:, None] if vector else X
        k = X2.shape[1]
        self.applications += 1
        if self.use_log_apply:
            self.columns += k
            out = np.asarray(self.kernel.log_apply(X2), dtype=np.float64).reshape(self.n, k)
            return floor_underflow(out[:, 0] if vector else out)
        top = np.max(X2, axis=0)  # -inf entries are fine; all -inf -> empty column
        bottom = np.min(X2, axis=0)
        if not np.all(np.isfinite(bottom)):
            bottom = np.min(X2, axis=0, where=np.isfinite(X2), initial=np.inf)
        empty = ~np.isfinite(top)
        if np.any(empty):
            top = np.where(empty, 0.0, top)
            bottom = np.where(empty, 0.0, bottom)
        bands = np.maximum(1, np.ceil((top - bottom) / self.band).astype(np.int64))
        if np.all(bands == 1):
            self.columns += k
            Y = X2 - top
            with np.errstate(under="ignore"):
                np.exp(Y, out=Y)
            Z = self.kernel.apply(Y if not vector else Y[:, 0])
            out = np.asarray(Z, dtype=np.float64).reshape(self.n, k)  # fresh array
            np.maximum(out, 0.0, out=out)
            with np.errstate(divide="ignore"):
                np.log(out, out=out)
            out += top
        else:
            out = self._banded(X2, top, bands)
        return floor_underflow(out[:, 0] if vector else out)

    def _banded(self, X2, top, bands):
        # Only occupied bands get a column, and at most MAX_BANDS per input column (the
        # last one takes everything below; what lies more than MAX_BANDS bands under the
        # top underflows): the work stays bounded whatever the dynamic range (an entropy
        # bound that sharpens to huge exponents no longer builds a block of ~range/band
        # columns per call).
        n, k = X2.shape
        levels = []
        for j in range(k):
            x = X2[:, j]
            rows = np.flatnonzero(np.isfinite(x))
            level = np.minimum((top[j] - x[rows]) // self.band, MAX_BANDS - 1).astype(np.int64)
            levels.append((rows, level, np.unique(level)))
        total = sum(len(used) for _, _, used in levels)
        self.columns += total
        block = np.zeros((n, total))
        offsets = np.empty(total)
        owner = np.empty(total, dtype=np.int64)
        col = 0
        for j, (rows, level, used) in enumerate(levels):
            x = X2[:, j]
            for b in used:
                hi = top[j] - b * self.band
                sel = rows[level == b]
                with np.errstate(under="ignore"):
                    block[sel, col] = np.exp(x[sel] - hi)
                offsets[col] = hi
                owner[col] = j
                col += 1
        Z = np.asarray(self.kernel.apply(block), dtype=np.float64).reshape(n, total)
        with np.errstate(divide="ignore"):
            logs = np.log(np.maximum(Z, 0.0)) + offsets
        out = np.empty((n, k))
        for j in range(k):
            part = logs[:, owner == j]
            m = np.max(part, axis=1)
            safe = np.where(np.isfinite(m), m, 0.0)
            with np.errstate(divide="ignore", under="ignore"):
                out[:, j] = np.log(np.exp(part - safe[:, None]).sum(axis=1)) + safe
        return out


def floor_underflow(out: np.ndarray) -> np.ndarray:
    """Replace underflowed (``-inf``) outputs by a finite floor far below the column maximum.

    A zero output where a density is positive would make the next scaling
    infinite; the floor keeps every quantity finite (the marginal residual then
    reports the violation honestly).
    """
    if np.all(np.isfinite(out)):
        return out
    top = np.max(np.where(np.isfinite(out), out, -np.inf), axis=0)
    top = np.where(np.isfinite(top), top, 0.0)
    return np.where(np.isfinite(out), out, top - _UNDERFLOW_GAP)


class OverRelaxation:
    r"""Adaptive over-relaxed Sinkhorn updates ``f <- f + omega (f_sinkhorn - f)``.

    Starts with plain Sinkhorn (``omega = 1``).  After each change of ``omega``
    the iteration is left to settle for one ``window``; then the residual decay
    ``lam`` measured over the next window gives an estimate of the plain Sinkhorn
    rate :math:`\eta = (\lambda + \omega - 1)^2 / (\lambda \omega^2)` (the
    successive over-relaxation relation), and ``omega`` moves up to the SOR optimum
    :math:`2 / (1 + \sqrt{1 - \eta})` (Thibault et al. 2017; Lehmann et al. 2021
    for the safeguard).  If the residual grows tenfold since the last change,
    ``omega`` backs off halfway to 1, so the iteration stays safe.
    ``enabled=False`` keeps plain Alg. 1.
    """

    def __init__(self, enabled: bool = True, window: int = 5, max_omega: float = 1.9,
                 stride: int = 1):
        self.enabled = enabled
        self.window = window
        self.stride = stride  # iterations between two calls of update()
        self.max_omega = max_omega
        self.omega = 1.0
        self._history: list[float] = []
        self._changed = 0

    def update(self, residual: float) -> float:
        if not self.enabled:
            return 1.0
        self._history.append(residual)
        k = len(self._history) - 1
        since = k - self._changed
        if since >= 2 and residual > 10.0 * self._history[self._changed] and self.omega > 1.0:
            self._set(1.0 + 0.5 * (self.omega - 1.0), k)
        elif since >= 2 * self.window and since % self.window == 0:
            old = self._history[k - self.window]
            lam = (residual / old) ** (1.0 / (self.window * self.stride)) if old > 0 else 0.0
            if 0.0 < lam < 1.0:
                om = self.omega
                eta = min((lam + om - 1.0) ** 2 / (lam * om * om), 0.9999)
                best = min(2.0 / (1.0 + math.sqrt(1.0 - eta)), self.max_omega)
                if best > self.omega + 0.01:
                    self._set(best, k)
        return self.omega

    def _set(self, omega: float, k: int) -> None:
        self.omega = omega
        self._changed = k


@dataclass
class Setup:
    """Validated common arguments of a convolutional solver."""

    gamma: float
    t: float
    substeps: int | None  # None with the geodesic kernel (it has no substeps)
    tol: float
    max_iter: int
    kernel: object
    logk: LogKernel
    areas: np.ndarray
    monitor: Monitor
    method: str = "convolutional"


# Sinkhorn accelerations (same fixed point): Anderson mixing of the scaling map
# (distances), adaptive over-relaxation, or none (the thesis' plain iterations).
ACCELERATIONS = ("anderson", "over-relaxation", "none")
BARYCENTER_ACCELERATIONS = ("over-relaxation", "none")


def check_acceleration(value, allowed: tuple[str, ...]) -> str:
    """Validate the ``acceleration`` argument against the solver's supported choices."""
    return check_choice(value, allowed, "acceleration")


def prepare(domain, *, gamma, t, substeps, tol, max_iter, progress, should_cancel,
            default_max_iter: int = 10000, backend: Backend = "auto",
            method: str = "convolutional") -> Setup:
    """Check ``gamma, t, substeps, tol, max_iter`` and fetch the domain's kernel: the heat
    kernel (factored by ``backend``, :func:`solvers.linalg.factorize_spd`), or with
    ``method="geodesic"`` the Gibbs kernel of squared geodesics
    (:meth:`~solvers.domains.TriangleMesh.geodesic_kernel`)."""
    extent = getattr(domain, "extent", None)
    gamma = check_positive(gamma, "gamma") if extent is None else check_gamma(gamma, extent)
    t = heat_time(gamma) if t is None else check_positive(t, "t")
    try:
        substeps = int(substeps)
    except (TypeError, ValueError) as exc:
        raise InputError("substeps must be an integer", field="substeps") from exc
    if substeps < 1:
        raise InputError(f"substeps must be >= 1, got {substeps}", field="substeps")
    tol = check_positive(tol, "tol")
    max_iter = default_max_iter if max_iter is None else int(max_iter)
    if max_iter < 1:
        raise InputError(f"max_iter must be >= 1, got {max_iter}", field="max_iter")
    if progress is not None and not callable(progress):
        raise InputError("progress must be callable", field="progress")
    if should_cancel is not None and not callable(should_cancel):
        raise InputError("should_cancel must be callable", field="should_cancel")
    substeps = kernel_substeps(method, substeps)
    if substeps is None:
        kernel = domain.geodesic_kernel(t)
    else:
        kernel = domain.heat_kernel(t, substeps, backend)
    return Setup(gamma, t, substeps, tol, max_iter, kernel, LogKernel(kernel),
                 np.asarray(domain.areas, dtype=np.float64), Monitor(progress, should_cancel),
                 method)


def log_density(masses: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """``log(m / a)`` with ``-inf`` where the mass is zero."""
    a = areas if masses.ndim == 1 else areas[:, None]
    with np.errstate(divide="ignore"):
        return np.log(masses / a)


def entropy(masses: np.ndarray, areas: np.ndarray) -> np.ndarray | float:
    r"""Differential entropy :math:`H(\mu) = -\sum_i a_i \mu_i \log \mu_i` of ``m = a mu``.

    Zero for the uniform density on a unit-area domain, negative otherwise.
    """
    ld = log_density(masses, areas)
    terms = np.where(masses > 0, masses * np.where(np.isfinite(ld), ld, 0.0), 0.0)
    out = -terms.sum(axis=0)
    return float(out) if np.ndim(out) == 0 else out


def masses_from_log(log_density_values: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Masses ``a * exp(log mu)`` normalized per column (shifted to avoid overflow)."""
    L = log_density_values
    top = np.max(np.where(np.isfinite(L), L, -np.inf), axis=0)
    top = np.where(np.isfinite(top), top, 0.0)
    a = areas if L.ndim == 1 else areas[:, None]
    with np.errstate(under="ignore"):
        m = a * np.exp(L - top)
    total = m.sum(axis=0)
    return m / np.where(total > 0, total, 1.0)
