r"""Displacement interpolation as two-input barycenters (thesis eq. 3.16).

.. math::  \mu_s = \arg\min_\mu\, (1-s)\, W^2_{2,H_t}(\mu, \mu_0) + s\, W^2_{2,H_t}(\mu, \mu_1)

for every requested time ``s``; all times are solved together, their ``2·T``
kernel applications forming one block per step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from solvers.convolutional.barycenter import barycenters_log
from solvers.convolutional.common import (
    BARYCENTER_ACCELERATIONS,
    check_acceleration,
    entropy,
    masses_from_log,
    prepare,
)
from solvers.convolutional.distance import watch_stagnation
from solvers.errors import InputError
from solvers.monitor import SolverResult
from solvers.regularization import Regularization, shape_method, shape_regularization
from solvers.validation import check_components, masses_block


@dataclass
class InterpolationResult(SolverResult):
    r"""Result of :func:`displacement_interpolation`.

    Attributes
    ----------
    masses : (n, T) array
        One frame per time (columns sum to 1).
    times : (T,) array
        The times.
    gamma, t, substeps, regularization, method
        As in :class:`~solvers.convolutional.SinkhornResult`.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    masses: np.ndarray
    times: np.ndarray
    gamma: float = 0.0
    t: float = 0.0
    substeps: int | None = 1  # None when the geodesic kernel ran
    regularization: Regularization | None = None
    method: str = "convolutional"


def displacement_interpolation(
    domain,
    mu0,
    mu1,
    times,
    *,
    gamma: float | str = "auto",
    t: float | None = None,
    substeps: int | None = None,
    sharpen: bool = False,
    debiased: bool = False,
    tol: float = 1e-5,
    max_iter: int | None = None,
    acceleration: str = "over-relaxation",
    method: str = "auto",
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> InterpolationResult:
    r"""Displacement interpolation between ``mu0`` and ``mu1`` (eq. 3.16).

    Each frame is the barycenter of ``(mu0, mu1)`` with weights ``(1 - s, s)``,

    .. math:: \mu_s = \arg\min_\mu\, (1 - s)\, W^2_{2,H_t}(\mu, \mu_0)
              + s\, W^2_{2,H_t}(\mu, \mu_1),

    solved by Alg. 2.  ``sharpen=True`` bounds every frame's entropy by the larger input
    entropy (Alg. 3), ``debiased=True`` uses debiased barycenters.

    Parameters
    ----------
    domain : Domain
        Any domain (``n`` vertices, nodes or points).
    mu0, mu1 : (n,) array
        Masses of the two ends.
    times : sequence of float
        The ``s`` in ``[0, 1]`` of the frames (``T`` of them).
    sharpen : bool
        Bound every frame's entropy by the larger input entropy (Alg. 3).
    debiased : bool
        Debiased barycenters.
    gamma, t, substeps, tol, max_iter, acceleration, method, progress, should_cancel :
        as :func:`barycenter` (``gamma="auto"``: the ``"shapes"`` policy; ``method="auto"``:
        the geodesic kernel on triangle meshes where offered).

    Returns
    -------
    InterpolationResult
        ``masses`` ``(n, T)``, ``times``, ``iterations``, ``residual``, ``converged``.
    """
    m0 = masses_block(domain, mu0, "mu0")
    m1 = masses_block(domain, mu1, "mu1")
    for name, m in (("mu0", m0), ("mu1", m1)):
        if m.ndim != 1:
            raise InputError(f"{name} must have shape ({domain.n},)", field=name)
    try:
        s = np.asarray(times, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError("times must be numbers in [0, 1]", field="times") from exc
    if s.size == 0 or not np.all(np.isfinite(s)) or np.any((s < 0) | (s > 1)):
        raise InputError("times must be a non-empty list of numbers in [0, 1]", field="times")
    acceleration = check_acceleration(acceleration, BARYCENTER_ACCELERATIONS)
    method = shape_method(domain, method)
    reg, gamma, substeps = shape_regularization(domain, gamma, t, substeps)
    setup = prepare(domain, gamma=gamma, t=t, substeps=substeps, tol=tol, max_iter=max_iter,
                    progress=progress, should_cancel=should_cancel, method=method)
    monitor = watch_stagnation(setup, project=max_iter is None)
    check_components(domain, np.stack([m0, m1], axis=1), setup.tol, "mu1")
    T = s.size
    inputs = np.concatenate([np.tile(m0[:, None], (1, T)), np.tile(m1[:, None], (1, T))], axis=1)
    weights = np.zeros((2 * T, T))
    weights[np.arange(T), np.arange(T)] = 1.0 - s
    weights[T + np.arange(T), np.arange(T)] = s
    owners = np.concatenate([np.arange(T), np.arange(T)])
    bounds = None
    if sharpen:
        bounds = np.full(T, float(np.max(entropy(np.stack([m0, m1], axis=1), setup.areas))))
    lbar, it, res, conv = barycenters_log(
        setup.logk, setup.areas, inputs, weights, tol=setup.tol, max_iter=setup.max_iter,
        monitor=monitor, entropy_bounds=bounds, debiased=debiased, owners=owners,
        relax=acceleration == "over-relaxation" and not sharpen and not debiased)
    masses = masses_from_log(lbar, setup.areas)
    return InterpolationResult(masses=masses, times=s, iterations=int(it), residual=float(res),
                               converged=conv, gamma=setup.gamma, t=setup.t,
                               substeps=setup.substeps,
                               regularization=reg and reg.for_kernel(setup.method),
                               method=setup.method)
