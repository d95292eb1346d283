"""Progress, cancellation and stagnation of iterative solvers; the result base they return.

Every iterative solver in ``solvers`` takes ``progress(iteration, residual)`` and
``should_cancel()`` callables and calls one :class:`Monitor` once per iteration, which

* raises :class:`~solvers.errors.CancelledError` when ``should_cancel()`` says so (the
  service's cancel button and job time limit go through here),
* forwards ``(iteration, residual)`` to ``progress`` (the job's progress bar), with the
  fraction done estimated from the residual's decrease towards ``tol`` when the progress
  callable accepts a third argument,
* records whether the residual has stopped falling (:attr:`Monitor.stalled`), so a solver
  can stop and report ``converged=False`` with the measured residual instead of running
  to its iteration cap.

Results derive from :class:`SolverResult`: ``iterations``, ``residual`` (the measured
stopping quantity) and ``converged`` mean the same in every solver.
"""

from __future__ import annotations

import inspect
import math
import types
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from solvers.errors import CancelledError, InputError

Progress = Callable[..., None]
ShouldCancel = Callable[[], bool]


@dataclass(kw_only=True)
class SolverResult:
    """Convergence data shared by every solver's result.

    ``iterations``: iterations run; ``residual``: the measured stopping quantity at the end
    (a marginal violation, a relative primal/dual residual, ... as each solver documents);
    ``converged``: ``residual <= tol`` was reached.

    Attributes
    ----------
    iterations : int
        Iterations run.
    residual : float
        The measured stopping quantity at the end.
    converged : bool
        ``residual <= tol`` was reached.
    """

    iterations: int = 0
    residual: float = math.nan
    converged: bool = False


def _arity(fn) -> int:
    """Positional parameters ``fn`` takes (3 with ``*args``); 2 when it cannot be told.

    Plain functions and bound methods are read off their code object (``inspect.signature``
    costs ~0.1 ms, paid on every solver call with a progress callback)."""
    func = getattr(fn, "__func__", fn)
    code = getattr(func, "__code__", None)
    if (isinstance(fn, (types.FunctionType, types.MethodType))
            and code is not None and not hasattr(func, "__wrapped__")):
        if code.co_flags & inspect.CO_VARARGS:
            return 3
        return code.co_argcount - (1 if isinstance(fn, types.MethodType) else 0)
    return _signature_arity(fn)


def _signature_arity(fn) -> int:
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return 2
    if any(p.kind is p.VAR_POSITIONAL for p in params):
        return 3
    return sum(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in params)


class Monitor:
    """Per-iteration hook: cancellation, progress and stagnation detection.

    ``tol`` (optional) lets the monitor estimate the fraction done as
    ``log(r0 / r) / log(r0 / tol)`` (linear convergence); it is passed as a third argument
    to ``progress`` when that callable takes one. ``patience``: iterations without a
    relative improvement of the best residual by ``min_improvement`` after which
    :attr:`stalled` becomes true (``None`` disables stagnation detection). With
    ``project=True`` (and ``tol``, ``max_iter``, ``patience``) the monitor also stalls when
    the residual still falls but, at the rate measured over the last ``patience``
    iterations, would not reach ``tol`` within ``max_iter`` (e.g. a sublinear tail).

    Parameters
    ----------
    progress : callable, optional
        ``progress(iteration, residual[, fraction])``, called once per iteration.
    should_cancel : callable, optional
        ``should_cancel() -> bool``; True raises :class:`~solvers.errors.CancelledError`.
    tol : float, optional
        The solver's tolerance, for the fraction done.
    patience : int, optional
        Iterations without improvement before :attr:`stalled` (None: never).
    min_improvement : float
        Relative improvement of the best residual that counts.
    max_iter : int, optional
        The solver's iteration budget (``project=True``).
    project : bool
        Also stall when the measured rate would not reach ``tol`` within ``max_iter``.
    """

    def __init__(self, progress: Progress | None = None, should_cancel: ShouldCancel | None = None,
                 *, tol: float | None = None, patience: int | None = None,
                 min_improvement: float = 1e-3, max_iter: int | None = None,
                 project: bool = False):
        if progress is not None and not callable(progress):
            raise InputError("progress must be callable", field="progress")
        if should_cancel is not None and not callable(should_cancel):
            raise InputError("should_cancel must be callable", field="should_cancel")
        self.progress = progress
        self.should_cancel = should_cancel
        self._with_fraction = progress is not None and _arity(progress) >= 3
        self.tol = tol
        self.patience = patience
        self.min_improvement = min_improvement
        self.offset = 0  # added to reported iterations (solvers run in stages)
        self.max_iter = None if max_iter is None else int(max_iter)
        self.project = bool(project and tol is not None and max_iter is not None
                            and patience is not None)
        self.first: float | None = None
        self.best = math.inf
        self._best_at = 0
        self._trail: deque = deque()  # (iteration, lowest residual so far), last `patience`
        self._then: tuple[int, float] | None = None
        self.stalled = False

    def next_stage(self) -> Monitor:
        """A fresh monitor with the same callbacks and settings (and offset) for a solver's
        next stage, so one stage's stagnation record does not stop the next."""
        fresh = Monitor(self.progress, self.should_cancel, tol=self.tol,
                        patience=self.patience, min_improvement=self.min_improvement,
                        max_iter=self.max_iter, project=self.project)
        fresh.offset = self.offset
        return fresh

    def check_cancel(self, where: str = "") -> None:
        """Raise :class:`~solvers.errors.CancelledError` if ``should_cancel()`` says so.

        Parameters
        ----------
        where : str
            Where the check is, for the error message.
        """
        if self.should_cancel is not None and self.should_cancel():
            raise CancelledError(f"cancelled{(' ' + where) if where else ''}")

    def fraction(self, residual: float) -> float | None:
        """Estimated fraction done from the residual's decrease towards ``tol``.

        Parameters
        ----------
        residual : float
            The current residual.
        """
        if self.tol is None or self.first is None or not math.isfinite(residual):
            return None
        if residual <= self.tol:
            return 1.0
        if self.first <= self.tol or residual >= self.first or residual <= 0:
            return 0.0
        return max(0.0, min(1.0, math.log(self.first / residual) / math.log(self.first / self.tol)))

    def __call__(self, iteration: int, residual: float) -> None:
        self.check_cancel(f"at iteration {self.offset + int(iteration)}")
        residual = float(residual)
        if self.first is None and math.isfinite(residual) and residual > 0:
            self.first = residual
        if self.patience is not None and math.isfinite(residual):
            if residual < self.best * (1.0 - self.min_improvement):
                self.best, self._best_at = residual, int(iteration)
            elif int(iteration) - self._best_at >= self.patience:
                self.stalled = True
            if self.project:
                self._project(int(iteration), residual)
        if self.progress is not None:
            if self._with_fraction:
                self.progress(self.offset + int(iteration), residual, self.fraction(residual))
            else:
                self.progress(self.offset + int(iteration), residual)

    def _project(self, it: int, residual: float) -> None:
        low = min(self.best, residual)
        self._trail.append((it, low))
        while self._trail and self._trail[0][0] <= it - self.patience:
            self._then = self._trail.popleft()
        if self._then is None or it < 2 * self.patience or low <= self.tol:
            return
        ratio = low / self._then[1] if self._then[1] > 0 else 1.0
        span = max(it - self._then[0], 1)
        if ratio >= 1.0 or it + span * math.log(self.tol / low) / math.log(ratio) > self.max_iter:
            self.stalled = True
