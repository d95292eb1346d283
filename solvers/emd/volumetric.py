r"""Volumetric earth mover's distances inside (and around) a closed surface (thesis §2.6).

A point :math:`x` in space is represented on the boundary mesh by its mean value
coordinates :math:`w(x)` (Ju, Schaefer & Warren 2005): weights on the vertices with
:math:`\sum_i w_i(x) = 1` and :math:`\sum_i w_i(x)\,p_i = x`.  The volumetric distance is
the W1 distance between these boundary distributions,

.. math::
    d(x, y) = \lVert w(x) - w(y)\rVert_{KR}
            = \min_J \sum_t A_t\lVert J_t\rVert \ \text{s.t.}\ \operatorname{div}J = w(x) - w(y),

computed with the Beckmann solvers of chapter 2.  Mean value coordinates are positive
inside convex shapes but may be negative in concave regions; Beckmann's problem only
depends on the (balanced) difference, so :math:`d` is the Kantorovich–Rubinstein norm and
stays a metric for signed weights.  Because linear functions restricted to the surface
are feasible dual potentials, :math:`d(x, y) \ge \lVert x - y\rVert` always.

Units: points and distances are in the mesh's normalized frame (``mesh.vertices``,
unit total area) unless ``units="input"`` is passed, in which case points are in the
coordinates of the loaded file (distances stay normalized; multiply by
``mesh.length_scale`` to convert).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.domains import supports
from solvers.domains.mesh import TriangleMesh
from solvers.emd.beckmann import earth_movers_distance
from solvers.emd.exact import MAX_VERTICES, kantorovich_rubinstein_norm
from solvers.errors import InputError, UnsupportedDomainError
from solvers.monitor import Monitor, SolverResult
from solvers.validation import check_choice

# Points closer than this (relative to the mean edge length) to a vertex or to the
# plane of a face they lie in are treated as on the surface.
_EPS = 1e-9
_CHUNK_ENTRIES = 4_000_000  # points x faces per vectorized block


@dataclass
class VolumetricDistanceResult(SolverResult):
    """``value`` = d(x, y); ``weights_x``, ``weights_y`` (V,) mean value coordinates;
    ``potential`` (V,) optimal Kantorovich potential, ``value == potential @ (w_y - w_x)``.

    Attributes
    ----------
    value : float
        :math:`d(x, y)`.
    weights_x, weights_y : (V,) array
        Mean value coordinates of the two points.
    potential : (V,) array
        Optimal Kantorovich potential.
    method : str
        The W1 solver that ran.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    value: float
    weights_x: np.ndarray
    weights_y: np.ndarray
    potential: np.ndarray
    method: str = "exact"


@dataclass
class VolumetricFieldResult(SolverResult):
    """Distances (P,) from one ``source`` point to each of ``points``; ``iterations`` sums
    the solver iterations, ``residual`` is the largest solver residual.

    Attributes
    ----------
    distances : (P,) array
        Distance to each point.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    distances: np.ndarray


@dataclass
class VolumetricPathResult(SolverResult):
    """Gradient-descent path from ``start`` towards ``target``: ``points`` (K, 3) and the
    distances (K,) to the target along it; ``converged`` when the last step reached
    the target within ``step``.

    Attributes
    ----------
    points : (K, 3) array
        The path.
    distances : (K,) array
        Distance to the target along it.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    points: np.ndarray
    distances: np.ndarray


# ---------------------------------------------------------------------------
# mean value coordinates
# ---------------------------------------------------------------------------
def _check_closed_mesh(mesh) -> None:
    if not supports(mesh, "faces"):
        raise UnsupportedDomainError("volumetric distances need a TriangleMesh", field="domain")
    if not mesh.is_closed:
        raise UnsupportedDomainError(
            "mean value coordinates need a closed (watertight) surface; this mesh has "
            f"{mesh.diagnostics.boundary_edges} boundary edges", field="domain")


def _points(mesh: TriangleMesh, points, units: str) -> np.ndarray:
    check_choice(units, ("mesh", "input"), "units")
    try:
        x = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"points must be numeric: {exc}", field="points") from exc
    if x.ndim == 1:
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
        raise InputError(f"points must have shape (P, 3), got {np.shape(points)}",
                         field="points")
    if not np.all(np.isfinite(x)):
        raise InputError("points contain NaN or infinite coordinates", field="points")
    return x / mesh.length_scale if units == "input" else x


def _corner_incidence(mesh: TriangleMesh) -> list[sp.csr_matrix]:
    nf = mesh.n_faces
    return [sp.csr_matrix((np.ones(nf), (np.arange(nf), mesh.faces[:, k])),
                          shape=(nf, mesh.n)) for k in range(3)]


def _mvc_block(mesh: TriangleMesh, x: np.ndarray, incidence) -> np.ndarray:
    """Mean value coordinates (P, V) of a block of points; robust formula of JSW 2005."""
    v, f = mesh.vertices, mesh.faces
    eps_d = _EPS * mesh.mean_edge_length
    diff = v[None, :, :] - x[:, None, :]  # (P, V, 3)
    d = np.linalg.norm(diff, axis=2)  # (P, V)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = diff / d[:, :, None]
    U = [u[:, f[:, k]] for k in range(3)]  # (P, F, 3) each
    D = [d[:, f[:, k]] for k in range(3)]  # (P, F)
    theta = []
    for k in range(3):
        chord = np.linalg.norm(U[(k + 1) % 3] - U[(k + 2) % 3], axis=2)
        theta.append(2.0 * np.arcsin(np.clip(0.5 * chord, 0.0, 1.0)))
    h = 0.5 * (theta[0] + theta[1] + theta[2])
    sin_t = [np.sin(t) for t in theta]
    det = np.einsum("pfc,pfc->pf", U[0], np.cross(U[1], U[2]))
    sign = np.where(det < 0, -1.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = [2.0 * np.sin(h) * np.sin(h - theta[k]) / (sin_t[(k + 1) % 3] * sin_t[(k + 2) % 3])
             - 1.0 for k in range(3)]
        s = [sign * np.sqrt(np.clip(1.0 - ck**2, 0.0, None)) for ck in c]
        w = []
        for k in range(3):
            k1, k2 = (k + 1) % 3, (k + 2) % 3
            w.append((theta[k] - c[k1] * theta[k2] - c[k2] * theta[k1])
                     / (D[k] * sin_t[k1] * s[k2]))
    # faces seen edge-on (x in their plane, outside them) contribute nothing
    ignore = (np.abs(s[0]) <= _EPS) | (np.abs(s[1]) <= _EPS) | (np.abs(s[2]) <= _EPS)
    W = np.zeros((len(x), mesh.n))
    for k in range(3):
        wk = np.where(ignore | ~np.isfinite(w[k]), 0.0, w[k])
        W += (incidence[k].T @ wk.T).T
    # x on a face (h == pi): barycentric coordinates of that face only
    on_face = np.pi - h < _EPS
    for p in np.flatnonzero(on_face.any(axis=1)):
        t = int(np.flatnonzero(on_face[p])[0])
        bary = np.array([sin_t[k][p, t] * D[(k + 2) % 3][p, t] * D[(k + 1) % 3][p, t]
                         for k in range(3)])
        W[p] = 0.0
        W[p, f[t]] = bary
    # x at a vertex: the Dirac there
    for p in np.flatnonzero((d < eps_d).any(axis=1)):
        W[p] = 0.0
        W[p, int(np.argmin(d[p]))] = 1.0
    totals = W.sum(axis=1)
    if np.any(~np.isfinite(totals)) or np.any(np.abs(totals) < 1e-300):
        raise InputError("mean value coordinates are undefined at some points",
                         field="points")
    return W / totals[:, None]


def mean_value_coordinates(mesh: TriangleMesh, points, *, units: str = "mesh") -> np.ndarray:
    r"""Mean value coordinates of points with respect to a closed triangle mesh.

    Ju, Schaefer & Warren, *Mean value coordinates for closed triangular meshes*
    (SIGGRAPH 2005), robust evaluation (their Fig. 8), vectorized over points x faces.
    For every point x: :math:`\sum_i w_i = 1` and :math:`\sum_i w_i p_i = x` (linear
    precision, inside and outside the surface); :math:`w_i > 0` inside convex shapes.
    Points on a face get that face's barycentric coordinates, points at a vertex its
    Dirac.

    Parameters
    ----------
    mesh : closed TriangleMesh.
    points : (P, 3) or (3,) positions (``mesh.vertices`` frame, or the file's with
        ``units="input"``).
    units : ``"mesh"`` or ``"input"``, the frame of ``points``.

    Returns
    -------
    (P, V) array of weights, rows summing to 1.
    """
    _check_closed_mesh(mesh)
    x = _points(mesh, points, units)
    incidence = _corner_incidence(mesh)
    step = max(1, _CHUNK_ENTRIES // max(mesh.n_faces, 1))
    return np.vstack([_mvc_block(mesh, x[i:i + step], incidence)
                      for i in range(0, len(x), step)])


def winding_number(mesh: TriangleMesh, points, *, units: str = "mesh") -> np.ndarray:
    r"""Generalized winding number (P,): :math:`\frac1{4\pi}\sum_t \Omega_t(x)` with the signed
    solid angles of Van Oosterom & Strackee; about 1 inside, 0 outside a closed,
    outward-oriented surface (negative for inward orientation).

    Parameters
    ----------
    mesh : TriangleMesh
        A closed surface.
    points : (P, 3) or (3,) array
        Positions (``mesh.vertices`` frame, or the file's with ``units="input"``).
    units : {"mesh", "input"}
        Frame of ``points``.

    Returns
    -------
    (P,) array
    """
    x = _points(mesh, points, units)
    v, f = mesh.vertices, mesh.faces
    out = np.empty(len(x))
    step = max(1, _CHUNK_ENTRIES // max(mesh.n_faces, 1))
    for i in range(0, len(x), step):
        xb = x[i:i + step]
        a, b, c = (v[f[:, k]][None] - xb[:, None] for k in range(3))
        la, lb, lc = (np.linalg.norm(q, axis=2) for q in (a, b, c))
        num = np.einsum("pfc,pfc->pf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pfc,pfc->pf", a, b) * lc
               + np.einsum("pfc,pfc->pf", b, c) * la + np.einsum("pfc,pfc->pf", c, a) * lb)
        out[i:i + step] = (2.0 * np.arctan2(num, den)).sum(axis=1) / (4.0 * np.pi)
    return out


# ---------------------------------------------------------------------------
# distances and paths
# ---------------------------------------------------------------------------
def _kr_distance(mesh, difference, method, tol, max_iter, max_vertices, basis="flow"):
    """(value, potential, iterations, residual, converged) of ||difference||_KR."""
    if method == "exact":
        tol = 1e-8 if tol is None else tol
        res = kantorovich_rubinstein_norm(mesh, difference, tol=tol, max_iter=max_iter or 200,
                                          max_vertices=max_vertices)
        return res.value, res.potential, res.iterations, res.residual, res.converged
    if method == "admm":
        pos = np.clip(difference, 0.0, None)
        neg = np.clip(-difference, 0.0, None)
        mass = pos.sum()
        if mass <= 0:
            return 0.0, np.zeros(mesh.n), 0, 0.0, True
        kwargs = {"method": "admm", "basis": basis}
        if tol is not None:
            kwargs["tol"] = tol
        if max_iter is not None:
            kwargs["max_iter"] = max_iter
        res = earth_movers_distance(mesh, pos / mass, neg / mass, **kwargs)
        return (mass * float(res.value), np.asarray(res.potential), int(res.iterations),
                float(res.residual), bool(res.converged))
    raise InputError(f"method must be 'exact' or 'admm', got {method!r}", field="method")


def volumetric_distance(
    mesh: TriangleMesh,
    x,
    y,
    *,
    method: str = "exact",
    basis: str = "flow",
    units: str = "mesh",
    tol: float | None = None,
    max_iter: int | None = None,
    max_vertices: int = MAX_VERTICES,
) -> VolumetricDistanceResult:
    r"""Volumetric W1 distance between two points in space (thesis §2.6).

    :math:`d(x, y) = \lVert w(x) - w(y)\rVert_{KR}` with :math:`w` the mean value
    coordinates on the closed boundary mesh.  ``method="exact"`` solves the Beckmann
    SOCP (:mod:`solvers.emd.exact`, at most ``max_vertices``); ``"admm"`` uses
    :func:`solvers.emd.earth_movers_distance` on the positive and negative parts, with
    its flow ``basis`` (default ``"flow"``: all piecewise-constant flows, the same
    discrete problem as the exact solver; ``"full"``/``"spectral"`` restrict the flows
    and give larger values — measured +4 % on a torus).
    ``potential`` is the optimal Kantorovich potential: ``value == potential @ (w_y - w_x)``.

    Parameters
    ----------
    mesh : TriangleMesh
        The closed boundary surface (``V`` vertices).
    x, y : (3,) array
        The two points.
    method : {"exact", "admm"}
        The W1 solver.
    basis : str
        Flow basis of ``"admm"`` (:func:`~solvers.emd.earth_movers_distance`).
    units : {"mesh", "input"}
        Frame of the points: ``mesh.vertices``, or the file's.
    tol, max_iter : float, int, optional
        The W1 solver's stopping rule.
    max_vertices : int
        Largest mesh of ``"exact"``.

    Returns
    -------
    VolumetricDistanceResult
    """
    _check_closed_mesh(mesh)
    pts = np.vstack([_points(mesh, x, units), _points(mesh, y, units)])
    if len(pts) != 2:
        raise InputError("x and y must be single points (3,)", field="x")
    W = mean_value_coordinates(mesh, pts)
    value, potential, iterations, residual, converged = _kr_distance(
        mesh, W[0] - W[1], method, tol, max_iter, max_vertices, basis)
    return VolumetricDistanceResult(value=value, weights_x=W[0], weights_y=W[1],
                                    potential=potential, iterations=iterations,
                                    residual=residual, converged=converged,
                                    method=method)


def volumetric_distances(
    mesh: TriangleMesh,
    source,
    points,
    *,
    method: str = "exact",
    basis: str = "flow",
    units: str = "mesh",
    tol: float | None = None,
    max_iter: int | None = None,
    max_vertices: int = MAX_VERTICES,
    progress=None,
    should_cancel=None,
) -> VolumetricFieldResult:
    r"""Volumetric distances :math:`d(\text{source}, y_j)` to many points (e.g. a slice grid).

    One W1 problem per point (no shortcut exists for W1 between different pairs); the
    mean value coordinates of all points are computed in one vectorized pass.
    ``progress(j, d_j)`` is called after each point, ``should_cancel()`` before each.

    Parameters
    ----------
    mesh : TriangleMesh
        The closed boundary surface (``V`` vertices).
    source : (3,) array
        The source point.
    points : (P, 3) array
        The points.
    method, basis, units, tol, max_iter, max_vertices
        As in :func:`volumetric_distance`.
    progress : callable, optional
        ``progress(j, d_j)``, after each point.
    should_cancel : callable, optional
        ``should_cancel() -> bool``, before each point.

    Returns
    -------
    VolumetricFieldResult
        ``distances`` ``(P,)``.
    """
    _check_closed_mesh(mesh)
    src = _points(mesh, source, units)
    if len(src) != 1:
        raise InputError("source must be a single point (3,)", field="source")
    pts = _points(mesh, points, units)
    w_src = mean_value_coordinates(mesh, src)[0]
    W = mean_value_coordinates(mesh, pts)
    out = np.empty(len(pts))
    iterations, residual, converged = 0, 0.0, True
    monitor = Monitor(progress, should_cancel)
    for j in range(len(pts)):
        monitor.check_cancel(f"before point {j}")
        value, _, its, res, ok = _kr_distance(mesh, w_src - W[j], method, tol, max_iter,
                                              max_vertices, basis)
        out[j] = value
        iterations += its
        residual = max(residual, float(res))
        converged = converged and ok
        monitor(j + 1, value)
    return VolumetricFieldResult(distances=out, iterations=iterations, residual=residual,
                                 converged=converged)


PATH_PATIENCE = 10


def volumetric_path(
    mesh: TriangleMesh,
    start,
    target,
    *,
    step: float | None = None,
    max_iter: int = 100,
    method: str = "exact",
    basis: str = "flow",
    units: str = "mesh",
    tol: float | None = None,
    max_vertices: int = MAX_VERTICES,
    progress=None,
    should_cancel=None,
) -> VolumetricPathResult:
    r"""Gradient-descent path on the volumetric distance to ``target`` (thesis §2.6).

    Iterates :math:`x_{k+1} = x_k - \text{step}\; g_k/\lVert g_k\rVert` with
    :math:`g_k = \nabla_x d(x, \text{target})|_{x_k} = Dw(x_k)^\top \phi_k` (envelope
    theorem: :math:`\phi_k` is the optimal Kantorovich potential, :math:`Dw` the Jacobian
    of the mean value coordinates by central differences), until the target is within
    one step.  Each iteration solves one W1 problem.  The volumetric distance is not an
    interior geodesic distance, so paths may leave a non-convex solid: between opposite
    points of a torus the descent was measured to go around the hole or through it,
    depending on mesh resolution and step.

    Parameters
    ----------
    mesh : closed TriangleMesh.
    start, target : (3,) points.
    step : step length (default: the mean edge length).
    method, basis, units, tol, max_vertices : W1 solver, as in
        :func:`volumetric_distance`.
    max_iter : maximum number of steps.
    progress : callable(iteration, distance) or None.
    should_cancel : callable() -> bool, polled before each step.

    Returns
    -------
    VolumetricPathResult
        ``points`` ``(K, 3)`` and the distances ``(K,)`` to the target along them.
    """
    _check_closed_mesh(mesh)
    x = _points(mesh, start, units)[0]
    y = _points(mesh, target, units)[0]
    if step is None:
        step = mesh.mean_edge_length
    if not np.isfinite(step) or step <= 0:
        raise InputError("step must be positive", field="step")
    if units == "input":
        step = step / mesh.length_scale
    w_target = mean_value_coordinates(mesh, y)[0]
    h = 1e-5 * mesh.mean_edge_length
    offsets = np.vstack([np.eye(3), -np.eye(3)]) * h
    points, distances = [x.copy()], []
    iterations = 0
    converged = False
    # The distance to the target must keep falling; PATH_PATIENCE steps without a 0.1 %
    # improvement (circling near the target, a step too large) stop the descent.
    monitor = Monitor(progress, should_cancel, patience=PATH_PATIENCE)
    for iterations in range(1, max_iter + 1):
        W = mean_value_coordinates(mesh, np.vstack([x, x + offsets]))
        value, potential, _, _, _ = _kr_distance(mesh, W[0] - w_target, method, tol, None,
                                                 max_vertices, basis)
        distances.append(value)
        monitor(iterations, value)
        if monitor.stalled:
            break
        if np.linalg.norm(x - y) <= step:
            points.append(y.copy())
            distances.append(0.0)
            converged = True
            break
        # d(x) = max_phi phi.(w_target - w(x))  =>  grad d = -Dw^T phi
        dd = -(W[1:4] - W[4:7]) @ potential / (2 * h)
        norm = np.linalg.norm(dd)
        if not np.isfinite(norm) or norm == 0:
            break
        x = x - step * dd / norm
        points.append(x.copy())
    if len(distances) < len(points):
        W = mean_value_coordinates(mesh, points[-1])
        distances.append(_kr_distance(mesh, W[0] - w_target, method, tol, None,
                                      max_vertices, basis)[0])
    return VolumetricPathResult(points=np.array(points), distances=np.array(distances),
                                iterations=iterations, residual=float(distances[-1]),
                                converged=converged)
