r"""Convolutional Wasserstein distance (thesis Alg. 1, eq. 3.10) and Sinkhorn divergence.

With the heat kernel :math:`H_t \approx \exp(-d^2/\gamma)` (``t = heat_time(gamma)``
:math:`= \gamma/4`), the entropic transport problem

.. math::  W^2_{2,H_t}(\mu_0,\mu_1) = \min_{\pi \in \Pi(\mu_0,\mu_1)}
           \textstyle\int\!\!\int d^2\, d\pi \;-\; \gamma H(\pi)

has the plan :math:`\pi = D_v D_a H_t D_a D_w` with scalings found by Sinkhorn,
:math:`v \leftarrow \mu_0 / H_t(a \otimes w)`, :math:`w \leftarrow \mu_1 / H_t(a \otimes v)`,
and value :math:`\gamma\, a^\top[\mu_0 \otimes \ln v + \mu_1 \otimes \ln w]` (eq. 3.10; the
thesis writes :math:`2t` for :math:`\gamma` because its kernel is
:math:`\exp(-d^2/2\gamma)`, i.e. the cost :math:`d^2/2`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from solvers.convolutional.common import (
    ACCELERATIONS,
    LogKernel,
    Monitor,
    OverRelaxation,
    check_acceleration,
    log_density,
    prepare,
)
from solvers.monitor import SolverResult
from solvers.regularization import Regularization
from solvers.transport.decision import DistanceDecision, decide_distance
from solvers.transport.exact import ExactTransportResult, exact_wasserstein_distance
from solvers.validation import check_components, distribution_pair

# Window (iterations) over which the convolutional solvers measure their convergence rate:
# they stop as stalled (converged=False with the measured residual) when the best residual
# has not fallen by 0.1 % over a window, or when at the rate of the last window ``tol``
# would not be reached within ``max_iter``.
STALL_PATIENCE = 200


def watch_stagnation(setup, project: bool = True) -> Monitor:
    """The stagnation-watching monitor of a prepared convolutional solve (patience
    ``STALL_PATIENCE``).  ``project``: also stop when ``tol`` is out of reach within
    ``max_iter`` at the measured rate (used with the default cap; an explicit ``max_iter``
    runs until the residual stops falling)."""
    old = setup.monitor
    mon = Monitor(old.progress, old.should_cancel, tol=setup.tol, patience=STALL_PATIENCE,
                  max_iter=setup.max_iter, project=project)
    mon.offset = old.offset
    return mon


@dataclass
class SinkhornResult(SolverResult):
    r"""Result of :func:`wasserstein_distance`.

    Attributes
    ----------
    value : float
        The (debiased, if asked) regularized squared distance.
    v, w : (n,) array
        Plan scalings (densities); may overflow to ``inf`` at small ``gamma``.
    log_v, log_w : (n,) array
        Their logarithms (use those at small ``gamma``).
    omega : float
        The over-relaxation factor at the end (1: plain Sinkhorn steps).
    self_values : tuple of float or None
        With ``debiased``: the values of :math:`(\mu_0, \mu_0)` and :math:`(\mu_1, \mu_1)`.
    debiased : bool
        Whether ``value`` is the Sinkhorn divergence.
    decision : DistanceDecision or None
        The method and parameters decided by ``method="auto"``.
    gamma, t, substeps : float, float, int
        The regularization used: :math:`\gamma`, the heat time :math:`t` and its implicit
        Euler steps.
    regularization : Regularization or None
        The policy's choice, when ``gamma="auto"`` (:mod:`solvers.regularization`).
    method : str
        The kernel used (``"convolutional"``: heat kernel; ``"geodesic"``, ...).
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
        ``residual``: L1 marginal violation :math:`\|a \otimes v \otimes H(a\otimes w) -
        m_0\|_1 + \|a \otimes w \otimes H(a \otimes v) - m_1\|_1` in mass units.
    """

    value: float
    v: np.ndarray
    w: np.ndarray
    log_v: np.ndarray = field(repr=False, default=None)
    log_w: np.ndarray = field(repr=False, default=None)
    gamma: float = 0.0
    t: float = 0.0
    omega: float = 1.0
    self_values: tuple[float, float] | None = None
    substeps: int = 1
    debiased: bool = False
    method: str = "convolutional"
    regularization: Regularization | None = None
    decision: DistanceDecision | None = None


def sinkhorn_steps(areas, m0, m1, *, tol, max_iter, monitor: Monitor,
                   acceleration: str = "anderson", init=None):
    r"""Log-domain Sinkhorn (Alg. 1) as a step generator (:func:`run_steps`).

    ``acceleration``: ``"anderson"`` (default, :func:`anderson_steps`),
    ``"over-relaxation"`` (adaptive SOR, :class:`OverRelaxation`) or ``"none"``
    (plain Alg. 1).  All three have the same fixed point.

    Returns ``(f, g, iterations, residual, converged, omega)`` with ``f = log v``,
    ``g = log w`` (``-inf`` where the mass is zero).
    """
    l0, l1 = log_density(m0, areas), log_density(m1, areas)
    s0, s1 = m0 > 0, m1 > 0
    if init is None:
        f = np.where(s0, 0.0, -np.inf)
    else:
        f = np.where(s0, init[0], -np.inf)
    if acceleration == "anderson":
        return (yield from anderson_steps(areas, m0, l0, l1, f, tol=tol, max_iter=max_iter,
                                          monitor=monitor))
    g = np.where(s1, 0.0 if init is None else init[1], -np.inf)
    # Full supports (the common case) update whole arrays, without gathers/scatters.
    s0 = slice(None) if s0.all() else s0
    s1 = slice(None) if s1.all() else s1
    sor = OverRelaxation(enabled=acceleration == "over-relaxation")
    lg = yield g
    res2 = 0.0
    residual = np.inf
    it = 0
    while True:
        # Marginal violations from the kernel outputs already at hand (no extra
        # application): after the g update the second marginal is exact unless relaxed.
        res1 = _l1_gap(m0, areas, f, lg)
        residual = res1 + res2
        monitor(it, residual)
        if residual <= tol or it >= max_iter or not np.isfinite(residual) \
                or monitor.stalled:
            break
        omega = sor.update(residual)
        f[s0] += omega * (l0[s0] - lg[s0] - f[s0])
        lf = yield f
        g[s1] += omega * (l1[s1] - lf[s1] - g[s1])
        res2 = _l1_gap(m1, areas, g, lf) if omega != 1.0 else 0.0
        lg = yield g
        it += 1
    return f, g, it, residual, bool(residual <= tol), sor.omega


# Anderson memory (past iterates combined per step; measured on the shared meshes:
# 20 halves the iterations of 8 at t = h^2 and costs ~1 ms per step at 50k vertices)
# and the residual growth, relative to the best so far, at which the history is dropped.
ANDERSON_MEMORY = 20
_ANDERSON_RESTART = 10.0


def run_steps(steps, logk: LogKernel):
    """Drive a step generator (``anderson_steps``, ``symmetric_steps``, ``pair_steps``):
    each log-block it yields is answered with ``logk(block)``; returns its return value."""
    with np.errstate(over="ignore", under="ignore"):
        try:
            block = next(steps)
            while True:
                block = steps.send(logk(block))
        except StopIteration as stop:
            return stop.value


def anderson_steps(areas, m0, l0, l1, f, *, tol, max_iter, monitor: Monitor,
                   memory: int = ANDERSON_MEMORY):
    r"""Sinkhorn as a fixed point ``f = T(f)`` solved with Anderson acceleration.

    One Sinkhorn iteration is the map :math:`T(f) = \log\mu_0 - \log H(a \otimes
    e^{g(f)})` with :math:`g(f) = \log\mu_1 - \log H(a \otimes e^f)`; its fixed
    point is the scaling of Alg. 1.  Anderson mixing (type II, Walker & Ni 2011)
    takes :math:`f_{k+1} = T(f_k) - \Delta T\,\gamma` with :math:`\gamma` the
    least-squares fit of the last ``memory`` residual differences
    :math:`\Delta r` to :math:`r_k = T(f_k) - f_k` (mass-weighted, Tikhonov-damped);
    the cost per iteration stays two kernel applications plus O(n memory).
    Safeguard: when the marginal violation grows ``_ANDERSON_RESTART`` times past
    the best seen, or the fit is singular, the history is dropped and a plain
    Sinkhorn step is taken.  The second marginal is exact after every step
    (``g = g(f)``), so the reported residual is the L1 violation of the first.

    A generator: it yields each log-input whose kernel application it needs and is sent
    :math:`\log H(a \otimes e^x)` back (:func:`run_steps` for one problem; the distance
    matrix answers many problems' inputs with one block solve).  Returns ``(f, g,
    iterations, residual, converged, 1.0)``.
    """
    support = np.flatnonzero(m0 > 0)
    full = len(support) == len(f)
    # Weight the log-residuals by mass: m0 |e^r - 1| ~ m0 |r| is the L1 violation.
    weight = np.sqrt(m0 if full else m0[support])
    mixer = _AndersonMixer(len(support), memory, weight)
    best = np.inf
    residual = np.inf
    it = 0
    while True:
        g = l1 - (yield f)
        lg = yield g
        residual = _l1_gap(m0, areas, f, lg)
        monitor(it, residual)
        if residual <= tol or it >= max_iter or not np.isfinite(residual) \
                or monitor.stalled:
            break
        if residual > _ANDERSON_RESTART * best:
            mixer.reset()
        best = min(best, residual)
        t_f = (l0 - lg) if full else (l0[support] - lg[support])
        step = mixer.step(t_f, t_f - (f if full else f[support]))
        if full:
            f = step
        else:  # off the support f stays -inf
            f[support] = step
        it += 1
    return f, g, it, residual, bool(residual <= tol), 1.0


class _AndersonMixer:
    """Anderson (type II) mixing with ring buffers and an incrementally updated Gram matrix."""

    def __init__(self, n: int, memory: int, weight: np.ndarray):
        self.memory = max(int(memory), 1)
        self.weight = weight
        self.d_r = np.empty((n, self.memory))  # weighted residual differences
        self.d_t = np.empty((n, self.memory))  # differences of T(f)
        self.gram = np.zeros((self.memory, self.memory))
        self.reset()

    def reset(self) -> None:
        self.count = 0  # stored difference columns
        self.slot = 0  # next column to overwrite
        self.last_t = None
        self.last_r = None

    def step(self, t_f: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Next iterate from ``T(f_k)`` and ``r_k = T(f_k) - f_k``."""
        r_w = r * self.weight
        if self.last_t is not None:
            c = self.slot
            np.subtract(r_w, self.last_r, out=self.d_r[:, c])
            np.subtract(t_f, self.last_t, out=self.d_t[:, c])
            self.count = min(self.count + 1, self.memory)
            self.slot = (c + 1) % self.memory
            k = self.count
            row = self.d_r[:, :k].T @ self.d_r[:, c]
            self.gram[c, :k] = row
            self.gram[:k, c] = row
        self.last_t, self.last_r = t_f, r_w
        k = self.count
        if k == 0:
            return t_f
        gram = self.gram[:k, :k].copy()
        gram[np.diag_indices(k)] += 1e-10 * np.trace(gram) + 1e-300
        try:
            coef = np.linalg.solve(gram, self.d_r[:, :k].T @ r_w)
        except np.linalg.LinAlgError:
            coef = None
        out = None if coef is None else t_f - self.d_t[:, :k] @ coef
        if out is None or not np.all(np.isfinite(out)):
            self.reset()
            return t_f
        return out


def _l1_gap(m, areas, f, lk) -> float:
    """``|| m - a exp(f + lk) ||_1`` with one temporary."""
    x = f + lk
    np.exp(x, out=x)
    x *= areas
    x -= m
    return float(np.abs(x, out=x).sum())


def symmetric_steps(areas, m, *, tol, max_iter, monitor: Monitor):
    r"""Self-transport :math:`W^2_{2,H_t}(\mu,\mu)`: symmetric scaling ``f = log v = log w``.

    Averaged update :math:`f \leftarrow \tfrac12 (f + \log\mu - \log H(e^f))`
    (Feydy et al. 2019), which converges in a few dozen iterations.  ``m`` may be
    ``(n, k)``: the ``k`` problems run as one block.  A step generator
    (:func:`run_steps`); returns ``(f, iterations, residual, converged)``.
    """
    lm = log_density(m, areas)
    s = m > 0
    f = np.where(s, 0.0, -np.inf)
    lf = yield f
    a = areas if m.ndim == 1 else areas[:, None]
    it = 0
    while True:
        residual = float(np.max(np.abs(m - a * np.exp(f + lf)).sum(axis=0)))
        monitor(it, residual)
        if residual <= tol or it >= max_iter or not np.isfinite(residual) \
                or monitor.stalled:
            break
        f[s] = 0.5 * (f[s] + lm[s] - lf[s])
        lf = yield f
        it += 1
    return f, it, residual, bool(residual <= tol)


@dataclass
class PairSolve:
    """What :func:`pair_steps` returns: the (debiased) value and its convergence data."""

    value: float
    f: np.ndarray
    g: np.ndarray
    iterations: int
    residual: float
    converged: bool
    omega: float
    self_values: tuple[float, float] | None


def pair_steps(areas, m0, m1, *, gamma, debiased, tol, max_iter, monitor: Monitor,
               acceleration: str = "anderson", init=None):
    """The whole convolutional distance of one pair as a step generator (:func:`run_steps`):
    Sinkhorn (Alg. 1, eq. 3.10), then, if ``debiased``, both self-transports as one
    two-column block.  Returns a :class:`PairSolve`."""
    f, g, it, res, conv, omega = yield from sinkhorn_steps(
        areas, m0, m1, tol=tol, max_iter=max_iter, monitor=monitor,
        acceleration=acceleration, init=init)
    value = _value(gamma, m0, f, m1, g)
    self_values = None
    if debiased:
        mon = monitor.next_stage()  # second stage: its own stagnation record
        mon.offset += it + 1
        h, it_s, res_s, conv_s = yield from symmetric_steps(
            areas, np.stack([m0, m1], axis=1), tol=tol, max_iter=max_iter, monitor=mon)
        self_values = (_value(gamma, m0, h[:, 0], m0, h[:, 0]),
                       _value(gamma, m1, h[:, 1], m1, h[:, 1]))
        it += it_s
        res = max(res, res_s)
        conv = conv and conv_s
        value = value - 0.5 * self_values[0] - 0.5 * self_values[1]
    return PairSolve(value, f, g, int(it), float(res), bool(conv), float(omega), self_values)


def _value(gamma, m0, f, m1, g) -> float:
    s0, s1 = m0 > 0, m1 > 0
    return float(gamma * (m0[s0] @ f[s0] + m1[s1] @ g[s1]))


def wasserstein_distance(
    domain, mu0, mu1, *, gamma: float | str = "auto", t: float | None = None,
    substeps: int | None = None, tol: float = 1e-5, max_iter: int | None = None,
    debiased: bool | None = None, method: str = "auto", acceleration: str = "anderson",
    init: tuple[np.ndarray, np.ndarray] | None = None,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> SinkhornResult | ExactTransportResult:
    r"""Convolutional Wasserstein distance :math:`W^2_{2,H_t}` (thesis Alg. 1, eq. 3.10).

    Objective: :math:`\min_\pi \int\!\!\int d^2\,d\pi - \gamma H(\pi)` over couplings of
    ``mu0`` and ``mu1``, with the Gibbs kernel replaced by the heat kernel
    :math:`H_t`, ``t = heat_time(gamma) = gamma/4`` (so :math:`H_t \approx e^{-d^2/\gamma}`).
    Returned value :math:`\gamma\, a^\top[\mu_0 \ln v + \mu_1 \ln w]` (squared-distance
    units, domain rescaled to unit area for meshes).  With ``debiased=True`` the
    Sinkhorn divergence :math:`S = W(\mu_0,\mu_1) - \tfrac12 W(\mu_0,\mu_0) - \tfrac12
    W(\mu_1,\mu_1)` is returned, which vanishes for ``mu0 == mu1`` and removes the
    first-order entropic bias.

    Defaults (``gamma="auto"``, ``method="auto"``): values users can trust, decided by
    :func:`~solvers.transport.decision.decide_distance` from the inputs and the stored
    domain alone (never the clock or the process's history; the service takes the same
    decision at submission): the exact discrete W2² (:func:`~solvers.transport.exact.
    exact_wasserstein_distance`: exact geodesic cost matrix between the supports,
    network-simplex LP) when its modelled time fits
    :data:`~solvers.transport.decision.EXACT_BUDGET_SECONDS`, else Alg. 1 with the
    regularization of :func:`solvers.regularization.choose_regularization` (``purpose=
    "values"``: debiased, ``gamma`` proportional to the mesh resolution times the estimated
    transport distance, substeps enough for implicit Euler to follow the Gaussian out to
    that distance).  The decision is in ``result.decision`` (and the policy's choice in
    ``result.regularization``).  Measured accuracy against the exact LP with exact
    geodesics: ``bench/results/distance_routes.md``.  A numeric ``gamma`` runs Alg. 1
    exactly as specified (``substeps=1``, ``debiased=False`` unless given; ``method="auto"``
    then means convolutional).

    Parameters
    ----------
    domain : any domain (mesh, grid, graph, point cloud).
    mu0, mu1 : ``(n,)`` masses (non-negative, normalized here).
    gamma : entropic regularization (cost :math:`d^2`), or ``"auto"`` (default: the policy).
    t, substeps : heat time (default ``gamma/4``) and implicit Euler substeps (default: the
        policy's with ``gamma="auto"``, else 1).
    tol : L1 marginal violation at which to stop (mass units).
    max_iter : iteration cap (default 10000); when hit, or when the residual stops
        falling (stagnation), ``converged`` is False and ``residual`` is the measured
        violation.
    debiased : return the Sinkhorn divergence (default: True with ``gamma="auto"``, else False).
    method : ``"auto"`` (default), ``"convolutional"`` (always Alg. 1) or ``"exact"`` (always
        the LP; meshes, grids and point clouds).
    acceleration : ``"anderson"`` (default: Anderson mixing of the Sinkhorn fixed-point
        map, about half the iterations of over-relaxation), ``"over-relaxation"``
        (adaptive SOR) or ``"none"`` (plain Alg. 1).  Same fixed point.
    init : optional warm start ``(log_v, log_w)`` from a previous result.
    progress, should_cancel : called every iteration; ``should_cancel()`` returning
        True raises :class:`solvers.errors.CancelledError`.

    Returns
    -------
    SinkhornResult(value, v, w, iterations, residual, converged, log_v, log_w, gamma, t,
    substeps, debiased, method="convolutional", regularization, decision, ...), or an
    ExactTransportResult(value, ..., method="exact", decision) when the exact method is taken.

    Examples
    --------
    Two bumps half a unit apart on a 1-D grid: :math:`W_2^2 \approx 0.5^2`.

    >>> import numpy as np
    >>> from solvers.domains import Grid
    >>> from solvers.convolutional import wasserstein_distance
    >>> x = np.linspace(0.0, 1.0, 50)
    >>> mu0 = np.exp(-((x - 0.25) / 0.05) ** 2)
    >>> mu1 = np.exp(-((x - 0.75) / 0.05) ** 2)
    >>> result = wasserstein_distance(Grid([50]), mu0 / mu0.sum(), mu1 / mu1.sum(), gamma=1e-3)
    >>> result.converged, f"{result.value:.2f}"
    (True, '0.25')
    """
    m0, m1 = distribution_pair(domain, mu0, mu1)
    acceleration = check_acceleration(acceleration, ACCELERATIONS)
    decision = decide_distance(domain, m0, m1, method=method, gamma=gamma, t=t,
                               substeps=substeps, debiased=debiased)
    if decision.method == "exact":
        res = exact_wasserstein_distance(domain, m0, m1, progress=progress,
                                         should_cancel=should_cancel)
        res.decision = decision
        return res
    setup = prepare(domain, gamma=decision.gamma, t=decision.t, substeps=decision.substeps,
                    tol=tol, max_iter=max_iter, progress=progress, should_cancel=should_cancel)
    check_components(domain, np.stack([m0, m1], axis=1), setup.tol, "mu1")
    mon = watch_stagnation(setup, project=max_iter is None)
    solve = run_steps(pair_steps(setup.areas, m0, m1, gamma=setup.gamma,
                                 debiased=decision.debiased, tol=setup.tol,
                                 max_iter=setup.max_iter, monitor=mon,
                                 acceleration=acceleration, init=init), setup.logk)
    return _balanced_result(solve, setup, decision)


def _balanced_result(solve: PairSolve, setup, decision) -> SinkhornResult:
    """The :class:`SinkhornResult` of a pair solve, its log-scalings shifted by opposite
    constants so that their finite maxima match."""
    f, g, it, res, conv = solve.f, solve.g, solve.iterations, solve.residual, solve.converged
    omega, self_values, value = solve.omega, solve.self_values, solve.value
    # Balance the scaling ambiguity (v, w) -> (c v, w / c) for readable v, w.
    shift = 0.5 * (_finite_max(f) - _finite_max(g))
    f, g = f - shift, g + shift
    with np.errstate(over="ignore", under="ignore"):
        v, w = np.exp(f), np.exp(g)
    return SinkhornResult(value=value, v=v, w=w, iterations=int(it), residual=float(res),
                          converged=bool(conv), log_v=f, log_w=g, gamma=setup.gamma,
                          t=setup.t, omega=float(omega), self_values=self_values,
                          substeps=setup.substeps, debiased=bool(decision.debiased),
                          regularization=decision.regularization, decision=decision)


def _finite_max(x: np.ndarray) -> float:
    finite = x[np.isfinite(x)]
    return float(finite.max()) if finite.size else 0.0
