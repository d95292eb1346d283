r"""Earth mover's distance W1 on triangle meshes via the Beckmann problem (thesis ch. 2).

.. math::

    W_1(\mu_0, \mu_1) = \min_J \int_M \|J(x)\|\,dA
    \quad\text{s.t.}\quad \nabla\cdot J = \rho_0 - \rho_1
    \qquad\text{(eq. 2.1, 2.3)}

(the thesis writes :math:`\rho_1-\rho_0` with the opposite sign of the flow; here
``J`` carries mass *from* ``mu0`` *to* ``mu1``).  Discretely ``J`` is constant per
face and the constraint is the weak one, ``mesh.divergence @ J.ravel() = m0 - m1``.
Every feasible flow is ``J = v + Ψ c`` (eq. 2.4-2.5): ``v = ∇f`` with
``L f = m1 - m0`` (one prefactored Neumann Poisson solve) plus a divergence-free
field from a basis ``Ψ`` (:mod:`solvers.emd.bases`), and we minimize
:math:`\sum_t A_t \|v_t + (\Psi c)_t\|` over ``c`` by

* **ADMM** (thesis Fig. 2.5) on ``min Σ A_t‖z_t‖ s.t. z = v + Ψc``: the c-update
  solves with ``ΨᵀAΨ``, which for the full curl basis is ``Pᵀ L P``, factored once
  per mesh and cached on it; z is a per-face shrinkage; the penalty β adapts by
  residual balancing (Boyd et al. 2011, §3.4.1);
* **Weiszfeld** iteration (thesis Fig. 2.4): iteratively reweighted least squares,
  one weighted factorization per iteration.

``basis="flow"`` optimizes over all piecewise-constant flows (no basis; the ADMM
J-update is a projection, i.e. one Poisson solve): the unrestricted discrete
problem, a reference below the curl-basis value.  Over all flows the default method is

* **a primal-dual interior-point method** (:mod:`solvers.emd.interior_point`): the same
  problem as a second-order cone program whose Newton systems are vertex-sized weighted
  Laplacians (one sparse Cholesky per iteration, 20-40 iterations); every iterate is a
  feasible flow and a feasible Kantorovich potential, so it stops at a *certified*
  relative gap ``tol`` between the two.

Accuracy (measured against the exact LP with exact geodesic costs, and against the exact
optimum of the same discretization, :func:`solvers.emd.exact.beckmann_w1_exact`:
``bench/results/w1_accuracy.md``): the unrestricted space (``"flow"``, the default) tracks
the LP (its optimum is a lower bound of the LP up to the geodesic solver), while the thesis'
curl basis (``"full"``) overestimates: rotated gradients of P1 stream functions span only part
of the divergence-free piecewise-constant flows.  Every ADMM iterate over all flows is
feasible (a projection onto the divergence constraint), so its value approaches that optimum
from above; it is within about 1 % of it long before the residuals reach 1e-4, hence the
looser default ``tol`` of the ADMM; within 1e-4 of the optimum takes it thousands of
iterations, which is why the interior-point method is the default over all flows.

The dual potential ``u`` (a vertex function with ``|∇u| ≈ 1`` where mass moves)
satisfies ``W1 ≈ u · (m1 - m0)``; rescaled to ``max|∇u| ≤ 1`` it certifies a lower
bound ``lower_bound`` ≤ the discrete optimum (weak duality).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.domains import supports
from solvers.emd.bases import CurlBasis, SpectralBasis, _apply_metric, _Basis
from solvers.emd.interior_point import beckmann_interior_point
from solvers.emd.operators import EMDOperators, mesh_operators
from solvers.errors import InputError, UnsupportedDomainError
from solvers.linalg import factorize_spd
from solvers.monitor import Monitor, SolverResult
from solvers.validation import check_choice, normalize_masses

METHODS = ("auto", "ipm", "admm", "weiszfeld")
BASES = ("auto", "full", "spectral", "flow")
# Default tolerances per (method, basis); others 1e-4.  "ipm": certified relative gap.
# The ADMM over all flows is within 1 % above its optimum at relative residuals of 1e-2, but
# 1e-4 of the optimum takes it thousands of iterations (bench/results/w1_accuracy.md).
DEFAULT_TOL = {("admm", "flow"): 1e-2, ("ipm", "flow"): 1e-4}
IPM_MAX_ITER = 100
# Interior-point iterations without a 0.1 % decrease of the certified gap: stalled.
IPM_PATIENCE = 15
RELAXATION = 1.6


@dataclass
class EMDResult(SolverResult):
    """W1 between two distributions on a mesh.

    Attributes
    ----------
    value : float
        W1 (discrete Beckmann objective of ``flow``; lengths at unit total area,
        multiply by ``mesh.length_scale`` for input units).
    flow : (F, 3) ndarray
        Optimal flow per face, from ``mu0`` to ``mu1``.
    potential : (V,) ndarray
        Dual (Kantorovich) potential ``u``, W1 ≈ ``u @ (m1 - m0)``.
    lower_bound : float
        Certified lower bound of the unrestricted discrete problem (NaN for matrix face
        weights).
    iterations, primal_residual, dual_residual, converged
        Solver report.
    residual : float
        The larger of the two relative residuals.
    method : str
        The solver that ran.
    basis : str
        The flow space (``"flow"``, ``"full"`` or ``"spectral"``).
    beta : float
        The final ADMM penalty (NaN for other solvers).
    """

    value: float
    flow: np.ndarray
    potential: np.ndarray
    lower_bound: float
    primal_residual: float
    dual_residual: float
    method: str
    basis: str
    beta: float = float("nan")


def check_mesh(mesh) -> EMDOperators:
    if not supports(mesh, "faces"):
        raise UnsupportedDomainError(
            f"earth mover's distances need a triangle mesh, got a {getattr(mesh, 'kind', mesh)}",
            field="mesh")
    return mesh_operators(mesh)


def check_pair(mesh, mu0, mu1) -> tuple[np.ndarray, np.ndarray]:
    """Validated, normalized masses; refuses mass that would have to change component."""
    m0 = normalize_masses(mu0, mesh.n, "mu0")
    m1 = normalize_masses(mu1, mesh.n, "mu1")
    if m0.ndim != 1 or m1.ndim != 1:
        raise InputError("mu0 and mu1 must be one distribution each, shape (n,)", field="mu1")
    mesh.require_matching_component_masses(np.stack([m0, m1], axis=1), 1e-9, "mu1")
    return m0, m1


def check_face_weights(face_weights, n_faces: int) -> np.ndarray | None:
    if face_weights is None:
        return None
    w = np.asarray(face_weights, dtype=np.float64)
    if w.shape not in ((n_faces,), (n_faces, 3, 3)):
        raise InputError(f"face_weights must have shape ({n_faces},) or ({n_faces}, 3, 3), "
                         f"got {w.shape}", field="face_weights")
    if not np.all(np.isfinite(w)):
        raise InputError("face_weights contains NaN or infinite values", field="face_weights")
    if w.ndim == 1 and np.any(w <= 0):
        raise InputError("face_weights must be positive", field="face_weights")
    return w


def make_basis(ops: EMDOperators, basis: str, k: int | None, harmonic: bool) -> _Basis | None:
    if basis == "full":
        return CurlBasis(ops, harmonic=harmonic)
    if basis == "spectral":
        if k is None:
            raise InputError("basis='spectral' needs the number k of eigenfunctions", field="k")
        return SpectralBasis(ops, int(k), harmonic=harmonic)
    if basis == "flow":
        return None
    raise InputError(f"basis must be one of {BASES}, got {basis!r}", field="basis")


def _dot(x: np.ndarray, y: np.ndarray) -> float:
    """Vector dot product without BLAS: threaded BLAS calls on vectors stall badly on
    oversubscribed machines (tens of ms each), and the iterations make many."""
    return float(np.einsum("i,i->", x, y))


def _face_norms(field: np.ndarray) -> np.ndarray:
    return np.sqrt(np.einsum("fc,fc->f", field, field))


def _shrink(y: np.ndarray, threshold) -> np.ndarray:
    """Per-face vector soft-thresholding: prox of ``threshold·‖·‖``."""
    norms = _face_norms(y)
    scale = np.maximum(1.0 - threshold / np.maximum(norms, 1e-300), 0.0)
    return y * scale[:, None]


def _cost(ops, field, weights) -> float:
    if weights is None:
        return _dot(ops.face_areas, _face_norms(field))
    if weights.ndim == 1:
        return _dot(ops.face_areas * weights, _face_norms(field))
    return _dot(ops.face_areas, _face_norms(_apply_metric(weights, field)))


def _potential(ops, dual_field, m0, m1, weights) -> tuple[np.ndarray, float]:
    """Least-squares potential ``∇u ≈ dual_field`` and the certified lower bound."""
    u = ops.solve_poisson(ops.grad_adjoint(dual_field))
    labels = ops.labels
    a = ops.mesh.areas
    means = np.bincount(labels, a * u) / np.bincount(labels, a)
    u = u - means[labels]
    if weights is not None and weights.ndim == 3:
        return u, float("nan")
    slope = _face_norms(ops.grad(u))
    if weights is not None:
        slope = slope / weights
    s = float(slope.max())
    return u, (float(u @ (m1 - m0)) / s if s > 0 else 0.0)


# Iterations without a 0.1 % improvement of the best residual after which the W1 loops stop
# as stalled (converged=False with the measured residuals).
ADMM_PATIENCE = 2000
WEISZFELD_PATIENCE = 50


def resolve_method(method: str, basis: str, matrix: bool = False) -> tuple[str, str]:
    """``(method, basis)`` that ``earth_movers_distance`` runs for these arguments
    (``matrix``: matrix ``face_weights``): ``"auto"`` resolved, impossible pairs refused."""
    check_choice(method, METHODS, "method")
    if basis == "auto":
        basis = "full" if matrix else "flow"
    if method == "auto":
        method = "ipm" if basis == "flow" and not matrix else "admm"
    if method == "ipm" and (basis != "flow" or matrix):
        raise InputError("method='ipm' solves over all flows (basis 'flow' or 'auto') with "
                         "scalar face weights", field="method")
    return method, basis


def earth_movers_distance(mesh, mu0, mu1, *, method: str = "auto", basis: str = "auto",
                          k: int | None = None, harmonic: bool = True, face_weights=None,
                          tol: float | None = None, max_iter: int | None = None,
                          beta: float | None = None, progress=None,
                          should_cancel=None) -> EMDResult:
    r"""W1 between vertex distributions on a triangle mesh (thesis eq. 2.1, 2.3-2.5).

    Minimizes :math:`\sum_t A_t w_t \|J_t\|` (or :math:`\sum_t A_t\|M_t J_t\|`) over
    flows with ``mesh.divergence @ J.ravel() = m0 - m1``.

    Parameters
    ----------
    mesh : TriangleMesh.
    mu0, mu1 : (V,) masses (non-negative, normalized to sum 1).
    method : ``"auto"`` (default: ``"ipm"`` over all flows with scalar or no face
        weights, else ``"admm"``), ``"ipm"`` (primal-dual interior point, all flows only:
        :mod:`solvers.emd.interior_point`), ``"admm"`` (Fig. 2.5) or ``"weiszfeld"``
        (Fig. 2.4).
    basis : ``"auto"`` (default: ``"flow"``, or ``"full"`` with matrix ``face_weights``),
        ``"flow"`` (all piecewise-constant flows: the unrestricted discrete problem, whose
        value tracks the exact LP), ``"full"`` (the thesis' rotated gradients of every
        vertex hat function, plus harmonic fields on surfaces with handles: a subspace, so
        an overestimate) or ``"spectral"`` (first ``k`` Laplacian eigenfunctions as stream
        functions).  Measured gaps to the exact LP and times:
        ``bench/results/w1_accuracy.md``.
    k : number of eigenfunctions for ``basis="spectral"``.
    harmonic : ``"full"``/``"spectral"``: include the ``2g`` harmonic fields (genus > 0).
        Without them W1 is overestimated on surfaces with handles (``"flow"`` contains
        every harmonic flow already).
    face_weights : None, (F,) positive scalars ``w`` or (F, 3, 3) matrices ``M``:
        anisotropic cost :math:`\int\|A(x) J\|` (§2.7).
    tol : certified relative gap ``(value - lower_bound) / value`` (interior point),
        relative primal/dual residual (ADMM) or relative objective change (Weiszfeld) at
        which to stop; default :data:`DEFAULT_TOL` (1e-4 for the interior point; looser for
        the ADMM over all flows, whose value settles long before its residuals do:
        ``bench/results/w1_accuracy.md``).
    max_iter : iteration cap (default 100 interior point, 20000 ADMM, 500 Weiszfeld); the
        loops also stop when the residual has not improved by 0.1 % for ``IPM_PATIENCE`` /
        ``ADMM_PATIENCE`` / ``WEISZFELD_PATIENCE`` iterations (stagnation: converged False,
        measured residuals).
    progress, should_cancel : called every iteration (``solvers.monitor.Monitor``).
    beta : initial ADMM penalty (default ``1 / Σ A‖v‖``); adapted by residual balancing.

    Returns
    -------
    EMDResult (value, flow (F, 3), potential (V,), lower_bound, iterations,
    primal_residual, dual_residual, converged).
    """
    check_choice(method, METHODS, "method")
    ops = check_mesh(mesh)
    m0, m1 = check_pair(mesh, mu0, mu1)
    weights = check_face_weights(face_weights, ops.n_faces)
    matrix = weights is not None and weights.ndim == 3
    method, basis = resolve_method(method, basis, matrix)
    tol = _tolerance(tol, method, basis)
    if basis == "flow" and weights is not None and weights.ndim == 3:
        raise InputError("matrix face_weights need basis='full' or 'spectral'",
                         field="face_weights")
    flow_basis = make_basis(ops, basis, k, harmonic)
    patience = {"ipm": IPM_PATIENCE, "admm": ADMM_PATIENCE}.get(method, WEISZFELD_PATIENCE)
    monitor = Monitor(progress, should_cancel, tol=tol, patience=patience)
    _, v = ops.particular_flow(m1 - m0)
    if method == "ipm":
        return _ipm(ops, v, m0, m1, weights, tol,
                    IPM_MAX_ITER if max_iter is None else int(max_iter), monitor)
    if method == "admm":
        max_iter = 20000 if max_iter is None else int(max_iter)
        out = _admm(ops, flow_basis, v, m0 - m1, weights, tol, max_iter, beta, monitor)
    else:
        max_iter = 500 if max_iter is None else int(max_iter)
        out = _weiszfeld(ops, flow_basis, v, m0 - m1, weights, tol, max_iter, monitor)
    flow, dual, iterations, r, s, beta_final = out
    potential, lower = _potential(ops, dual, m0, m1, weights)
    return EMDResult(value=_cost(ops, flow, weights), flow=flow, potential=potential,
                     lower_bound=lower, iterations=iterations, primal_residual=r,
                     dual_residual=s, residual=max(r, s), converged=bool(r <= tol and s <= tol),
                     method=method, basis=basis, beta=beta_final)


def _tolerance(tol, method: str, basis: str) -> float:
    """``tol`` checked, or the default of ``(method, basis)`` (:data:`DEFAULT_TOL`)."""
    if tol is None:
        tol = DEFAULT_TOL.get((method, basis), 1e-4)
    if not (np.isfinite(tol) and tol > 0):
        raise InputError(f"tol must be positive, got {tol}", field="tol")
    return tol


def _ipm(ops, v, m0, m1, weights, tol, max_iter, monitor) -> EMDResult:
    """The interior-point route: start from the Poisson flow ``v`` (feasible), return the
    certified flow and potential."""
    geo, structure = ops.interior_point_structure
    w = np.ones(ops.n_faces) if weights is None else weights
    u0 = np.einsum("fc,fdc->fd", v, geo.frames) * ops.face_areas[:, None]
    out = beckmann_interior_point(geo.div, structure.faces, w, m0 - m1, ops._keep, u0, tol,
                                  max_iter, monitor, structure=structure)
    flow = np.einsum("fd,fdc->fc", out.u, geo.frames) / ops.face_areas[:, None]
    potential = -out.y  # the module's dual maximizes y·(m0 - m1); here u·(m1 - m0)
    labels, a = ops.labels, ops.mesh.areas
    potential -= (np.bincount(labels, a * potential) / np.bincount(labels, a))[labels]
    scale = max(float(np.abs(m0 - m1).max()), 1e-300)
    return EMDResult(value=_cost(ops, flow, weights), flow=flow, potential=potential,
                     lower_bound=out.lower_bound, iterations=out.iterations,
                     primal_residual=out.feasibility / scale, dual_residual=0.0,
                     residual=out.gap, converged=out.converged, method="ipm",
                     basis="flow")


def _admm(ops, basis, v, b, weights, tol, max_iter, beta, monitor):
    """ADMM on ``min Σ A_t w_t‖z_t‖ s.t. z = M(v + Ψc)`` (scaled form, unscaled λ)."""
    area = ops.face_areas
    matrix = weights is not None and weights.ndim == 3
    threshold = 1.0 if (weights is None or matrix) else weights
    metric = weights if matrix else None

    def wnorm(x):
        return float(np.sqrt(np.einsum("f,fc,fc->", area, x, x)))

    if basis is None:
        def update(target):  # project target onto {D J = b}: J = y + ∇μ, L μ = D y - b
            mu = ops.solve_poisson(ops.weak_divergence(target) - b)
            return target + ops.grad(mu)
    elif matrix:
        transposed = weights.transpose(0, 2, 1)
        solve = basis.weighted_solver(transposed @ weights)
        mv = _apply_metric(weights, v)

        def update(target):  # argmin_c ‖M(v + Ψc) - target‖_A
            return v + basis.apply(solve(basis.adjoint(_apply_metric(transposed, target - mv))))
    else:
        def update(target):  # argmin_c ‖v + Ψc - target‖_A, prefactored system
            return v + basis.apply(basis.solve_normal(basis.adjoint(target - v)))

    mj = _apply_metric(metric, v)
    z = mj.copy()
    lam = np.zeros_like(v)
    if beta is None:
        beta = 1.0 / max(_dot(area, _face_norms(mj)), 1e-300)
    flow = v
    r = s = np.inf
    it = 0
    for it in range(1, max_iter + 1):
        flow = update(z - lam / beta)
        mj = _apply_metric(metric, flow)
        z_old = z
        relaxed = RELAXATION * mj + (1.0 - RELAXATION) * z_old  # over-relaxation, Boyd §3.4.3
        z = _shrink(relaxed + lam / beta, threshold / beta)
        lam = lam + beta * (relaxed - z)
        scale = max(wnorm(mj), wnorm(z), 1e-300)
        r = wnorm(mj - z) / scale
        s = beta * wnorm(z - z_old) / max(wnorm(lam), 1e-300)
        monitor(it, max(r, s))
        if (r <= tol and s <= tol) or monitor.stalled:
            break
        if r > 10.0 * s:
            beta *= 2.0
        elif s > 10.0 * r:
            beta /= 2.0
    dual = _apply_metric(weights.transpose(0, 2, 1), lam) if matrix else lam
    return flow, dual, it, r, s, beta


def _weiszfeld(ops, basis, v, b, weights, tol, max_iter, monitor):
    """Weiszfeld / IRLS: ``c ← argmin Σ A_t ω_t‖M(v + Ψc)_t‖²``, ω = 1/‖M J^k‖."""
    area = ops.face_areas
    matrix = weights is not None and weights.ndim == 3
    metric = weights if matrix else None
    scalar = weights if (weights is not None and not matrix) else None
    flow = v
    cost = _cost(ops, flow, weights)
    change = np.inf
    it = 0
    for it in range(1, max_iter + 1):
        norms = _face_norms(_apply_metric(metric, flow))
        floor = 1e-9 * max(float(norms.max()), 1e-300)
        omega = 1.0 / np.maximum(norms, floor)
        if scalar is not None:
            omega = omega * scalar
        if basis is None:
            # min Σ A ω ‖J‖² s.t. D J = b  ->  J = -∇ν/ω with (Gᵀ diag(A/ω) G) ν = b
            conductance = 1.0 / omega
            lap = ops.gradient_matrix.T @ (
                ops.gradient_matrix.multiply(np.repeat(area * conductance, 3)[:, None]))
            keep = ops._keep
            nu = np.zeros(ops.n_vertices)
            nu[keep] = factorize_spd(lap.tocsr()[keep][:, keep].tocsc()).solve(b[keep])
            flow = -ops.grad(nu) / omega[:, None]
        else:
            q = (omega[:, None, None] * np.einsum("fji,fjk->fik", weights, weights)
                 if matrix else omega)
            solve = basis.weighted_solver(q)
            coef = solve(-basis.adjoint(_apply_metric(q, v)))
            flow = v + basis.apply(coef)
        new_cost = _cost(ops, flow, weights)
        change = abs(cost - new_cost) / max(new_cost, 1e-300)
        cost = new_cost
        monitor(it, change)
        if change <= tol or monitor.stalled:
            break
    mj = _apply_metric(metric, flow)
    norms = np.maximum(_face_norms(mj), 1e-300)
    unit = mj / norms[:, None]
    if matrix:
        dual = np.einsum("fji,fj->fi", weights, unit)
    else:
        dual = unit * (scalar[:, None] if scalar is not None else 1.0)
    return flow, dual, it, 0.0, change, float("nan")
