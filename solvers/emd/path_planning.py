r"""Path planning by W1 (thesis §2.7, eq. 2.6).

Occupants with density :math:`\rho_0` leave through a set of exits :math:`S`:

.. math::
    \inf_{\rho_1} \; W_1(\rho_0, \rho_1) + \varepsilon \int \rho_1^2
    \quad\text{s.t.}\quad \rho_1 \ge 0,\ \operatorname{supp}\rho_1 \subseteq S,\
    \int \rho_1 = 1 .

With :math:`\varepsilon = 0` every unit of mass goes to its nearest exit (the value is
:math:`\int d(x, S)\, \rho_0`); :math:`\varepsilon > 0` spreads the arrivals over the exits
(congestion).  In Beckmann form (eq. 2.3) this is one convex program in the face flow
:math:`J` and the exit masses :math:`m_1 = A\rho_1` (lumped vertex areas :math:`A`):

.. math::
    \min_{J,\ m_1 \ge 0 \text{ on } S} \sum_t w_t A_t \lVert J_t\rVert
    + \varepsilon \sum_{v\in S} m_{1,v}^2 / A_v
    \quad\text{s.t.}\quad \operatorname{div} J = m_0 - m_1 ,

solved by the primal-dual interior point of :mod:`solvers.emd.interior_point_exits`
(vertex-sized Newton systems, any mesh size) or by Clarabel (the whole second-order cone
QP, small meshes: the reference the interior point is tested against).  The flow and its
Hodge decomposition :math:`J = \nabla f + R\nabla g` (:mod:`solvers.emd.hodge`) are what
Fig. 2.12 shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.domains import supports
from solvers.emd.exact import (
    MAX_VERTICES,
    _check_mesh,
    _ConicProgram,
    _converged,
    _face_weights,
    _masses,
)
from solvers.emd.flow_geometry import flow_cost, flow_geometry, flow_vectors
from solvers.emd.hodge import HodgeDecomposition, hodge_decomposition
from solvers.errors import InputError, UnsupportedDomainError
from solvers.monitor import Monitor, SolverResult
from solvers.validation import check_choice


@dataclass
class PathPlanningResult(SolverResult):
    r"""Eq. 2.6: ``value`` = W1(rho0, rho1) of the returned flow, ``objective`` = value +
    ε ∫ρ1², ``target_masses`` (V,) the arrivals m1 (zero off the exits), ``flow`` J (F, 3)
    from rho0 to the exits, ``potential`` (V,) the dual of ``div J = m0 - m1`` (with ε = 0,
    ``value == potential @ (m1 - m0)``), ``hodge`` the decomposition J = ∇f + R∇g + h.
    ``residual`` is the max violation of the divergence constraint.

    Attributes
    ----------
    value : float
        :math:`W_1(\rho_0, \rho_1)` of the returned flow.
    objective : float
        ``value`` + :math:`\varepsilon \int \rho_1^2`.
    target_masses : (V,) array
        The arrivals :math:`m_1` (zero off the exits).
    flow : (F, 3) array
        The flow :math:`J` from :math:`\rho_0` to the exits.
    potential : (V,) array
        Dual of ``div J = m0 - m1``.
    hodge : HodgeDecomposition
        :math:`J = \nabla f + R\nabla g + h`.
    status : str
        The solver's final status.
    solve_time : float
        Seconds of the solve.
    method : {"ipm", "socp"}
        The solver that ran.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    value: float
    objective: float
    target_masses: np.ndarray
    flow: np.ndarray
    potential: np.ndarray
    hodge: HodgeDecomposition
    status: str
    solve_time: float
    method: str


def _target_mask(mesh, targets, m0) -> np.ndarray:
    return check_targets(targets, mesh.n, mesh.component_labels, m0)


def check_targets(targets, n: int, labels, m0, field: str = "targets") -> np.ndarray:
    """The exits as a (n,) boolean mask, from vertex indices or a (n,) boolean mask: at least
    one, in range, and one on every connected component (``labels``) where ``m0`` has mass
    (mass cannot leave its component).  The service checks requests with it at submission."""
    t = np.asarray(targets)
    mask = np.zeros(n, dtype=bool)
    if t.dtype == bool:
        if t.shape != (n,):
            raise InputError(f"a boolean targets mask must have shape ({n},)", field=field)
        mask = t.copy()
    else:
        idx = np.asarray(t, dtype=np.int64).ravel()
        if idx.size and (idx.min() < 0 or idx.max() >= n):
            raise InputError(f"targets must be vertex indices in [0, {n - 1}]", field=field)
        mask[idx] = True
    if not mask.any():
        raise InputError("targets must name at least one vertex", field=field)
    labels = np.asarray(labels)
    n_components = int(labels.max()) + 1 if len(labels) else 1
    reachable = np.bincount(labels[mask], minlength=n_components) > 0
    stranded = np.bincount(labels, np.asarray(m0), minlength=n_components)[~reachable]
    if np.any(stranded > 0):
        raise InputError("rho0 has mass on a connected component without any target vertex",
                         field=field)
    return mask


METHODS = ("auto", "ipm", "socp")
# Interior-point defaults: certified relative gap and iteration cap.
IPM_TOL = 1e-6
IPM_MAX_ITER = 100


def w1_path_planning(
    mesh,
    rho0,
    targets,
    *,
    epsilon: float = 0.0,
    face_weights=None,
    method: str = "auto",
    tol: float | None = None,
    max_iter: int | None = None,
    max_vertices: int = MAX_VERTICES,
    time_limit: float | None = None,
    progress=None,
    should_cancel=None,
) -> PathPlanningResult:
    r"""Path planning, thesis eq. (2.6): :math:`\inf_{\rho_1} W_1(\rho_0,\rho_1) +
    \varepsilon\int\rho_1^2` over :math:`\rho_1 \ge 0` of unit mass supported on the
    targets (module docstring).

    Parameters
    ----------
    mesh : TriangleMesh.
    rho0 : (V,) masses of the occupants (non-negative, normalized to sum 1).
    targets : vertex indices of the exits S, or a (V,) boolean mask.
    epsilon : weight ε >= 0 of the congestion term ∫ρ1² (ρ1 = m1 / A per vertex).
    face_weights : optional (F,) travel cost per unit length (``np.inf`` = wall).
    method : ``"auto"`` (``"ipm"`` unless a face weight is infinite), ``"ipm"`` (the
        primal-dual interior point with vertex-sized Newton systems of
        :mod:`solvers.emd.interior_point_exits`, any mesh size; ``tol`` is the certified
        relative duality gap, default ``IPM_TOL``) or ``"socp"`` (Clarabel on the whole
        program, at most ``max_vertices`` vertices; default ``tol`` 1e-8).
    tol : ``"ipm"``: certified relative duality gap (default ``IPM_TOL``); ``"socp"``:
        the conic solver's tolerance (default 1e-8).
    max_iter : iteration cap (default ``IPM_MAX_ITER`` / 200).
    max_vertices : largest mesh of the ``"socp"`` route.
    time_limit : wall-time cap (s) of the ``"socp"`` route.
    progress, should_cancel : as in :func:`solvers.emd.exact.beckmann_w1_exact`.

    Returns
    -------
    PathPlanningResult (value, objective, target_masses (V,), flow (F, 3), potential (V,),
    hodge, method).
    """
    check_choice(method, METHODS, "method")
    if not supports(mesh, "faces"):
        raise UnsupportedDomainError("path planning needs a TriangleMesh domain",
                                     field="domain")
    m0 = _masses(mesh, rho0, "rho0")
    if m0.ndim != 1:
        raise InputError("rho0 must be a single (V,) distribution", field="rho0")
    mask = _target_mask(mesh, targets, m0)
    eps = float(epsilon)
    if not (np.isfinite(eps) and eps >= 0):
        raise InputError("epsilon must be a finite number >= 0", field="epsilon")
    fw = _face_weights(mesh, face_weights)
    if method == "auto":
        method = "ipm" if np.all(np.isfinite(fw)) else "socp"
    if method == "ipm" and not np.all(np.isfinite(fw)):
        raise InputError("method='ipm' needs finite face_weights; use 'socp' for walls",
                         field="method")
    Monitor(progress, should_cancel).check_cancel("before the solve")
    solve = _solve_ipm if method == "ipm" else _solve_socp
    if method == "socp":
        _check_mesh(mesh, max_vertices)
    out = solve(mesh, m0, mask, eps, fw, tol, max_iter, time_limit, progress, should_cancel)
    target = out["target"]
    exits = np.flatnonzero(mask)
    return PathPlanningResult(
        value=out["value"],
        objective=out["value"] + eps * float(np.sum(target[exits] ** 2 / mesh.areas[exits])),
        target_masses=target,
        flow=out["flow"],
        potential=out["potential"],
        hodge=hodge_decomposition(mesh, out["flow"]),
        iterations=out["iterations"],
        residual=out["residual"],
        converged=out["converged"],
        status=out["status"],
        solve_time=out["solve_time"],
        method=method,
    )


def _kept_rows(mesh, mask) -> np.ndarray:
    """All divergence rows but one per component without targets (those are redundant)."""
    labels = mesh.component_labels
    _, first = np.unique(labels, return_index=True)
    has_target = np.bincount(labels[mask], minlength=mesh.n_components) > 0
    return np.setdiff1d(np.arange(mesh.n), first[~has_target])


def _solve_socp(mesh, m0, mask, eps, fw, tol, max_iter, time_limit, progress, should_cancel):
    geo = flow_geometry(mesh, fw)
    keep = _kept_rows(mesh, mask)
    exits = np.flatnonzero(mask)
    prog = _ConicProgram()
    flow = prog.flow_block(geo)
    m1 = prog.variables(len(exits))
    if eps > 0:
        prog.quadratic(m1, 2.0 * eps / mesh.areas[exits])
    place = sp.csr_matrix((np.ones(len(exits)), (exits, np.arange(len(exits)))),
                          shape=(mesh.n, len(exits)))
    prog.constrain("eq", [(flow, geo.div[keep]), (m1, place[keep])], m0[keep])
    prog.constrain("nonneg", [(m1, -sp.identity(len(exits), format="csr"))],
                   np.zeros(len(exits)))
    x, z, iterations, status, elapsed = prog.solve(
        1e-8 if tol is None else tol, 200 if max_iter is None else int(max_iter), time_limit,
        progress, should_cancel)
    target = np.zeros(mesh.n)
    target[exits] = np.clip(x[m1], 0.0, None)
    xb = x[flow]
    potential = np.zeros(mesh.n)
    potential[keep] = z[: len(keep)]
    return {"value": flow_cost(geo, xb), "target": target,
            "flow": flow_vectors(mesh, geo, xb), "potential": potential,
            "iterations": iterations, "status": status, "converged": _converged(status),
            "residual": float(np.abs(geo.div @ xb - (m0 - target)).max()),
            "solve_time": elapsed}


def _ipm_start(mesh, ops, m0, exits):
    """A strictly feasible start: each component's mass spread evenly over its exits (exits
    on components without mass are dropped: they receive nothing), the Poisson flow that
    carries it, and ``y = -δ`` on components with exits."""
    labels = ops.labels
    comp_mass = np.bincount(labels, m0, minlength=mesh.n_components)
    exits = exits[comp_mass[labels[exits]] > 0]
    count = np.bincount(labels[exits], minlength=mesh.n_components)
    m_start = comp_mass[labels[exits]] / count[labels[exits]]
    arrivals = np.zeros(mesh.n)
    arrivals[exits] = m_start
    _, v = ops.particular_flow(arrivals - m0)
    geo, _ = ops.interior_point_structure
    u0 = np.einsum("fc,fdc->fd", v, geo.frames) * mesh.face_areas[:, None]
    scale = max(float(np.linalg.norm(u0, axis=1).sum()), 1e-12)
    y = np.where(count[labels] > 0, -scale, 0.0)
    return exits, m_start, u0, y


def _solve_ipm(mesh, m0, mask, eps, fw, tol, max_iter, time_limit, progress, should_cancel):
    import time

    from solvers.emd.beckmann import IPM_PATIENCE
    from solvers.emd.interior_point import normal_structure
    from solvers.emd.interior_point_exits import exits_interior_point
    from solvers.emd.operators import mesh_operators

    start = time.perf_counter()
    ops = mesh_operators(mesh)
    exits, m_start, u0, y0 = _ipm_start(mesh, ops, m0, np.flatnonzero(mask))
    used = np.zeros(mesh.n, dtype=bool)
    used[exits] = True
    keep = _kept_rows(mesh, used)
    geo, _ = ops.interior_point_structure
    st = normal_structure(geo.div, np.asarray(mesh.faces), keep)
    tol = IPM_TOL if tol is None else float(tol)
    monitor = Monitor(progress, should_cancel, tol=tol, patience=IPM_PATIENCE)
    out = exits_interior_point(geo.div, st, fw, m0, exits, 2.0 * eps / mesh.areas[exits], u0,
                               m_start, y0, tol,
                               IPM_MAX_ITER if max_iter is None else int(max_iter), monitor)
    target = np.zeros(mesh.n)
    target[exits] = out.m
    flow = np.einsum("fd,fdc->fc", out.u, geo.frames) / mesh.face_areas[:, None]
    return {"value": float(fw @ np.linalg.norm(out.u, axis=1)), "target": target,
            "flow": flow, "potential": -out.y, "iterations": out.iterations,
            "status": "Solved" if out.converged else "NotConverged",
            "converged": out.converged, "residual": out.feasibility,
            "solve_time": time.perf_counter() - start}
