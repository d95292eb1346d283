r"""One policy for the entropic regularization of convolutional transport (thesis ch. 3).

Convolutional transport replaces :math:`e^{-d^2/\gamma}` by the heat kernel at
:math:`t = \gamma/4` (:func:`solvers.kernels.heat_time`, Varadhan's formula).  On a mesh the
implicit-Euler heat kernel follows :math:`e^{-d^2/4t}` out to a distance :math:`d` only when
:math:`t \gtrsim h\,d` (``h`` the mean edge length at unit area) and with enough substeps to
lose Euler's exponential tail; below that the effective cost grows almost linearly with
distance and W2² values come out far too small.  Hence two purposes:

* ``purpose="values"`` (distances): debiased Sinkhorn divergence, ``substeps =``
  :data:`VALUE_SUBSTEPS`, :math:`\gamma = c\,h\,d` with ``d`` the typical transport
  distance of the inputs, estimated cheaply by :func:`transport_distance_estimate` (an exact
  LP between few-point quantizations of the two inputs, with shortest edge paths on meshes),
  and :math:`c` = :data:`VALUE_FACTOR` (the README's expert rule).
* ``purpose="shapes"`` (barycenters, interpolations, propagation): the support of the result
  matters, not the value; :math:`\gamma = (2h)^2` (``t = h^2``, sharp) with
  :data:`SHAPE_SUBSTEPS` substeps so that mass travels along geodesics.

Every input of the policy comes from the stored domain through a
:class:`~solvers.domains.sketch.DomainSketch` (sizes, coordinates, edges: no operator is
built) and from the masses, and every constant is fixed: the same request gets the same
choice in any process.  Measured accuracy against the exact LP (squared exact geodesics):
``bench/results/distance_routes.md``.  Grids (exact Gaussian kernel) use the grid spacing for
``h``; graphs use hops (``h = 1``); point clouds ``sqrt(1/n)`` at unit area.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from solvers.domains import supports
from solvers.domains.sketch import DomainSketch
from solvers.errors import InputError
from solvers.kernels import GEODESIC_KERNEL_VERTICES, heat_time
from solvers.validation import check_choice

PURPOSES = ("values", "shapes")
# gamma = VALUE_FACTOR * h * d for values (bench/results/convolutional.md), with h at least
# VALUE_MIN_H on meshes: on the finest shared meshes (stanford-bunny h = 0.006, nefertiti
# 0.005) gamma proportional to h needs more substeps than the time budget allows and the
# debiased value came out 9-17 % low (bunny far -17 %); a floor of 0.02 gave -3 % / -2 % on
# bunny near/middle but +13 % on homer middle (h = 0.015, +7 % without the floor), so the
# floor sits below the 6k-vertex meshes (homer, fandisk, cheburashka unchanged).
VALUE_FACTOR = 2.5
VALUE_MIN_H = 0.012
# Implicit Euler needs about SUBSTEP_FACTOR * d^2 / t substeps (t = gamma / 4) before its
# kernel follows exp(-d^2 / 4t) out to the transport distance d; rounded up to a power of
# two within [VALUE_SUBSTEPS, MAX_SUBSTEPS] and lowered to fit VALUE_SECONDS.
VALUE_SUBSTEPS = 64
MAX_SUBSTEPS = 512
SUBSTEP_FACTOR = 2.0
# Time budget (modelled seconds) of a default convolutional distance; substeps are reduced
# to fit.  At 60 s nefertiti's far bump got 64 substeps and came out 13.5 % low (an earlier
# run); at 90 s it gets 256 (bench/results/distance_routes.md), well inside the service's
# 600 s job limit.
VALUE_SECONDS = 90.0
# Kernel applications of a debiased distance solve (Sinkhorn + symmetric passes, measured)
# and seconds per substep solve per mesh vertex: nefertiti (50k) took 15.5 / 31.2 / 54.4 s
# at 64 / 128 / 256 substeps (7-8e-8 per vertex, load ~3); 1e-7 keeps a margin.
APPLICATIONS = 60
SOLVE_SECONDS_PER_VERTEX = 1e-7
SHAPE_SUBSTEPS = 8
# Points per side of the quantized first pass of transport_distance_estimate.
ESTIMATE_POINTS = 8


@dataclass(frozen=True)
class Regularization:
    """The chosen ``gamma``, heat time ``t``, ``substeps`` and ``debiased`` and why.

    ``h``: the domain's length scale (mean edge length / grid spacing at unit area);
    ``distance``: the estimated typical transport distance (None for shapes);
    ``reason``: a one-line account of the choice.

    Attributes
    ----------
    gamma : float
        Entropic regularization.
    t : float
        Heat time.
    substeps : int
        Implicit Euler steps.
    debiased : bool
        Whether values are debiased.
    purpose : str
        ``"values"`` or ``"shapes"``.
    h : float
        The domain's length scale.
    distance : float or None
        Estimated typical transport distance.
    reason : str
        A one-line account of the choice.
    """

    gamma: float
    t: float
    substeps: int | None  # None: the kernel that ran has none (the geodesic kernel)
    debiased: bool
    purpose: str
    h: float
    distance: float | None
    reason: str

    def as_dict(self) -> dict:
        return asdict(self)

    def for_kernel(self, method: str) -> Regularization:
        """This choice as it ran with the shape kernel ``method``: the geodesic kernel
        (exact Gibbs kernel of squared geodesics) has no implicit-Euler substeps.

        Parameters
        ----------
        method : str
            The kernel that ran (``"geodesic"`` drops ``substeps``).
        """
        return replace(self, substeps=kernel_substeps(method, self.substeps))


def kernel_substeps(method: str, substeps: int | None) -> int | None:
    """The implicit-Euler substeps the shape kernel ``method`` runs: ``substeps`` for the
    heat kernel (``"convolutional"``), None for the geodesic kernel, which has none.

    Parameters
    ----------
    method : str
        The shape kernel (``"geodesic"`` or ``"convolutional"``).
    substeps : int or None
        The substeps chosen for the heat kernel.

    Returns
    -------
    int or None
    """
    return None if method == "geodesic" else substeps


def sketch_of(domain) -> DomainSketch:
    """``domain`` itself when it is a :class:`DomainSketch`, else its sketch.

    Parameters
    ----------
    domain : Domain or DomainSketch
        The domain, or its sketch (the same choice either way).

    Returns
    -------
    DomainSketch
    """
    return domain if isinstance(domain, DomainSketch) else DomainSketch.of(domain)


def length_scale(domain) -> float:
    """``h`` of a domain or sketch (:attr:`DomainSketch.length_scale`).

    Parameters
    ----------
    domain : Domain or DomainSketch
        Either.

    Returns
    -------
    float
    """
    return sketch_of(domain).length_scale


def quantize(points: np.ndarray, masses: np.ndarray, k: int):
    """``k`` representatives of a weighted point set (mass-weighted farthest points, each
    point's mass moved to its nearest representative): ``(indices, masses)``.

    Parameters
    ----------
    points : (n, d) array
        Positions.
    masses : (n,) array
        Their masses.
    k : int
        Number of representatives.

    Returns
    -------
    indices : (k,) int array
        The representatives.
    masses : (k,) array
        Their masses.
    """
    support = np.flatnonzero(masses > 0)
    if len(support) <= k:
        return support, masses[support]
    p, m = points[support], masses[support]
    chosen = [int(np.argmax(m))]
    dist = np.linalg.norm(p - p[chosen[0]], axis=1)
    for _ in range(k - 1):
        nxt = int(np.argmax(dist * np.sqrt(m)))
        if dist[nxt] <= 0:
            break
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(p - p[nxt], axis=1))
    reps = p[chosen]
    owner = np.argmin(((p[:, None, :] - reps[None, :, :]) ** 2).sum(axis=2), axis=1)
    return support[chosen], np.bincount(owner, weights=m, minlength=len(chosen))


def transport_distance_estimate(domain, m0: np.ndarray, m1: np.ndarray,
                                points: int = ESTIMATE_POINTS) -> float:
    r"""Cheap estimate of :math:`W_2(\mu_0, \mu_1)`: the exact LP between ``points``-point
    quantizations of the two inputs, with the sketch's ground distances
    (:meth:`DomainSketch.distances`: shortest edge paths on meshes, hops on graphs,
    straight lines otherwise).  ``domain``: a domain or its sketch.

    Parameters
    ----------
    domain : Domain or DomainSketch
        The domain, or its sketch (the same choice either way).
    m0, m1 : (n,) array
        The two distributions.
    points : int
        Points of each quantization.

    Returns
    -------
    float
    """
    import ot

    sketch = sketch_of(domain)
    if sketch.points is None:  # graphs: no coordinates; quantize by mass only
        i0 = np.argsort(m0, kind="stable")[::-1][:points]
        i1 = np.argsort(m1, kind="stable")[::-1][:points]
        w0, w1 = m0[i0], m1[i1]
    else:
        i0, w0 = quantize(sketch.points, m0, points)
        i1, w1 = quantize(sketch.points, m1, points)
    cost = sketch.distances(i0, i1) ** 2
    if not np.all(np.isfinite(cost)):  # different components: per-component masses match
        cost = np.where(np.isfinite(cost), cost, 1e6 * np.nanmax(np.where(np.isfinite(cost),
                                                                          cost, 0.0)) + 1.0)
    w0, w1 = w0 / w0.sum(), w1 / w1.sum()
    return float(math.sqrt(max(ot.emd2(w0, w1, cost), 0.0)))


def value_substeps(domain, distance: float, t: float) -> tuple[int, str]:
    """Substeps for values: ``SUBSTEP_FACTOR * d^2 / t`` rounded up to a power of two in
    ``[VALUE_SUBSTEPS, MAX_SUBSTEPS]``, lowered (not below VALUE_SUBSTEPS) until the
    estimated solve time fits ``VALUE_SECONDS``; returns ``(substeps, why)``.

    Parameters
    ----------
    domain : Domain or DomainSketch
        The domain, or its sketch (the same choice either way).
    distance : float
        Estimated transport distance :math:`d`.
    t : float
        Heat time.

    Returns
    -------
    substeps : int
    why : str
    """
    if supports(domain, "exact_heat_kernel"):  # exact Gaussian: substeps are unused
        return 1, "exact grid kernel"
    want = SUBSTEP_FACTOR * distance * distance / t
    steps = VALUE_SUBSTEPS
    while steps < want and steps < MAX_SUBSTEPS:
        steps *= 2
    per_step = APPLICATIONS * SOLVE_SECONDS_PER_VERTEX * float(domain.n)
    note = f"{SUBSTEP_FACTOR} d^2/t = {want:.0f}"
    if steps > VALUE_SUBSTEPS and steps * per_step > VALUE_SECONDS:
        while steps > VALUE_SUBSTEPS and steps * per_step > VALUE_SECONDS:
            steps //= 2
        note += f", lowered to fit the {VALUE_SECONDS:.0f} s budget"
    return steps, note


def choose_regularization(domain, m0=None, m1=None, *, purpose: str = "values",
                          gamma=None, t=None, substeps=None, debiased=None) -> Regularization:
    """The regularization policy (module docstring); explicit arguments win.

    ``m0, m1``: normalized ``(n,)`` masses (needed for ``purpose="values"`` unless ``gamma``
    is given).  ``gamma``: a number, or None/``"auto"`` for the policy's choice; ``t``,
    ``substeps``, ``debiased``: None for the policy's choice.  ``domain``: a domain or its
    :class:`DomainSketch` (the same choice either way).

    Parameters
    ----------
    domain : Domain or DomainSketch
        The domain, or its sketch (the same choice either way).
    m0, m1 : (n,) array, optional
        Normalized masses.
    purpose : {"values", "shapes"}
        What the regularization is for.
    gamma : float or "auto", optional
        Entropic regularization.
    t : float, optional
        Heat time.
    substeps : int, optional
        Implicit Euler steps.
    debiased : bool, optional
        Debias values.

    Returns
    -------
    Regularization
    """
    check_choice(purpose, PURPOSES, "purpose")
    domain = sketch_of(domain)
    h = domain.length_scale
    auto = gamma is None or (isinstance(gamma, str) and gamma == "auto")
    if isinstance(gamma, str) and not auto:
        raise InputError(f"gamma must be a positive number or 'auto', got {gamma!r}",
                         field="gamma")
    distance = None
    if purpose == "values":
        deb = True if debiased is None else bool(debiased)
        if auto:
            if m0 is None or m1 is None:
                raise InputError("gamma='auto' for values needs both distributions",
                                 field="gamma")
            distance = transport_distance_estimate(domain, np.asarray(m0), np.asarray(m1))
            h_value = max(h, VALUE_MIN_H) if domain.supports("edge_lengths") else h
            # Identical or nearly identical inputs: resolve at least a few edges.
            d_eff = max(distance, 4.0 * h_value)
            value = VALUE_FACTOR * h_value * d_eff
            why = (f"values: gamma = {VALUE_FACTOR} h d with h = {h_value:.4g}"
                   + (f" (mesh h {h:.4g} raised to {VALUE_MIN_H})" if h_value > h else "")
                   + f", estimated transport distance d = {distance:.4g}"
                   + (f" (raised to 4h = {4 * h_value:.4g})" if d_eff > distance else ""))
            if substeps is None:
                steps, note = value_substeps(domain, d_eff, heat_time(value))
                why += f"; debiased, {steps} substeps ({note})"
            else:
                steps = int(substeps)
        else:
            value = float(gamma)
            steps = VALUE_SUBSTEPS if substeps is None else int(substeps)
            why = "values: gamma given"
    else:
        steps = SHAPE_SUBSTEPS if substeps is None else int(substeps)
        deb = False if debiased is None else bool(debiased)
        if auto:
            value = (2.0 * h) ** 2
            why = f"shapes: gamma = (2h)^2 with h = {h:.4g} (t = h^2)"
        else:
            value = float(gamma)
            why = "shapes: gamma given"
    if not (value > 0 and math.isfinite(value)):
        raise InputError(f"gamma must be positive and finite, got {value!r}", field="gamma")
    tt = heat_time(value) if t is None else float(t)
    return Regularization(gamma=float(value), t=float(tt), substeps=int(steps), debiased=deb,
                          purpose=purpose, h=h, distance=distance, reason=why)


# Kernels of the shape solvers (barycenters, interpolations): "geodesic" is the Gibbs kernel of
# squared heat-method geodesics, exact in the log domain (sharp at every distance);
# "convolutional" the thesis' implicit-Euler heat kernel (Alg. 2, §3.5).
SHAPE_METHODS = ("auto", "convolutional", "geodesic")


def shape_method(domain, method: str = "auto") -> str:
    """The kernel of a shape solver: ``method`` when given, else ``"geodesic"`` where the
    domain offers it (connected triangle meshes up to ``GEODESIC_KERNEL_VERTICES`` vertices: the
    implicit-Euler kernel's exponential tail smears results along the direction of travel,
    ``bench/results/sharp_transport.md``) and ``"convolutional"`` elsewhere (on grids the
    heat kernel already is the exact Gaussian).  A function of the domain's kind and size.

    Parameters
    ----------
    domain : Domain or DomainSketch
        The domain, or its sketch (the same choice either way).
    method : str
        ``"auto"``, ``"geodesic"`` or ``"convolutional"``.

    Returns
    -------
    str
    """
    check_choice(method, SHAPE_METHODS, "method")
    available = sketch_of(domain).geodesic_kernel_available
    if method == "geodesic" and not available:
        raise InputError("method 'geodesic' is available on connected triangle meshes of at "
                         f"most {GEODESIC_KERNEL_VERTICES} vertices; use 'convolutional'",
                         field="method")
    if method == "auto":
        return "geodesic" if available else "convolutional"
    return method


def shape_regularization(domain, gamma, t, substeps) -> tuple[Regularization | None, float, int]:
    """``(policy or None, gamma, substeps)`` of the shape solvers (barycenters,
    interpolations, propagation): ``gamma="auto"`` takes the ``"shapes"`` policy; an
    explicit number runs as specified (one substep unless given).

    Parameters
    ----------
    domain : Domain or DomainSketch
        The domain, or its sketch (the same choice either way).
    gamma : float or "auto"
        Entropic regularization.
    t : float, optional
        Heat time.
    substeps : int, optional
        Implicit Euler steps.

    Returns
    -------
    policy : Regularization or None
    gamma : float
    substeps : int
    """
    if gamma is None or (isinstance(gamma, str) and gamma == "auto"):
        reg = choose_regularization(domain, purpose="shapes", t=t, substeps=substeps)
        return reg, reg.gamma, reg.substeps
    return None, gamma, 1 if substeps is None else substeps
