r"""Exact W1 (Beckmann) on triangle meshes as second-order cone programs (thesis ch. 2).

The earth mover's distance between masses :math:`m_0, m_1` on the vertices of a mesh
is computed in Beckmann's flow form (eq. 2.3), discretized with one tangent vector
:math:`J_t` per face and the weak (P1 finite-element) divergence:

.. math::
    W_1(m_0, m_1) = \min_J \sum_t A_t \lVert J_t\rVert
    \quad\text{s.t.}\quad \operatorname{div} J = m_0 - m_1 ,

where ``(div J)_i = -\sum_t A_t \nabla\phi_i|_t \cdot J_t`` is ``mesh.divergence @ J``.
Its dual is the Kantorovich–Rubinstein problem (eq. 2.1)
:math:`\max_\phi \phi^\top(m_1 - m_0)` over piecewise-linear :math:`\phi` with
:math:`\lVert\nabla\phi|_t\rVert \le 1` on every face, returned as ``potential``.
A piecewise-linear function with unit-bounded face gradients is 1-Lipschitz for the
polyhedral geodesic distance, so this discrete W1 is never above the exact linear
program with polyhedral geodesic costs; the gap is a discretization error that
shrinks under refinement.

With the substitution :math:`u_t = A_t J_t` (two coordinates in a tangent frame per
face) the problem is an SOCP: minimize :math:`\sum_t s_t` subject to linear
equalities and :math:`(s_t, u_t)` in the 3-dimensional Lorentz cone.  It is solved
to interior-point accuracy with Clarabel, which makes it the ground truth for the
iterative ADMM solver of :mod:`solvers.emd`, and lets the same machinery solve the
convex W1 problems of §2.7:

* :func:`w1_barycenter` – eq. (2.7), :math:`\min_\rho \sum_i \alpha_i W_1(\rho_i, \rho)^2`
  (here as the reference method ``method="socp"``; the default method is the vertex-sized
  interior point of :mod:`solvers.emd.interior_point_barycenter`, any mesh size),
  and :func:`w1_median`, the unsquared :math:`\sum_i \alpha_i W_1` (a geometric median);
* :func:`w1_multistep_paths` – not in the thesis: a sequence of distributions from a start
  to a goal minimizing :math:`\sum_k W_1(\mu_k, \mu_{k+1})` under per-vertex capacities,
  forbidden vertices and per-face travel costs (obstacles);
* :func:`solvers.emd.path_planning.w1_path_planning` (eq. 2.6) builds on the same
  assembler.

Clarabel's cost grows superlinearly, so every conic entry point refuses problems above
``max_vertices`` (default 5,000) mesh vertices (use :mod:`solvers.emd` beyond that), and
the coupled programs above ``MAX_BLOCK_UNKNOWNS`` vertices x blocks.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from solvers.domains import supports
from solvers.domains.mesh import TriangleMesh
from solvers.emd.beckmann import IPM_PATIENCE as W1_IPM_PATIENCE
from solvers.emd.flow_geometry import FlowGeometry, flow_cost, flow_geometry, flow_vectors
from solvers.emd.interior_point_barycenter import solve_barycenter_ipm
from solvers.errors import CancelledError, InputError, UnsupportedDomainError
from solvers.monitor import Monitor, SolverResult
from solvers.validation import check_choice, check_masses, check_weights, normalized_columns

MAX_VERTICES = 5000
# The eq. 2.7 interior point (method "ipm"): certified relative gap and iteration cap.
IPM_TOL = 1e-6
IPM_MAX_ITER = 100
BARYCENTER_METHODS = ("auto", "ipm", "socp")
# Coupled programs (barycenters, paths) factor much worse than k separate ones: cap
# vertices x (flow blocks + distribution blocks). Single-W1 timings are in
# bench/results/w1_exact.md; a coupled program costs far more than its blocks solved apart.
MAX_BLOCK_UNKNOWNS = 12000
# Relative component-mass mismatch above which mass would have to cross components.
_BALANCE_TOL = 1e-9


@dataclass
class BeckmannResult(SolverResult):
    """Exact W1 between two vertex mass vectors.

    ``flow`` is :math:`J` per face ``(F, 3)`` (tangent; flux density, mass per length),
    oriented from ``mu0`` towards ``mu1``; ``potential`` ``(V,)`` is the optimal
    Kantorovich potential, ``value == potential @ (mu1 - mu0)``, with face gradients
    of norm at most the face weight.  ``residual`` is the max-norm violation of
    ``div J = mu0 - mu1``; ``iterations`` are interior-point iterations.

    Attributes
    ----------
    value : float
        :math:`W_1` (unit-area lengths).
    flow : (F, 3) array
        The optimal flow :math:`J`.
    potential : (V,) array
        The optimal Kantorovich potential.
    status : str
        The conic solver's final status (``"Solved"``, ``"AlmostSolved"``, ...).
    solve_time : float
        Seconds of the solve.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    value: float
    flow: np.ndarray
    potential: np.ndarray
    status: str
    solve_time: float


@dataclass
class W1BarycenterResult(SolverResult):
    r"""W1 barycenter (eq. 2.7, :func:`w1_barycenter`) or median (:func:`w1_median`):
    ``masses`` ``(V,)``, the solved objective ``value`` (:math:`\sum_i \alpha_i W_1^2`
    or :math:`\sum_i \alpha_i W_1`) and the distances ``(k,)`` from the result to each
    input, with their flows ``(k, F, 3)`` (``J_i`` carries ``masses`` to input ``i``);
    ``residual`` is the largest violation of the flows' divergence constraints and
    ``method`` the solver that ran (``"ipm"`` adds a certified ``lower_bound`` and the
    relative ``gap``).

    Attributes
    ----------
    masses : (V,) array
        The barycenter (or median).
    value : float
        The solved objective.
    distances : (k,) array
        :math:`W_1` from the result to each input.
    flows : (k, F, 3) array
        The flows :math:`J_i`.
    status : str
        The conic solver's final status (``"Solved"``, ``"AlmostSolved"``, ...).
    solve_time : float
        Seconds of the solve.
    method : {"socp", "ipm"}
        The solver that ran.
    lower_bound, gap : float
        ``"ipm"``: certified lower bound and relative gap (NaN otherwise).
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    masses: np.ndarray
    value: float
    distances: np.ndarray
    flows: np.ndarray
    status: str
    solve_time: float
    method: str = "socp"
    lower_bound: float = float("nan")  # "ipm": certified lower bound of the objective
    gap: float = float("nan")  # "ipm": (value - lower_bound) / value


@dataclass
class W1MultistepResult(SolverResult):
    """Multi-step W1 chain (:func:`w1_multistep_paths`): ``masses`` ``(V, n_steps + 1)``
    from start to goal, the cost ``step_costs`` ``(n_steps,)`` of every step, their sum
    ``value`` and the step flows ``(n_steps, F, 3)``.

    Attributes
    ----------
    masses : (V, n_steps + 1) array
        The distributions from start to goal.
    value : float
        The total cost.
    step_costs : (n_steps,) array
        Cost of every step.
    flows : (n_steps, F, 3) array
        The step flows.
    status : str
        The conic solver's final status (``"Solved"``, ``"AlmostSolved"``, ...).
    solve_time : float
        Seconds of the solve.
    times : (n_steps + 1,) array
        Normalized time of each distribution, from 0 to 1.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    masses: np.ndarray
    value: float
    step_costs: np.ndarray
    flows: np.ndarray
    status: str
    solve_time: float
    times: np.ndarray = field(default_factory=lambda: np.zeros(0))


# ---------------------------------------------------------------------------
# validation helpers
# ---------------------------------------------------------------------------
def _check_mesh(mesh, max_vertices: int, blocks: int = 1) -> None:
    if not supports(mesh, "faces"):
        raise UnsupportedDomainError("exact W1 needs a TriangleMesh domain", field="domain")
    if mesh.n > max_vertices:
        raise InputError(
            f"mesh has {mesh.n} vertices; the exact (interior-point) W1 solver is limited to "
            f"{max_vertices}; use solvers.emd for larger meshes", field="domain")
    if blocks > 1 and mesh.n * blocks > MAX_BLOCK_UNKNOWNS:
        raise InputError(
            f"problem too large for the exact solver: {blocks} coupled blocks x {mesh.n} "
            f"vertices exceeds {MAX_BLOCK_UNKNOWNS}; use fewer inputs/steps or a coarser "
            "mesh", field="domain")


def _masses(mesh, values, field_name: str) -> np.ndarray:
    return normalized_columns(check_masses(values, mesh.n, field_name))


def _face_weights(mesh, face_weights) -> np.ndarray:
    if face_weights is None:
        return np.ones(mesh.n_faces)
    w = np.asarray(face_weights, dtype=np.float64)
    if w.shape != (mesh.n_faces,):
        raise InputError(f"face_weights must have shape ({mesh.n_faces},), got {w.shape}",
                         field="face_weights")
    if np.any(np.isnan(w)) or np.any(w <= 0):
        raise InputError("face_weights must be positive (np.inf blocks a face)",
                         field="face_weights")
    if not np.any(np.isfinite(w)):
        raise InputError("face_weights block every face", field="face_weights")
    return w


class _ConicProgram:
    """A tiny assembler for ``min q^T x  s.t.  A x + s = b, s in K`` (Clarabel's form)."""

    def __init__(self):
        self.n = 0
        self.q: list[tuple[int, np.ndarray]] = []
        self.p_diag: list[tuple[int, np.ndarray]] = []  # objective 1/2 x^T diag(p) x
        self.blocks = {"eq": [], "nonneg": [], "soc": []}
        self.rows = {"eq": 0, "nonneg": 0, "soc": 0}
        self.soc_sizes: list[int] = []

    def variables(self, k: int, cost=None) -> slice:
        s = slice(self.n, self.n + k)
        self.n += k
        if cost is not None:
            self.q.append((s.start, np.broadcast_to(np.asarray(cost, dtype=float), (k,))))
        return s

    def quadratic(self, s: slice, diag) -> None:
        r"""Add :math:`\tfrac12 \sum_j d_j x_j^2` over the variables ``s`` to the objective."""
        self.p_diag.append((s.start, np.broadcast_to(np.asarray(diag, dtype=float),
                                                     (s.stop - s.start,))))

    def constrain(self, kind: str, terms: list[tuple[slice, sp.spmatrix]], b) -> int:
        """Add rows ``sum_j M_j x[s_j] + slack = b`` with slack in cone ``kind``."""
        first = self.rows[kind]
        m = terms[0][1].shape[0]
        self.blocks[kind].append((first, terms, np.asarray(b, dtype=float)))
        self.rows[kind] += m
        return first

    def flow_block(self, geo: FlowGeometry, cost_scale: float = 1.0) -> slice:
        nf = len(geo.faces)
        cost = np.zeros(3 * nf)
        cost[0::3] = cost_scale * geo.weights
        s = self.variables(3 * nf, cost)
        self.constrain("soc", [(s, -sp.identity(3 * nf, format="csr"))], np.zeros(3 * nf))
        self.soc_sizes += [3] * nf
        return s

    def solve(self, tol: float, max_iter: int, time_limit: float | None, progress=None,
              should_cancel=None):
        import clarabel

        q = np.zeros(self.n)
        for start, c in self.q:
            q[start:start + len(c)] += c
        rows, cols, vals, b = [], [], [], []
        offset = 0
        for kind in ("eq", "nonneg", "soc"):
            for first, terms, _rhs in self.blocks[kind]:
                for s, M in terms:
                    M = M.tocoo()
                    rows.append(M.row + offset + first)
                    cols.append(M.col + s.start)
                    vals.append(M.data)
            kb = np.zeros(self.rows[kind])
            for first, _, rhs in self.blocks[kind]:
                kb[first:first + len(rhs)] = rhs
            b.append(kb)
            offset += self.rows[kind]
        A = sp.csc_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(offset, self.n))
        cones = []
        if self.rows["eq"]:
            cones.append(clarabel.ZeroConeT(self.rows["eq"]))
        if self.rows["nonneg"]:
            cones.append(clarabel.NonnegativeConeT(self.rows["nonneg"]))
        cones += [clarabel.SecondOrderConeT(k) for k in self.soc_sizes]
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.tol_gap_abs = tol
        settings.tol_gap_rel = tol
        settings.tol_feas = tol
        settings.max_iter = int(max_iter)
        if time_limit is not None:
            settings.time_limit = float(time_limit)
        p = np.zeros(self.n)
        for start, d in self.p_diag:
            p[start:start + len(d)] += d
        P = sp.diags(p, format="csc")
        solver = clarabel.DefaultSolver(P, q, A, np.concatenate(b), cones, settings)
        cancelled, stalled = [], []
        monitor = Monitor(progress, should_cancel, tol=tol, patience=IPM_PATIENCE)

        def callback(info) -> bool:  # True stops the interior-point loop
            try:
                monitor(int(info.iterations),
                        float(max(info.gap_rel, info.res_primal, info.res_dual)))
            except CancelledError:
                cancelled.append(True)
                return True
            if monitor.stalled:  # residual stopped falling: stop, report not converged
                stalled.append(True)
                return True
            return False

        solver.set_termination_callback(callback)
        start = time.perf_counter()
        solution = solver.solve()
        elapsed = time.perf_counter() - start
        if cancelled:
            raise CancelledError("conic solve cancelled", field="should_cancel")
        status = str(solution.status)
        if "." in status:
            status = status.rsplit(".", 1)[1]
        if stalled:
            status = "Stalled"
        x = np.asarray(solution.x)
        z = np.asarray(solution.z)
        return x, z, int(solution.iterations), status, elapsed


def _kept_rows(mesh: TriangleMesh) -> np.ndarray:
    """All vertices but one per component: the divergence rows are rank V - components."""
    labels = mesh.component_labels
    _, first = np.unique(labels, return_index=True)
    keep = np.ones(mesh.n, dtype=bool)
    keep[first] = False
    return np.flatnonzero(keep)


def _component_sum_matrix(mesh: TriangleMesh) -> sp.csr_matrix:
    labels = mesh.component_labels
    return sp.csr_matrix((np.ones(mesh.n), (labels, np.arange(mesh.n))),
                         shape=(mesh.n_components, mesh.n))


# Interior-point iterations without a 0.1 % improvement of the residual after which the
# conic solve stops as stalled (status "Stalled": converged False).
IPM_PATIENCE = 25


def _converged(status: str) -> bool:
    return status in ("Solved", "AlmostSolved")


# ---------------------------------------------------------------------------
# public solvers
# ---------------------------------------------------------------------------
def beckmann_w1_exact(
    mesh: TriangleMesh,
    mu0,
    mu1,
    *,
    face_weights=None,
    tol: float = 1e-8,
    max_iter: int = 200,
    max_vertices: int = MAX_VERTICES,
    time_limit: float | None = None,
    progress=None,
    should_cancel=None,
) -> BeckmannResult:
    r"""Exact discrete W1 (Beckmann problem, eq. 2.3) by second-order cone programming.

    Solves :math:`\min_J \sum_t w_t A_t \lVert J_t\rVert` s.t.
    ``mesh.divergence @ J = m0 - m1`` with one tangent vector per face.

    Parameters
    ----------
    mesh : TriangleMesh with at most ``max_vertices`` vertices.
    mu0, mu1 : (V,) masses (non-negative, normalized to sum 1 here).
    max_vertices : largest mesh accepted (the SOCP grows with the mesh).
    face_weights : optional (F,) positive travel cost per unit length on each face
        (the isotropic case of the anisotropic W1 of §2.7); ``np.inf`` forbids a face.
        Flow may pass from face to face through a shared vertex, so an obstacle must
        block every face touching its vertices (``blocked[mesh.faces].any(axis=1)``).
    tol : interior-point gap and feasibility tolerance.
    max_iter, time_limit : interior-point iteration and wall-time (s) caps.
    progress : callable(iteration, residual) after every interior-point iteration
        (residual = max of relative gap and primal/dual residuals), or None.
    should_cancel : callable() -> bool polled every iteration; True raises
        ``CancelledError``.  The same keywords apply to the barycenter and path solvers.

    Returns
    -------
    BeckmannResult with ``value``, ``flow`` (F, 3), ``potential`` (V,).
    """
    _check_mesh(mesh, max_vertices)
    m0 = _masses(mesh, mu0, "mu0")
    m1 = _masses(mesh, mu1, "mu1")
    if m0.ndim != 1 or m1.ndim != 1:
        raise InputError("mu0 and mu1 must be single (V,) distributions", field="mu0")
    return _beckmann_difference(mesh, m0 - m1, face_weights=face_weights, tol=tol,
                                max_iter=max_iter, time_limit=time_limit,
                                progress=progress, should_cancel=should_cancel)


def _beckmann_difference(mesh, difference, *, face_weights=None, tol=1e-8, max_iter=200,
                         time_limit=None, progress=None, should_cancel=None,
                         field_name: str = "mu1") -> BeckmannResult:
    """Kantorovich–Rubinstein norm of a balanced signed mass vector ``m0 - m1``."""
    if mesh.n_components > 1:
        scale = max(np.abs(difference).sum(), 1e-300)
        mesh.require_matching_component_masses(
            np.stack([np.maximum(difference, 0), np.maximum(-difference, 0)], axis=1),
            _BALANCE_TOL * scale + 1e-12, field_name)
    weights = _face_weights(mesh, face_weights)
    geo = flow_geometry(mesh, weights)
    keep = _kept_rows(mesh)
    Monitor(progress, should_cancel).check_cancel("before the conic solve")
    prog = _ConicProgram()
    flow = prog.flow_block(geo)
    prog.constrain("eq", [(flow, geo.div[keep])], difference[keep])
    x, z, iterations, status, elapsed = prog.solve(
        tol, max_iter, time_limit, progress, should_cancel)
    if status in ("PrimalInfeasible", "AlmostPrimalInfeasible"):
        raise UnsupportedDomainError(
            "no flow can carry the mass: the faces allowed by face_weights disconnect the "
            "support of mu0 from that of mu1", field="face_weights")
    xb = x[flow]
    potential = np.zeros(mesh.n)
    potential[keep] = z[: len(keep)]
    residual = float(np.abs(geo.div @ xb - difference).max())
    value = flow_cost(geo, xb)
    return BeckmannResult(
        value=value,
        flow=flow_vectors(mesh, geo, xb),
        potential=potential,
        iterations=iterations,
        residual=residual,
        converged=_converged(status),
        status=status,
        solve_time=elapsed,
    )


def kantorovich_rubinstein_norm(mesh: TriangleMesh, difference, **kwargs) -> BeckmannResult:
    r"""Exact :math:`\lVert m_0 - m_1\rVert_{KR}` of a signed (V,) vector summing to 0.

    The Beckmann problem only sees the difference of its two marginals, so it is a norm
    on balanced signed measures; this is what volumetric distances (§2.6) need, since
    mean value coordinates may be negative.  ``value = W1(positive part, negative part)``.
    Keyword arguments are those of :func:`beckmann_w1_exact`.

    Parameters
    ----------
    mesh : TriangleMesh
        The surface.
    difference : (V,) array
        Signed masses summing to 0.
    **kwargs
        Keywords of :func:`beckmann_w1_exact`.

    Returns
    -------
    BeckmannResult
    """
    d = np.asarray(difference, dtype=np.float64)
    if d.shape != (mesh.n,) or not np.all(np.isfinite(d)):
        raise InputError(f"difference must be a finite ({mesh.n},) vector", field="difference")
    scale = np.abs(d).sum()
    if abs(d.sum()) > 1e-9 * max(scale, 1.0):
        raise InputError(f"difference must sum to zero, got {d.sum():g}", field="difference")
    _check_mesh(mesh, kwargs.pop("max_vertices", MAX_VERTICES))
    return _beckmann_difference(mesh, d, field_name="difference", **kwargs)


def w1_barycenter(
    mesh: TriangleMesh,
    mus,
    weights=None,
    *,
    face_weights=None,
    method: str = "auto",
    tol: float | None = None,
    max_iter: int | None = None,
    max_vertices: int = MAX_VERTICES,
    time_limit: float | None = None,
    progress=None,
    should_cancel=None,
) -> W1BarycenterResult:
    r"""W1 barycenter, thesis eq. (2.7):
    :math:`\min_{\rho\ge0,\ \int\rho=1} \sum_i \alpha_i W_1(\rho_i, \rho)^2`.

    One convex program in :math:`\rho` (vertex masses), k Beckmann flows :math:`J_i` with
    ``div J_i = rho - rho_i`` and epigraph variables
    :math:`t_i \ge \sum_t w_t A_t \lVert J_{i,t}\rVert`; the objective
    :math:`\sum_i \alpha_i t_i^2` is a diagonal quadratic, so the program is a convex QP
    over second-order cones.  For Dirac inputs the optimum is (close to) a Dirac at a point
    minimizing :math:`\sum_i \alpha_i d(x_i, p)^2` (the thesis' remark after Fig. 2.16);
    :func:`w1_median` solves the unsquared problem instead.

    Parameters
    ----------
    mesh : TriangleMesh.
    mus : (V, k) masses, one column per input :math:`\rho_i` (normalized per column).
    weights : (k,) non-negative weights :math:`\alpha` (normalized to sum 1), default uniform.
    face_weights : as in :func:`beckmann_w1_exact`.
    method : ``"auto"`` (``"ipm"`` unless a face weight is infinite), ``"ipm"`` (the
        primal-dual interior point with vertex-sized Newton systems of
        :mod:`solvers.emd.interior_point_barycenter`, any mesh size; ``tol`` is the
        certified relative duality gap, default ``IPM_TOL``) or ``"socp"`` (Clarabel on the
        whole program, at most ``max_vertices`` vertices and ``MAX_BLOCK_UNKNOWNS``
        vertices x (k + 1); default ``tol`` 1e-8).
    tol : ``"ipm"``: certified relative duality gap (default ``IPM_TOL``); ``"socp"``: the
        conic solver's tolerance (default 1e-8).
    max_iter : iteration cap (default ``IPM_MAX_ITER`` / 200).
    max_vertices : largest mesh of the ``"socp"`` route.
    time_limit : wall-time cap (s) of the ``"socp"`` route.
    progress, should_cancel : as in :func:`beckmann_w1_exact` (the ``"ipm"`` route reports
        its certified relative gap).

    Returns
    -------
    W1BarycenterResult: ``masses`` (V,), ``value`` :math:`\sum_i \alpha_i W_1^2`,
    ``distances`` (k,) the W1 of each input's flow, ``flows`` (k, F, 3), and for ``"ipm"``
    the certified ``lower_bound`` and relative ``gap``.
    """
    check_choice(method, BARYCENTER_METHODS, "method")
    fw = _face_weights(mesh, face_weights) if supports(mesh, "faces") else None
    if method == "auto":
        method = "socp" if fw is not None and not np.all(np.isfinite(fw)) else "ipm"
    if method == "ipm":
        if fw is not None and not np.all(np.isfinite(fw)):
            raise InputError("method='ipm' needs finite face_weights; use 'socp' for walls",
                             field="method")
        return _barycenter_ipm(mesh, mus, weights, fw, IPM_TOL if tol is None else float(tol),
                               IPM_MAX_ITER if max_iter is None else int(max_iter), progress,
                               should_cancel)
    return _barycenter(mesh, mus, weights, squared=True, face_weights=face_weights,
                       tol=1e-8 if tol is None else tol,
                       max_iter=200 if max_iter is None else max_iter,
                       max_vertices=max_vertices, time_limit=time_limit,
                       progress=progress, should_cancel=should_cancel)


def w1_median(
    mesh: TriangleMesh,
    mus,
    weights=None,
    *,
    face_weights=None,
    tol: float = 1e-8,
    max_iter: int = 200,
    max_vertices: int = MAX_VERTICES,
    time_limit: float | None = None,
    progress=None,
    should_cancel=None,
) -> W1BarycenterResult:
    r"""W1 geometric median: :math:`\min_{\rho\ge0,\ \int\rho=1} \sum_i \alpha_i
    W_1(\rho, \rho_i)` (*not* eq. 2.7, which squares the distances: :func:`w1_barycenter`).

    One linear program over second-order cones in :math:`\rho` and k Beckmann flows
    :math:`J_i` with ``div J_i = rho - rho_i``.  Like a geometric median it need not be
    unique and tends to be sparse; with two inputs and :math:`\alpha_1 \ge \alpha_2`,
    :math:`\rho_1` itself is optimal.  Parameters and result as in :func:`w1_barycenter`,
    with ``value`` :math:`= \sum_i \alpha_i W_1(\rho, \rho_i)`.

    Parameters
    ----------
    mesh : TriangleMesh
        The surface.
    mus : (V, k) array
        One column per input :math:`\rho_i` (normalized per column).
    weights : (k,) array, optional
        Non-negative weights :math:`\alpha` (normalized to sum 1), default uniform.
    face_weights : (F,) array, optional
        As in :func:`beckmann_w1_exact`.
    tol, max_iter, max_vertices, time_limit : float, int, int, float
        As in :func:`beckmann_w1_exact`.
    progress, should_cancel : callable, optional
        As in :func:`beckmann_w1_exact`.

    Returns
    -------
    W1BarycenterResult
    """
    return _barycenter(mesh, mus, weights, squared=False, face_weights=face_weights, tol=tol,
                       max_iter=max_iter, max_vertices=max_vertices, time_limit=time_limit,
                       progress=progress, should_cancel=should_cancel)


def _barycenter_inputs(mesh, mus, weights, max_vertices: int | None):
    """Validated ``(M (V, k) normalized columns, alpha (k,) summing to 1)``; the conic
    solver's size caps unless ``max_vertices`` is None."""
    if not supports(mesh, "faces"):
        raise UnsupportedDomainError("W1 barycenters need a TriangleMesh domain",
                                     field="domain")
    x_in = check_masses(mus, mesh.n, "mus")
    if x_in.ndim != 2:
        raise InputError("mus must be a (V, k) array, one column per input", field="mus")
    M = normalized_columns(x_in)
    k = M.shape[1]
    if max_vertices is not None:
        _check_mesh(mesh, max_vertices, blocks=k + 1)
    alpha = check_weights(weights, k)
    mesh.require_matching_component_masses(M, _BALANCE_TOL, "mus")
    return M, alpha


def _barycenter_ipm(mesh, mus, weights, fw, tol, max_iter, progress,
                    should_cancel) -> W1BarycenterResult:
    """Eq. 2.7 by the interior point of :mod:`solvers.emd.interior_point_barycenter`."""
    M, alpha = _barycenter_inputs(mesh, mus, weights, None)
    monitor = Monitor(progress, should_cancel, tol=tol, patience=W1_IPM_PATIENCE)
    monitor.check_cancel("before the solve")
    start = time.perf_counter()
    out = solve_barycenter_ipm(mesh, M, alpha, fw, tol, max_iter, monitor)
    return W1BarycenterResult(
        masses=out["masses"], value=out["value"], distances=out["distances"],
        flows=out["flows"], iterations=out["iterations"], residual=out["feasibility"],
        converged=out["converged"], status="Solved" if out["converged"] else "NotConverged",
        solve_time=time.perf_counter() - start, method="ipm",
        lower_bound=out["lower_bound"], gap=out["gap"])


def _barycenter(mesh, mus, weights, *, squared, face_weights, tol, max_iter, max_vertices,
                time_limit, progress, should_cancel) -> W1BarycenterResult:
    """Eq. 2.7 (``squared``) or the W1 median as one conic program."""
    M, alpha = _barycenter_inputs(mesh, mus, weights, max_vertices)
    k = M.shape[1]
    geo = flow_geometry(mesh, _face_weights(mesh, face_weights))
    keep = _kept_rows(mesh)
    Monitor(progress, should_cancel).check_cancel("before the conic solve")

    prog = _ConicProgram()
    mu = prog.variables(mesh.n)
    restrict = sp.identity(mesh.n, format="csr")[keep]
    nf = len(geo.faces)
    # row vector picking sum_t w_t s_t out of an interleaved flow block
    cost_row = sp.csr_matrix((geo.weights, (np.zeros(nf, dtype=np.int64), 3 * np.arange(nf))),
                             shape=(1, 3 * nf))
    flows = []
    for i in range(k):
        fl = prog.flow_block(geo, cost_scale=0.0 if squared else alpha[i])
        # div J_i - mu = -mu_i   (J_i carries mu towards mu_i)
        prog.constrain("eq", [(fl, geo.div[keep]), (mu, -restrict)], -M[keep, i])
        if squared:  # epigraph t_i >= sum_t w_t s_t, objective alpha_i t_i^2
            t = prog.variables(1)
            prog.quadratic(t, 2.0 * alpha[i])
            prog.constrain("nonneg", [(fl, cost_row), (t, -sp.identity(1, format="csr"))],
                           np.zeros(1))
        flows.append(fl)
    prog.constrain("eq", [(mu, _component_sum_matrix(mesh))], mesh.component_masses(M[:, 0]))
    prog.constrain("nonneg", [(mu, -sp.identity(mesh.n, format="csr"))], np.zeros(mesh.n))
    x, _, iterations, status, elapsed = prog.solve(
        tol, max_iter, time_limit, progress, should_cancel)
    masses = np.clip(x[mu], 0.0, None)
    masses /= masses.sum()
    xs = [x[fl] for fl in flows]
    distances = np.array([flow_cost(geo, xb) for xb in xs])
    residual = max(float(np.abs(geo.div @ xb - (x[mu] - M[:, i])).max())
                   for i, xb in enumerate(xs))
    return W1BarycenterResult(
        masses=masses,
        value=float(alpha @ (distances ** 2 if squared else distances)),
        distances=distances,
        flows=np.stack([flow_vectors(mesh, geo, xb) for xb in xs]),
        iterations=iterations,
        residual=residual,
        converged=_converged(status),
        status=status,
        solve_time=elapsed,
    )


def w1_multistep_paths(
    mesh: TriangleMesh, mu_start, mu_goal, n_steps: int, *, capacity=None,
    obstacle_vertices=None, face_weights=None, tol: float = 1e-8, max_iter: int = 200,
    max_vertices: int = MAX_VERTICES, time_limit: float | None = None, progress=None,
    should_cancel=None,
) -> W1MultistepResult:
    r"""A capacitated multi-step W1 chain from a start to a goal, as one convex program.

    Not the thesis' path planning (eq. 2.6, :func:`solvers.emd.path_planning.w1_path_planning`,
    which sends occupants to a set of exits): this moves one distribution to a given goal
    through ``n_steps - 1`` intermediate distributions under congestion constraints.

    .. math::
        \min_{\mu_1..\mu_{K-1},\,J_0..J_{K-1}} \sum_{k<K} \sum_t w_t A_t \lVert J_{k,t}\rVert
        \ \text{s.t.}\ \operatorname{div} J_k = \mu_k - \mu_{k+1},\ \mu_0 = \mu_{start},\
        \mu_K = \mu_{goal},\ 0 \le \mu_k \le c,\ J_k|_{\text{obstacle faces}} = 0 ,

    i.e. a chain of ``n_steps`` W1 moves through the space of distributions.  Without
    constraints the value is :math:`W_1(\mu_{start}, \mu_{goal})` (triangle inequality);
    capacities ``c`` (congestion: at most ``c_i`` mass on vertex i at any intermediate
    time), obstacle vertices (no mass rests on them and no flow crosses the faces that
    touch them) and face weights (travel cost; ``np.inf`` = obstacle face) shape the path.

    Parameters
    ----------
    mesh : TriangleMesh with at most ``max_vertices`` vertices.
    mu_start, mu_goal : (V,) masses.
    n_steps : number of moves K >= 1 (the result holds K + 1 distributions).
    capacity : scalar or (V,) upper bound on the intermediate masses.
    obstacle_vertices : vertex indices blocked for mass and flow; the start and goal
        must carry no mass there.
    face_weights : optional (F,) travel cost per unit length (``np.inf`` = obstacle face).
    tol, max_iter, max_vertices, time_limit, progress, should_cancel :
        as in :func:`beckmann_w1_exact`.

    Returns
    -------
    W1MultistepResult
        ``masses`` ``(V, n_steps + 1)``, ``step_costs`` ``(n_steps,)``, their sum
        ``value`` and the step flows ``(n_steps, F, 3)``.
    """
    if not isinstance(n_steps, (int, np.integer)) or n_steps < 1:
        raise InputError("n_steps must be a positive integer", field="n_steps")
    _check_mesh(mesh, max_vertices, blocks=2 * int(n_steps) - 1)
    m0 = _masses(mesh, mu_start, "mu_start")
    m1 = _masses(mesh, mu_goal, "mu_goal")
    if m0.ndim != 1 or m1.ndim != 1:
        raise InputError("mu_start and mu_goal must be (V,) vectors", field="mu_start")
    mesh.require_matching_component_masses(np.stack([m0, m1], axis=1), _BALANCE_TOL, "mu_goal")
    fw, upper, forbidden = _path_constraints(mesh, m0, m1, capacity, obstacle_vertices,
                                             face_weights)
    geo = flow_geometry(mesh, fw)
    Monitor(progress, should_cancel).check_cancel("before the conic solve")
    K = int(n_steps)
    prog, mids, flows = _path_program(mesh, geo, m0, m1, K, upper, forbidden)
    x, _, iterations, status, elapsed = prog.solve(
        tol, max_iter, time_limit, progress, should_cancel)
    if status in ("PrimalInfeasible", "AlmostPrimalInfeasible"):
        raise InputError(
            "no path satisfies the constraints (capacity too small, or forbidden vertices "
            "and obstacle faces cut the start from the goal)", field="capacity")
    masses = np.empty((mesh.n, K + 1))
    masses[:, 0], masses[:, K] = m0, m1
    for k, mid in enumerate(mids):
        masses[:, k + 1] = x[mid]
    xs = [x[fl] for fl in flows]
    costs = np.array([flow_cost(geo, xb) for xb in xs])
    residual = max(float(np.abs(geo.div @ xb - (masses[:, k] - masses[:, k + 1])).max())
                   for k, xb in enumerate(xs))
    return W1MultistepResult(
        masses=masses,
        value=float(costs.sum()),
        step_costs=costs,
        flows=np.stack([flow_vectors(mesh, geo, xb) for xb in xs]),
        iterations=iterations,
        residual=residual,
        converged=_converged(status),
        status=status,
        solve_time=elapsed,
        times=np.linspace(0.0, 1.0, K + 1),
    )


def _path_constraints(mesh, m0, m1, capacity, obstacle_vertices, face_weights):
    """Validated path constraints: face weights (``inf`` on faces touching an obstacle
    vertex), per-vertex capacity (or ``None``) and the (V,) obstacle mask."""
    fw = _face_weights(mesh, face_weights)
    upper = None
    if capacity is not None:
        upper = np.broadcast_to(np.asarray(capacity, dtype=np.float64), (mesh.n,)).copy()
        if not np.all(np.isfinite(upper) | (upper == np.inf)) or np.any(upper < 0):
            raise InputError("capacity must be non-negative", field="capacity")
    forbidden = np.zeros(mesh.n, dtype=bool)
    if obstacle_vertices is not None:
        idx = np.asarray(obstacle_vertices, dtype=np.int64).ravel()
        if idx.size and (idx.min() < 0 or idx.max() >= mesh.n):
            raise InputError(f"obstacle_vertices must lie in [0, {mesh.n - 1}]",
                             field="obstacle_vertices")
        forbidden[idx] = True
        if (m0[forbidden].sum() > 0) or (m1[forbidden].sum() > 0):
            raise InputError("mu_start and mu_goal must carry no mass on obstacle_vertices",
                             field="obstacle_vertices")
        fw = np.where(forbidden[mesh.faces].any(axis=1), np.inf, fw)
    return fw, upper, forbidden


def _path_program(mesh, geo, m0, m1, K, upper, forbidden):
    """The conic program of :func:`w1_multistep_paths`: ``K`` flow blocks chained through ``K - 1``
    intermediate distributions; returns ``(program, mid variables, flow variables)``."""
    keep = _kept_rows(mesh)
    restrict = sp.identity(mesh.n, format="csr")[keep]
    eye = sp.identity(mesh.n, format="csr")
    comp_sum = _component_sum_matrix(mesh)
    prog = _ConicProgram()
    mids = [prog.variables(mesh.n) for _ in range(K - 1)]
    flows = [prog.flow_block(geo) for _ in range(K)]
    for k in range(K):
        terms = [(flows[k], geo.div[keep])]
        rhs = np.zeros(len(keep))
        # div J_k - mu_k + mu_{k+1} = 0, known endpoints moved to the right-hand side
        if k == 0:
            rhs += m0[keep]
        else:
            terms.append((mids[k - 1], -restrict))
        if k == K - 1:
            rhs -= m1[keep]
        else:
            terms.append((mids[k], restrict))
        prog.constrain("eq", terms, rhs)
    for mid in mids:
        prog.constrain("eq", [(mid, comp_sum)], mesh.component_masses(m0))
        prog.constrain("nonneg", [(mid, -eye)], np.zeros(mesh.n))
        if upper is not None:
            finite = np.flatnonzero(np.isfinite(upper))
            prog.constrain("nonneg", [(mid, eye[finite])], upper[finite])
        if forbidden.any():
            prog.constrain("eq", [(mid, eye[forbidden])], np.zeros(int(forbidden.sum())))
    return prog, mids, flows
