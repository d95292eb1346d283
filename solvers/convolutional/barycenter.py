r"""Convolutional Wasserstein barycenters (eq. 3.13, Alg. 2) and entropic sharpening (Alg. 3).

.. math::  \mu^\star = \arg\min_{\mu} \sum_i \alpha_i\, W^2_{2,H_t}(\mu, \mu_i)

solved by iterative Bregman projections: with one pair of scalings
:math:`(v_i, w_i)` per input,

.. math::  w_i \leftarrow \mu_i / H_t(a \otimes v_i), \quad
           d_i = v_i \otimes H_t(a \otimes w_i), \quad
           \mu \leftarrow \textstyle\prod_i d_i^{\alpha_i}, \quad
           v_i \leftarrow v_i \otimes \mu / d_i .

All ``k`` kernel applications of a step form one ``n×k`` block (one multi-RHS
solve on meshes, one batched convolution on grids); every quantity is kept as a
logarithm (see :class:`~solvers.convolutional.common.LogKernel`), so small
``gamma`` cannot overflow.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from solvers.convolutional.common import (
    BARYCENTER_ACCELERATIONS,
    LogKernel,
    Monitor,
    OverRelaxation,
    check_acceleration,
    entropy,
    log_density,
    masses_from_log,
    prepare,
)
from solvers.convolutional.distance import run_steps, watch_stagnation
from solvers.monitor import SolverResult
from solvers.regularization import Regularization, shape_method, shape_regularization
from solvers.validation import check_components, check_entropy_bound, check_weights, masses_block


@dataclass
class BarycenterResult(SolverResult):
    r"""Result of :func:`barycenter`.

    Attributes
    ----------
    masses : (n,) array
        The barycenter (sum 1).
    entropy : float
        :math:`-\sum m \log(m/a)`.
    entropy_bound : float or None
        The bound used by sharpening (None without sharpening).
    log_scalings : tuple of (n, k) array or None
        ``(log v, log w)``: the plan of input ``i`` is :math:`\pi_i = D_{v_i} K D_{w_i}`
        (barycenter side ``v``, input side ``w``).
    gamma, t, substeps, regularization, method
        As in :class:`~solvers.convolutional.SinkhornResult`.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
        ``residual``: largest L1 violation :math:`\|a \otimes (v_i \otimes H(a\otimes w_i) -
        \mu)\|_1` over the inputs (mass units).
    """

    masses: np.ndarray
    entropy: float
    entropy_bound: float | None = None
    gamma: float = 0.0
    t: float = 0.0
    log_scalings: tuple[np.ndarray, np.ndarray] | None = None
    substeps: int | None = 1  # None when the geodesic kernel ran
    regularization: Regularization | None = None
    method: str = "convolutional"


def sharpen_log(lbar: np.ndarray, areas: np.ndarray, bound: float) -> np.ndarray:
    r"""Entropic sharpening (Alg. 3) of a log-density ``lbar`` (``(n,)``).

    If the entropy of the normalized density exceeds :math:`H_0`, replace
    :math:`\mu` by :math:`\mu^\beta` rescaled to the same mass, with
    :math:`\beta \ge 1` chosen (bisection; the entropy of the normalized power
    decreases in :math:`\beta`) so that its normalized entropy equals :math:`H_0`.
    The thesis states the constraint as :math:`a^\top\mu^\beta + H(\mu^\beta) = 1 + H_0`,
    which agrees when :math:`a^\top\mu = 1` but has no root for the unnormalized
    early iterates when :math:`H_0 < -1`; measuring the normalized entropy keeps the
    bound meaningful at every iteration.
    """
    finite = np.isfinite(lbar)
    L = lbar[finite]
    a = areas[finite]
    top = float(L.max())

    def log_mass(beta: float) -> float:
        with np.errstate(under="ignore"):
            return beta * top + float(np.log(np.sum(a * np.exp(beta * (L - top)))))

    def normalized_entropy(beta: float) -> float:
        lz = log_mass(beta)
        with np.errstate(under="ignore"):
            nu = a * np.exp(beta * L - lz)
        return lz - beta * float(nu @ L)

    if not normalized_entropy(1.0) > bound:
        return lbar
    lo, hi = 1.0, 2.0
    while normalized_entropy(hi) > bound and hi < 1e6:
        lo, hi = hi, 2.0 * hi
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if normalized_entropy(mid) > bound:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-10 * hi:
            break
    shift = log_mass(1.0) - log_mass(hi)  # keep the mass of mu
    return np.where(finite, hi * lbar + shift, lbar)


def barycenters_log(logk: LogKernel, areas: np.ndarray, inputs: np.ndarray,
                    weights: np.ndarray, **options):
    r"""``B`` barycenters at once from ``C`` input columns: :func:`barycenter_steps`
    driven by ``logk`` (same arguments, returns ``(log_bar (n, B), iterations, residual,
    converged)``)."""
    options.setdefault("order", "F" if logk.use_log_apply else "C")
    with np.errstate(invalid="ignore"):
        return run_steps(barycenter_steps(areas, inputs, weights, **options), logk)


def barycenter_steps(areas: np.ndarray, inputs: np.ndarray, weights: np.ndarray, *,
                     tol: float, max_iter: int, monitor: Monitor,
                     entropy_bounds: np.ndarray | None = None, debiased: bool = False,
                     owners: np.ndarray | None = None, relax: bool = False,
                     measure_all: bool = False, scalings: dict | None = None,
                     order: str = "F"):
    r"""``B`` barycenters at once from ``C`` input columns, as a step generator: it yields
    each log-block to which the kernel applies and receives ``logk`` of it
    (:func:`~solvers.convolutional.distance.run_steps`, or
    :func:`~solvers.convolutional.matrix.run_block` for many problems in one block).

    ``inputs`` ``(n, C)`` masses; ``weights`` ``(C, B)``: column ``c`` enters
    barycenter ``b`` with weight ``weights[c, b]`` (each column of ``weights`` sums
    to 1; a column belongs to one barycenter, ``owners[c]``, default the barycenter
    where its weight is positive).  ``relax`` over-relaxes both scaling updates
    (:class:`~solvers.convolutional.common.OverRelaxation`; same fixed point).
    ``measure_all``: the residual also counts columns of weight 0 (their plans, to the
    barycenter they do not influence, are then converged too); ``scalings``: a dict that
    receives ``"log_v"`` and ``"log_w"`` (``(n, C)``) at the end.
    Returns ``(log_bar (n, B), iterations, residual, converged)``.
    """
    n, C = inputs.shape
    owner = np.argmax(weights > 0, axis=1) if owners is None else np.asarray(owners)
    alpha = weights[np.arange(C), owner]
    # Keep (n, C) blocks in the kernel's preferred layout: grid kernels work on the
    # transposed (C, *shape) block, so Fortran order avoids a transpose copy per call.
    lm = np.asarray(log_density(inputs, areas), order=order)
    lv = np.zeros((n, C), order=order)
    B = weights.shape[1]
    lc = np.zeros((n, B))
    lbar = np.zeros((n, B))
    a = areas[:, None]
    support = np.isfinite(lm)
    full = bool(support.all())

    def spread(x):  # (n, B) -> (n, C): each column's barycenter (broadcast when B == 1)
        return x if B == 1 else x[:, owner]

    check = 5  # marginal violation measured every `check` iterations (and at max_iter)
    sor = OverRelaxation(enabled=relax, window=2, stride=check)
    omega = 1.0
    lw = None
    it = 0
    residual = np.inf
    while True:
        lkv = yield lv
        target = lm - lkv
        if lw is None or omega == 1.0:
            lw = target
        else:
            lw = lw + omega * (target - lw)
            if not full:
                lw = np.where(support, lw, -np.inf)
        lku = yield lw
        ld = lv + lku
        if debiased:
            lbar, lc = yield from _debiased_mean_steps(lku, weights, lc)
        else:
            lbar = ld @ weights  # Alg. 2: mu = prod_i d_i^alpha_i
        if entropy_bounds is not None:
            for b in range(B):
                lbar[:, b] = sharpen_log(lbar[:, b], areas, entropy_bounds[b])
        if it % check == 0 or it >= max_iter:
            gaps = _marginal_gaps(a, ld, spread(lbar), omega, lw, lkv, inputs)
            residual = float(np.max(gaps if measure_all else np.where(alpha > 0, gaps, 0.0)))
            if not np.isfinite(residual):
                residual = float("inf")
            if residual <= tol or it >= max_iter or not np.isfinite(residual) \
                    or monitor.stalled:
                monitor(it, residual)
                break
            omega = sor.update(residual)
        monitor(it, residual)
        lv = lv + omega * (spread(lbar) - lku - lv)
        it += 1
    if scalings is not None:
        scalings["log_v"], scalings["log_w"] = lv, lw
    return lbar, it, residual, bool(residual <= tol)


def _debiased_mean_steps(lku, weights, lc):
    """The debiased barycenter's log-density and its log-factor ``c`` as a step generator
    (Janati et al. (2020) / POT: geometric mean of H(w_i) times c, 10 fixed-point steps
    of ``c``); returns ``(lbar, lc)``."""
    lbar = lku @ weights + lc
    for _ in range(10):
        lc = 0.5 * (lc + lbar - (yield lc))
    return lbar, lc


def _marginal_gaps(a, ld, spread_lbar, omega, lw, lkv, inputs):
    """Per column the L1 violation of its plan's marginal at the barycenter, plus, when
    over-relaxed (``omega != 1``), at the input: the relaxed w update leaves it inexact."""
    gaps = np.abs(a * (np.exp(ld) - np.exp(spread_lbar))).sum(axis=0)
    if omega != 1.0:
        gaps = gaps + np.abs(a * np.exp(lw + lkv) - inputs).sum(axis=0)
    return gaps


def barycenter(
    domain,
    mus,
    weights=None,
    *,
    gamma: float | str = "auto",
    t: float | None = None,
    substeps: int | None = None,
    entropy_bound: float | None = None,
    sharpen: bool = False,
    debiased: bool = False,
    tol: float = 1e-5,
    max_iter: int | None = None,
    acceleration: str = "over-relaxation",
    method: str = "auto",
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> BarycenterResult:
    r"""Wasserstein barycenter :math:`\arg\min_\mu \sum_i \alpha_i W^2_{2,H_t}(\mu,\mu_i)`.

    Thesis eq. 3.13 / Alg. 2, with optional entropic sharpening (Alg. 3): after each
    barycenter update, if its entropy exceeds :math:`H_0` it is replaced by
    :math:`\mu^\beta` (same mass) whose entropy is :math:`H_0` (:func:`sharpen_log`).
    :math:`H_0` is ``entropy_bound`` or, with ``sharpen=True`` and no bound, the
    largest input entropy.  ``debiased=True`` computes the debiased barycenter of
    Janati et al. (2020), minimizing Sinkhorn divergences instead (an extra
    symmetric scaling ``c`` with :math:`c \otimes H(a \otimes c) = \mu` multiplies
    the geometric mean), which removes most of the entropic blur.

    Parameters
    ----------
    domain : any domain.
    mus : ``(n, k)`` input masses (columns normalized here).
    weights : ``(k,)`` non-negative barycentric weights (default uniform), normalized.
    gamma, t, substeps : regularization, heat time (default ``gamma/4``), substeps.
        ``gamma="auto"`` (default) takes :func:`solvers.regularization.choose_regularization`
        with ``purpose="shapes"`` (reported in ``result.regularization``); a numeric
        ``gamma`` runs as specified, one substep unless given.
    entropy_bound, sharpen, debiased : see above.
    tol : largest L1 marginal violation over the inputs at which to stop.
    max_iter : iteration cap (default 10000); the loop also stops when the residual stops
        falling (stagnation), reporting ``converged=False`` and the measured residual.
    acceleration : ``"over-relaxation"`` (default: adaptive over-relaxation of both
        scaling updates, same fixed point, typically 3-5x fewer iterations; used
        without sharpening/debiasing) or ``"none"`` (plain Alg. 2).
    method : the kernel (:func:`solvers.regularization.shape_method`): ``"auto"``
        (default: ``"geodesic"`` on triangle meshes where offered, else
        ``"convolutional"``), ``"geodesic"`` (the Gibbs kernel :math:`e^{-d^2/\gamma}` of
        squared heat-method geodesics, applied exactly in the log domain: Alg. 2's
        iterations with the kernel that the heat kernel approximates; sharp at every
        distance; substeps unused) or ``"convolutional"`` (the thesis' heat kernel, Alg. 2
        as published).  ``result.method`` says which ran.
    progress, should_cancel : called every iteration.

    Returns
    -------
    BarycenterResult(masses (n,), iterations, residual, converged, entropy, entropy_bound)

    Examples
    --------
    The midpoint of two bumps on a 1-D grid sits half way between them.

    >>> import numpy as np
    >>> from solvers.domains import Grid
    >>> from solvers.convolutional import barycenter
    >>> x = np.linspace(0.0, 1.0, 50)
    >>> mus = np.stack([np.exp(-((x - c) / 0.05) ** 2) for c in (0.25, 0.75)], axis=1)
    >>> result = barycenter(Grid([50]), mus / mus.sum(axis=0), gamma=1e-3)
    >>> result.masses.shape, f"{x @ result.masses:.2f}"
    ((50,), '0.50')
    """
    M = _inputs(domain, mus)
    alpha = check_weights(weights, M.shape[1])
    reg, setup, options = _prepared(domain, M, gamma=gamma, t=t, substeps=substeps,
                                    entropy_bound=entropy_bound, sharpen=sharpen,
                                    debiased=debiased, tol=tol, max_iter=max_iter,
                                    acceleration=acceleration, method=method,
                                    progress=progress, should_cancel=should_cancel)
    bound = options["entropy_bounds"]
    bound = None if bound is None else float(bound[0])
    scalings: dict = {}
    lbar, it, res, conv = barycenters_log(
        setup.logk, setup.areas, M, alpha[:, None],
        monitor=watch_stagnation(setup, project=max_iter is None), scalings=scalings,
        **options)
    masses = masses_from_log(lbar[:, 0], setup.areas)
    return BarycenterResult(masses=masses, iterations=int(it), residual=float(res),
                            converged=conv, entropy=float(entropy(masses, setup.areas)),
                            entropy_bound=bound, gamma=setup.gamma, t=setup.t,
                            log_scalings=(scalings["log_v"], scalings["log_w"]),
                            substeps=setup.substeps,
                            regularization=reg and reg.for_kernel(setup.method),
                            method=setup.method)


def _inputs(domain, mus) -> np.ndarray:
    """``(n, k)`` normalized input masses of a barycenter."""
    M = masses_block(domain, mus, "mus")
    return M[:, None] if M.ndim == 1 else M


def _prepared(domain, M, *, gamma, t, substeps, entropy_bound, sharpen, debiased, tol,
              max_iter, acceleration, method, progress, should_cancel):
    """``(policy or None, prepared setup, options of barycenter_steps)`` of
    :func:`barycenter` / :func:`barycenters` (their shared checks and regularization)."""
    acceleration = check_acceleration(acceleration, BARYCENTER_ACCELERATIONS)
    method = shape_method(domain, method)
    reg, gamma, substeps = shape_regularization(domain, gamma, t, substeps)
    setup = prepare(domain, gamma=gamma, t=t, substeps=substeps, tol=tol, max_iter=max_iter,
                    progress=progress, should_cancel=should_cancel, method=method)
    check_components(domain, M, setup.tol, "mus")
    bound = None
    if entropy_bound is not None:
        bound = check_entropy_bound(entropy_bound, setup.areas, "entropy_bound")
    elif sharpen:
        bound = float(np.max(entropy(M, setup.areas)))
    options = {"tol": setup.tol, "max_iter": setup.max_iter, "debiased": debiased,
               "entropy_bounds": None if bound is None else np.array([bound]),
               "relax": acceleration == "over-relaxation" and bound is None and not debiased}
    return reg, setup, options


@dataclass
class BarycentersResult(SolverResult):
    r"""Result of :func:`barycenters`: one barycenter per weight vector.

    Attributes
    ----------
    masses : (n, B) array
        Barycenters (columns sum to 1).
    weights : (B, k) array
        The weight vectors.
    problem_iterations, problem_residuals, problem_converged : (B,) array
        Convergence data per weight vector.
    entropies : (B,) array
        Entropy of each barycenter.
    entropy_bound : float or None
        The bound used by sharpening.
    gamma, t, substeps, regularization, method
        As in :class:`~solvers.convolutional.SinkhornResult`.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
        ``iterations`` (sum), ``residual`` (max) and ``converged`` (all) summarize the
        problems.
    """

    masses: np.ndarray
    weights: np.ndarray
    problem_iterations: np.ndarray
    problem_residuals: np.ndarray
    problem_converged: np.ndarray
    entropies: np.ndarray
    entropy_bound: float | None = None
    gamma: float = 0.0
    t: float = 0.0
    substeps: int | None = 1  # None when the geodesic kernel ran
    regularization: Regularization | None = None
    method: str = "convolutional"


# Batched barycenters: problems per block step such that the block's kernel columns (n
# values per input column) fit this many bytes.  All problems in one block measured slower
# than single calls on spot, blocks of this size faster (bench/results/distance_matrix.md,
# barycenters): wide blocks leave the cache between a step's element-wise passes.
BLOCK_CACHE_BYTES = 256 * 2**10


def _weight_vectors(weights, k: int) -> np.ndarray:
    """``(B, k)`` weight vectors, each checked and normalized."""
    from solvers.errors import InputError

    try:
        W = np.atleast_2d(np.asarray(weights, dtype=np.float64))
    except (TypeError, ValueError) as exc:
        raise InputError("weights must be a list of weight vectors", field="weights") from exc
    if W.ndim != 2 or W.shape[0] == 0:
        raise InputError(f"weights must have shape (B, {k})", field="weights")
    return np.stack([check_weights(w, k) for w in W])


def _check_block(block) -> None:
    """Raise unless ``block`` is ``None`` or a positive integer."""
    from solvers.errors import InputError

    if block is not None and (isinstance(block, bool) or not isinstance(block, (int, np.integer))
                              or block < 1):
        raise InputError(f"block must be a positive integer, got {block!r}", field="block")


def cached_problems(n: int, inputs: int) -> int:
    """Barycenter problems of ``inputs`` columns on ``n`` vertices per block (at least 1; a
    function of the sizes only)."""
    return max(1, BLOCK_CACHE_BYTES // (8 * int(n) * int(inputs)))


def barycenters(
    domain, mus, weights, *, gamma: float | str = "auto", t: float | None = None,
    substeps: int | None = None, entropy_bound: float | None = None, sharpen: bool = False,
    debiased: bool = False, tol: float = 1e-5, max_iter: int | None = None,
    acceleration: str = "over-relaxation", method: str = "auto", block: int | None = None,
    progress: Callable[..., None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> BarycentersResult:
    r"""Many barycenters of the same inputs, one per weight vector, solved as one block.

    For every weight vector :math:`\alpha^{(b)}`,
    :math:`\mu_b = \arg\min_\mu \sum_i \alpha^{(b)}_i W^2_{2,H_t}(\mu, \mu_i)`.
    Problem ``b`` is :func:`barycenter` ``(domain, mus, weights[b], ...)`` with the same
    arguments (eq. 3.13 / Alg. 2; Alg. 3 with sharpening): every problem keeps its own
    scalings, over-relaxation, stopping rule and stagnation record, so each column of
    ``masses`` is that single call's result; the kernel applications of all active
    problems form one multi-column block per step
    (:func:`~solvers.convolutional.matrix.run_block`), finished problems leave it and the
    next enter.  The regularization (``gamma="auto"``: the ``"shapes"`` policy) depends on
    the domain alone, so every problem shares one kernel.

    Parameters
    ----------
    domain : any domain.
    mus : ``(n, k)`` input masses (columns normalized here).
    weights : ``(B, k)`` non-negative weight vectors (each normalized), e.g. a grid of
        ``alphas`` (thesis Fig. 3.4).
    gamma, t, substeps, entropy_bound, sharpen, debiased, tol, max_iter, acceleration, method :
        as :func:`barycenter`.
    block : problems advanced together (default :func:`cached_problems`: their kernel
        columns fit :data:`BLOCK_CACHE_BYTES`); each problem's result does not depend on it.
    progress : ``progress(problems_done, worst_residual)`` after each finished problem.
    should_cancel : checked before every block step (raises
        :class:`~solvers.errors.CancelledError`).

    Returns
    -------
    BarycentersResult(masses (n, B), weights (B, k), problem_iterations, problem_residuals,
    problem_converged, entropies, iterations, residual, converged, ...)
    """
    from solvers.convolutional.matrix import run_block

    M = _inputs(domain, mus)
    k = M.shape[1]
    W = _weight_vectors(weights, k)
    _check_block(block)
    reg, setup, options = _prepared(domain, M, gamma=gamma, t=t, substeps=substeps,
                                    entropy_bound=entropy_bound, sharpen=sharpen,
                                    debiased=debiased, tol=tol, max_iter=max_iter,
                                    acceleration=acceleration, method=method,
                                    progress=None, should_cancel=None)
    bound = options["entropy_bounds"]
    bound = None if bound is None else float(bound[0])
    B = W.shape[0]
    out = {"masses": np.zeros((M.shape[0], B)), "it": np.zeros(B, dtype=np.int64),
           "res": np.full(B, np.nan), "conv": np.zeros(B, dtype=bool)}

    def jobs():
        for b in range(B):
            steps = barycenter_steps(
                setup.areas, M, W[b][:, None],
                monitor=watch_stagnation(setup, project=max_iter is None),
                order="F" if setup.logk.use_log_apply else "C", **options)
            yield b, steps

    def done(b, value) -> None:
        lbar, it, res, conv = value
        out["masses"][:, b] = masses_from_log(lbar[:, 0], setup.areas)
        out["it"][b], out["res"][b], out["conv"][b] = it, res, conv
        if progress is not None:
            finished = np.isfinite(out["res"])
            progress(int(finished.sum()), float(np.max(out["res"][finished])))

    stop = Monitor(None, should_cancel).check_cancel
    with np.errstate(invalid="ignore"):
        run_block(setup.logk, jobs(), block or cached_problems(M.shape[0], k), done, stop)
    masses = out["masses"]
    return BarycentersResult(
        masses=masses, weights=W, problem_iterations=out["it"], problem_residuals=out["res"],
        problem_converged=out["conv"], entropies=entropy(masses, setup.areas),
        entropy_bound=bound, gamma=setup.gamma, t=setup.t, substeps=setup.substeps,
        regularization=reg and reg.for_kernel(setup.method), iterations=int(out["it"].sum()),
        residual=float(out["res"].max()), converged=bool(out["conv"].all()), method=setup.method)
