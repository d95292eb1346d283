r"""The default decision of a W2 distance: method and regularization from the data alone.

:func:`decide_distance` is what ``wasserstein_distance(domain, mu0, mu1)`` runs when
``method`` and ``gamma`` are left to ``"auto"``, and what the service runs at submission (its
decision is stored with the job and executed by the worker as explicit arguments):

* **method** — ``"exact"`` (:func:`~solvers.transport.exact.exact_wasserstein_distance`:
  exact geodesic costs between the supports and the transport LP, no bias) when the exact
  method is available on the domain (meshes, grids, point clouds), its LP is within
  :data:`~solvers.transport.exact.MAX_SUPPORT_PRODUCT` entries and its modelled time
  (:func:`~solvers.transport.exact.exact_route_estimate`) is at most
  :data:`EXACT_BUDGET_SECONDS`; else ``"convolutional"``;
* **regularization** of the convolutional method — ``gamma``, ``t``, ``substeps``,
  ``debiased`` from :func:`solvers.regularization.choose_regularization` (``purpose=
  "values"``).

It is a pure function of the masses and of the domain's
:class:`~solvers.domains.sketch.DomainSketch` (sizes, unit-area coordinates, edges): every
cost model has constants calibrated once offline (``bench/distance_routes.py calibrate``) and
committed; nothing reads the clock, the load or timings measured in the process, and no
operator is built.  The same request therefore gets the same decision in the library, in the
API process and in any worker, now and after a re-run; a run that overruns its time limit
fails as such and never switches method.  Coverage of the exact method (which meshes and bump
sizes it takes) and the accuracy of the default: ``bench/results/distance_routes.md``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from solvers.errors import InputError
from solvers.regularization import (
    APPLICATIONS,
    SOLVE_SECONDS_PER_VERTEX,
    Regularization,
    choose_regularization,
    sketch_of,
)
from solvers.transport.exact import (
    MAX_SUPPORT_PRODUCT,
    exact_route_estimate,
    exact_route_upper_bound,
    supports_exact,
)
from solvers.validation import check_choice

METHODS = ("auto", "convolutional", "exact")
# The exact method is taken when its modelled time (one core of the 2-core machine, load ~1)
# is at most this: 25 + 25 point masses on every shared mesh and the bumps of the meshes
# listed in bench/results/distance_routes.md fit; at twice the time (a loaded machine) a
# run stays inside the service's default job limit of 600 s.
EXACT_BUDGET_SECONDS = 120.0


@dataclass(frozen=True)
class DistanceDecision:
    """What a distance will run, taken before it runs (stored with a job, executed as is).

    Attributes
    ----------
    method : str
        ``"exact"`` or ``"convolutional"``.
    reason : str
        Why this method.
    gamma, t, substeps, debiased : float, float, int, bool or None
        The convolutional method's regularization (None on the exact method).
    estimated_seconds : float or None
        The cost model of the chosen method (None where there is none).
    exact_seconds : float or None
        The exact method's modelled seconds (None where unavailable).
    regularization : Regularization or None
        The policy's choice and its reason (None when gamma was given or on the exact
        method).
    """

    method: str
    reason: str
    gamma: float | None = None
    t: float | None = None
    substeps: int | None = None
    debiased: bool | None = None
    estimated_seconds: float | None = None
    exact_seconds: float | None = None
    regularization: Regularization | None = None

    def as_dict(self) -> dict:
        """JSON-ready (stored with a job; floats round-trip exactly through JSON)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> DistanceDecision:
        """The decision :meth:`as_dict` wrote.

        Parameters
        ----------
        data : dict
            Its fields, ``regularization`` as a dict or None.

        Returns
        -------
        DistanceDecision
        """
        reg = data.get("regularization")
        return cls(**{**data, "regularization": None if reg is None else Regularization(**reg)})

    def solver_arguments(self) -> dict:
        """The explicit arguments of ``wasserstein_distance`` that execute this decision."""
        if self.method == "exact":
            return {"method": "exact"}
        return {"method": "convolutional", "gamma": self.gamma, "t": self.t,
                "substeps": self.substeps, "debiased": self.debiased}


def convolutional_seconds(sketch, substeps: int) -> float | None:
    """Modelled seconds of a debiased convolutional distance (``APPLICATIONS`` kernel
    applications of ``substeps`` solves, regularization module); None on grids (separable
    Gaussian kernels, not modelled)."""
    if sketch.supports("exact_heat_kernel"):
        return None
    return APPLICATIONS * SOLVE_SECONDS_PER_VERTEX * float(sketch.n) * int(substeps)


def decide_distance(domain, mu0, mu1, *, method: str = "auto", gamma="auto", t=None,
                    substeps=None, debiased=None) -> DistanceDecision:
    """The decision of ``wasserstein_distance(domain, mu0, mu1, method=..., gamma=..., t=...,
    substeps=..., debiased=...)`` (module docstring).

    Explicit arguments win: ``method="exact"`` always takes the exact method, a numeric
    ``gamma`` always the convolutional one as specified (one substep, not debiased unless
    given).

    Parameters
    ----------
    domain : domain or DomainSketch
        The domain, or its :class:`~solvers.domains.sketch.DomainSketch`.
    mu0, mu1 : ndarray
        Normalized ``(n,)`` masses.
    method : str
        ``"auto"``, ``"exact"`` or ``"convolutional"``.
    gamma : float or "auto"
        The convolutional method's regularization (``"auto"``: the policy's).
    t, substeps, debiased : float, int, bool or None
        The convolutional method's heat time, substeps and debiasing (None: the policy's).

    Returns
    -------
    DistanceDecision
    """
    check_choice(method, METHODS, "method")
    auto = gamma is None or (isinstance(gamma, str) and gamma == "auto")
    if not auto and not isinstance(gamma, (int, float, np.number)) or isinstance(gamma, bool):
        raise InputError(f"gamma must be a positive number or 'auto', got {gamma!r}",
                         field="gamma")
    sketch = sketch_of(domain)
    m0, m1 = np.asarray(mu0, dtype=np.float64), np.asarray(mu1, dtype=np.float64)
    exact = None
    n0, n1 = int(np.count_nonzero(m0)), int(np.count_nonzero(m1))
    wanted = method == "exact" or (method == "auto" and auto)
    if wanted and supports_exact(sketch) and n0 * n1 <= MAX_SUPPORT_PRODUCT:
        exact = float(exact_route_estimate(sketch, m0, m1,
                                           budget=None if method == "exact" else
                                           EXACT_BUDGET_SECONDS))
    if method == "exact":
        return DistanceDecision("exact", "route 'exact' requested", estimated_seconds=exact,
                                exact_seconds=exact)
    if method == "auto" and auto and exact is not None and exact <= EXACT_BUDGET_SECONDS:
        return DistanceDecision("exact", f"exact route estimated at {exact:.3g} s, within "
                                f"its {EXACT_BUDGET_SECONDS:.0f} s budget",
                                estimated_seconds=exact, exact_seconds=exact)
    if auto:
        reg = choose_regularization(sketch, m0, m1, purpose="values", t=t,
                                    substeps=substeps, debiased=debiased)
        why = _convolutional_reason(sketch, method, exact, n0 * n1)
        return DistanceDecision("convolutional", why, reg.gamma, reg.t, reg.substeps,
                                reg.debiased, convolutional_seconds(sketch, reg.substeps),
                                exact, reg)
    gamma = float(gamma)  # an explicit gamma: Alg. 1 as specified
    steps = 1 if substeps is None else int(substeps)
    return DistanceDecision("convolutional", "gamma given", gamma,
                            None if t is None else float(t), steps,
                            False if debiased is None else bool(debiased),
                            convolutional_seconds(sketch, steps), exact)


def decide_method(sketch, m0, m1, *, method: str = "auto", gamma="auto", t=None, substeps=None,
                 debiased=None) -> DistanceDecision:
    """:func:`decide_distance`'s method and regularization, taken without planning the exact
    method when its size-only upper bound (:func:`~solvers.transport.exact.
    exact_route_upper_bound`) already fits :data:`EXACT_BUDGET_SECONDS` (then the estimate
    fits too: the same method; ``estimated_seconds`` is that bound).  Many decisions on small
    supports (a distance matrix) skip the planning LP this way."""
    auto = gamma is None or (isinstance(gamma, str) and gamma == "auto")
    if method == "auto" and auto and supports_exact(sketch):
        n0, n1 = int(np.count_nonzero(m0)), int(np.count_nonzero(m1))
        if n0 * n1 <= MAX_SUPPORT_PRODUCT:
            bound = float(exact_route_upper_bound(sketch, m0, m1))
            if bound <= EXACT_BUDGET_SECONDS:
                return DistanceDecision("exact", f"exact route bounded by {bound:.3g} s, "
                                        f"within its {EXACT_BUDGET_SECONDS:.0f} s budget",
                                        estimated_seconds=bound)
    return decide_distance(sketch, m0, m1, method=method, gamma=gamma, t=t, substeps=substeps,
                           debiased=debiased)


def _convolutional_reason(sketch, method: str, exact: float | None, entries: int) -> str:
    if method == "convolutional":
        return "route 'convolutional' requested"
    if exact is None and entries <= MAX_SUPPORT_PRODUCT and supports_exact(sketch):
        return "gamma given"
    if not supports_exact(sketch):
        return f"no exact route on {sketch.kind} domains"
    if exact is None:
        return (f"the exact route's LP would have {entries} entries, above its limit of "
                f"{MAX_SUPPORT_PRODUCT}")
    return (f"exact route estimated at {exact:.3g} s, above its {EXACT_BUDGET_SECONDS:.0f} s "
            "budget")
