r"""W1 over all piecewise-constant flows by a primal-dual interior-point method whose
Newton systems are vertex-sized (thesis ch. 2, eq. 2.3).

The discrete Beckmann problem of :func:`solvers.emd.exact.beckmann_w1_exact`,

.. math::
    \min_{x_t = (s_t, u_t) \in \mathcal Q^3} \sum_t w_t s_t
    \quad\text{s.t.}\quad D u = m_0 - m_1 ,

with :math:`u_t = A_t J_t` (two coordinates in a tangent frame of face ``t``), ``D`` the
weak divergence and :math:`\mathcal Q^3` the Lorentz cone :math:`s_t \ge \lVert u_t\rVert`,
and its dual (Kantorovich–Rubinstein, eq. 2.1)

.. math::
    \max_y\; y^\top (m_0 - m_1) \quad\text{s.t.}\quad
    z_t = (w_t, -(D^\top y)_t) \in \mathcal Q^3
    \;\Leftrightarrow\; \lVert \nabla y|_t \rVert \le w_t ,

are solved together by Mehrotra's predictor-corrector with Nesterov–Todd scaling
(Vandenberghe, *The CVXOPT linear and quadratic cone program solvers*, 2010, §4).  A generic
conic solver factors the whole KKT system (``3F + V`` unknowns); here the face variables are
eliminated in closed form (the scaling is a 3×3 block per face), which leaves the normal
equations :math:`D\, W_t^{-2} D^\top \Delta y = r`: a weighted Laplacian of the mesh's
sparsity, one sparse Cholesky per iteration.

The start is primal and dual feasible (``u`` = the area-weighted gradient of the Poisson
solution, ``y = 0``), and every step keeps both feasible, so each iterate brackets the
optimum: ``value`` (the cost :math:`\sum_t w_t \lVert u_t\rVert` of a flow satisfying the
divergence constraint) is an upper bound, ``lower_bound`` :math:`= y^\top(m_0 - m_1)` with
unit-bounded face gradients a lower bound, and the loop stops when
``value - lower_bound <= tol * value``: a certified relative error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.emd.flow_geometry import flow_geometry
from solvers.jit import cached_njit
from solvers.linalg import factorize_spd, have_pardiso

# Fraction of the largest cone-feasible step taken (keeps iterates interior).
STEP_FRACTION = 0.99


@dataclass
class NormalStructure:
    """Index maps of the normal matrix, built once per (mesh, blocked faces)."""

    faces: np.ndarray  # (F, 3) vertices of the faces that carry flow
    local: np.ndarray  # (F, 3, 2): D restricted to face t, (vertex slot, tangent coord)
    slots: np.ndarray  # (k,) CSR data slot of each kept (face, a, b) entry
    kept: np.ndarray  # (9 F,) bool: entry (face, a, b) touches no pinned vertex
    pattern: sp.csr_matrix  # the normal matrix's pattern on the kept vertices
    keep: np.ndarray  # kept vertices (one pinned per component)


def normal_structure(div: sp.csr_matrix, faces: np.ndarray, keep: np.ndarray) -> NormalStructure:
    """Per-face 3×2 blocks of the interleaved divergence ``div`` ``(V, 3 F)`` (columns
    ``3t + 1 + d`` hold tangent coordinate ``d`` of face ``t``) and the CSR slots of the
    normal matrix's face contributions."""
    n_faces = len(faces)
    coo = div.tocoo()
    face, coord = np.divmod(coo.col, 3)
    tangent = coord >= 1
    face, coord, vertex, value = face[tangent], coord[tangent] - 1, coo.row[tangent], \
        coo.data[tangent]
    slot = np.argmax(faces[face] == vertex[:, None], axis=1)
    local = np.zeros((n_faces, 3, 2))
    np.add.at(local, (face, slot, coord), value)
    n = div.shape[0]
    position = np.full(n, -1, dtype=np.int64)
    position[keep] = np.arange(len(keep))
    rows = position[np.repeat(faces, 3, axis=1).ravel()]
    cols = position[np.tile(faces, (1, 3)).ravel()]
    kept = (rows >= 0) & (cols >= 0)
    rows, cols = rows[kept], cols[kept]
    size = len(keep)
    pattern = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(size, size))
    pattern.sum_duplicates()
    pattern.sort_indices()
    keys = np.repeat(np.arange(size), np.diff(pattern.indptr)) * size + pattern.indices
    slots = np.searchsorted(keys, rows * size + cols)
    return NormalStructure(faces, local, slots, kept, pattern, keep)


# -- the Lorentz cone Q^3, batched over faces: arrays (F, 3) ------------------------------
# The per-face operations run as compiled loops, one pass per operation and no temporaries
# (they are most of an iteration's work besides the factorization once k F cones are
# stacked); each evaluates the same float64 expressions in the same order as the formulas
# in its docstring.
@cached_njit()
def _jdot_kernel(x, y):  # pragma: no cover - compiled
    out = np.empty(x.shape[0])
    for t in range(x.shape[0]):
        out[t] = x[t, 0] * y[t, 0] - x[t, 1] * y[t, 1] - x[t, 2] * y[t, 2]
    return out


def _jdot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``xᵀ J y`` with ``J = diag(1, -1, -1)``."""
    return _jdot_kernel(x, y)


@cached_njit()
def _jordan_point(x0, x1, x2, y0, y1, y2):  # pragma: no cover - compiled
    """One face's Jordan product ``x ∘ y``."""
    return x0 * y0 + x1 * y1 + x2 * y2, x0 * y1 + y0 * x1, x0 * y2 + y0 * x2


@cached_njit()
def _jordan_kernel(x, y):  # pragma: no cover - compiled
    out = np.empty(x.shape)
    for t in range(x.shape[0]):
        out[t, 0], out[t, 1], out[t, 2] = _jordan_point(x[t, 0], x[t, 1], x[t, 2], y[t, 0],
                                                        y[t, 1], y[t, 2])
    return out


def _jordan(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Jordan product ``x ∘ y = (xᵀy, x_0 ȳ + y_0 x̄)``."""
    return _jordan_kernel(x, y)


@cached_njit()
def _jordan_solve_point(l0, l1, l2, r0, r1, r2):  # pragma: no cover - compiled
    """One face's ``v`` with ``λ ∘ v = r`` (the arrow matrix of ``λ`` inverted in closed
    form)."""
    v0 = (l0 * r0 - l1 * r1 - l2 * r2) / (l0 * l0 - l1 * l1 - l2 * l2)
    return v0, (r1 - v0 * l1) / l0, (r2 - v0 * l2) / l0


@cached_njit()
def _scale_point(v0, v1, v2, b, y0, y1, y2, forward):  # pragma: no cover - compiled
    """One face's ``β (2 v vᵀ − J) y`` (``forward``) or ``(2 v vᵀ − J) y / β``."""
    c = 2.0 * (v0 * y0 + v1 * y1 + v2 * y2)
    y0, y1, y2 = c * v0 - y0, c * v1 + y1, c * v2 + y2
    if forward:
        return b * y0, b * y1, b * y2
    return y0 / b, y1 / b, y2 / b


@cached_njit()
def _inverse_square_kernel(p, beta, y):  # pragma: no cover - compiled
    """``W⁻² y``: ``W⁻¹ y = (2 p pᵀ − J) y / β`` (:func:`_scale_point`) twice."""
    out = np.empty(y.shape)
    for t in range(y.shape[0]):
        p0, p1, p2 = p[t, 0], p[t, 1], p[t, 2]
        y0, y1, y2 = y[t, 0], y[t, 1], y[t, 2]
        for _ in range(2):
            y0, y1, y2 = _scale_point(p0, p1, p2, beta[t], y0, y1, y2, False)
        out[t, 0], out[t, 1], out[t, 2] = y0, y1, y2
    return out


@cached_njit()
def _scaled_jordan_solve_kernel(lam, p, beta, r):  # pragma: no cover - compiled
    """``W⁻¹ (λ \\ r)``: :func:`_jordan_solve_point`, then ``W⁻¹``, in one pass."""
    out = np.empty(r.shape)
    for t in range(r.shape[0]):
        q0, q1, q2 = _jordan_solve_point(lam[t, 0], lam[t, 1], lam[t, 2], r[t, 0], r[t, 1],
                                         r[t, 2])
        out[t, 0], out[t, 1], out[t, 2] = _scale_point(p[t, 0], p[t, 1], p[t, 2], beta[t],
                                                       q0, q1, q2, False)
    return out


@cached_njit()
def _corrector_rhs_kernel(affine, v, p, beta, dx, dz, shift):  # pragma: no cover - compiled
    """Mehrotra's ``affine - (W⁻¹ Δz) ∘ (W Δx) + shift e`` in one pass (the same
    expressions as :func:`_jordan_kernel` and :func:`_scale_point`)."""
    out = np.empty(dx.shape)
    for t in range(dx.shape[0]):
        u0, u1, u2 = _scale_point(p[t, 0], p[t, 1], p[t, 2], beta[t], dz[t, 0], dz[t, 1],
                                  dz[t, 2], False)
        w0, w1, w2 = _scale_point(v[t, 0], v[t, 1], v[t, 2], beta[t], dx[t, 0], dx[t, 1],
                                  dx[t, 2], True)
        c0, c1, c2 = _jordan_point(u0, u1, u2, w0, w1, w2)
        out[t, 0] = (affine[t, 0] - c0) + shift
        out[t, 1], out[t, 2] = affine[t, 1] - c1, affine[t, 2] - c2
    return out


@dataclass
class _Scaling:
    """Nesterov–Todd scaling per face: ``W = β (2 v vᵀ − J)`` with ``vᵀ J v = 1``, the
    symmetric matrix with ``W x = W⁻¹ z = λ`` (Vandenberghe 2010, §4.2), applied in closed
    form: ``W⁻¹ = β⁻¹ (2 p pᵀ − J)`` with ``p = J v``."""

    v: np.ndarray  # (F, 3)
    p: np.ndarray  # (F, 3), J v
    beta: np.ndarray  # (F,)
    lam: np.ndarray  # (F, 3), W x

    def apply_inverse_square(self, y: np.ndarray) -> np.ndarray:  # W⁻² y
        return _inverse_square_kernel(self.p, self.beta, y)

    def inverse_jordan_solve(self, r: np.ndarray) -> np.ndarray:
        """``W⁻¹ (λ \\ r)``: the ``v`` with ``λ ∘ v = r``, then ``W⁻¹``."""
        return _scaled_jordan_solve_kernel(self.lam, self.p, self.beta, r)

    def corrector_rhs(self, affine: np.ndarray, dx: np.ndarray, dz: np.ndarray,
                      shift: float) -> np.ndarray:
        """Mehrotra's corrector right-hand side ``-λ ∘ λ - (W⁻¹ Δz) ∘ (W Δx) + shift e``
        (``e = (1, 0, 0)``) of the affine directions ``dx``, ``dz``; ``affine``: the affine
        right-hand side ``-λ ∘ λ`` they were solved for (not computed again)."""
        return _corrector_rhs_kernel(affine, self.v, self.p, self.beta, dx, dz, float(shift))

    def inverse_square_tangent(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Entries ``(t11, t12, t22)`` of the tangential 2×2 block of
        ``W⁻² = β⁻² (4 ‖v‖² p pᵀ − 2 (p vᵀ + v pᵀ) + I)``."""
        p, v = self.p, self.v
        vv = 4.0 * _dot(v, v)
        scale = 1.0 / self.beta**2

        def entry(i, j):
            eye = 1.0 if i == j else 0.0
            return scale * (vv * p[:, i] * p[:, j] - 2.0 * (p[:, i] * v[:, j]
                                                              + v[:, i] * p[:, j]) + eye)

        return entry(1, 1), entry(1, 2), entry(2, 2)


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return x[:, 0] * y[:, 0] + x[:, 1] * y[:, 1] + x[:, 2] * y[:, 2]


@cached_njit()
def _nt_kernel(x, z, v, p, beta, lam):  # pragma: no cover - compiled
    for t in range(x.shape[0]):
        xn = np.sqrt(x[t, 0] * x[t, 0] - x[t, 1] * x[t, 1] - x[t, 2] * x[t, 2])
        zn = np.sqrt(z[t, 0] * z[t, 0] - z[t, 1] * z[t, 1] - z[t, 2] * z[t, 2])
        x0, x1, x2 = x[t, 0] / xn, x[t, 1] / xn, x[t, 2] / xn
        z0, z1, z2 = z[t, 0] / zn, z[t, 1] / zn, z[t, 2] / zn
        gamma = np.sqrt(0.5 * (1.0 + (x0 * z0 + x1 * z1 + x2 * z2)))
        w0, w1, w2 = (z0 + x0) / (2.0 * gamma), (z1 + -x1) / (2.0 * gamma), \
            (z2 + -x2) / (2.0 * gamma)
        norm = np.sqrt(2.0 * (w0 + 1.0))
        v0, v1, v2 = (w0 + 1.0) / norm, w1 / norm, w2 / norm
        b = np.sqrt(zn / xn)
        v[t, 0], v[t, 1], v[t, 2] = v0, v1, v2
        p[t, 0], p[t, 1], p[t, 2] = v0, -v1, -v2
        beta[t] = b
        c = 2.0 * (v0 * x[t, 0] + v1 * x[t, 1] + v2 * x[t, 2])
        lam[t, 0] = b * (c * v0 - x[t, 0])
        lam[t, 1] = b * (c * v1 + x[t, 1])
        lam[t, 2] = b * (c * v2 + x[t, 2])


def _nt_scaling(x: np.ndarray, z: np.ndarray) -> _Scaling:
    n = len(x)
    scaling = _Scaling(v=np.empty((n, 3)), p=np.empty((n, 3)), beta=np.empty(n),
                       lam=np.empty((n, 3)))
    _nt_kernel(x, z, scaling.v, scaling.p, scaling.beta, scaling.lam)
    return scaling


@cached_njit()
def _max_step_kernel(x, d):  # pragma: no cover - compiled
    best = np.inf
    for t in range(x.shape[0]):
        a = d[t, 0] * d[t, 0] - d[t, 1] * d[t, 1] - d[t, 2] * d[t, 2]
        b = x[t, 0] * d[t, 0] - x[t, 1] * d[t, 1] - x[t, 2] * d[t, 2]
        c = x[t, 0] * x[t, 0] - x[t, 1] * x[t, 1] - x[t, 2] * x[t, 2]
        disc = b * b - a * c
        if a < 0 or (b < 0 and disc >= 0):
            root = c / (np.sqrt(max(disc, 0.0)) - b)
            if np.isnan(root):
                return np.nan
            best = min(best, root)
    return best


def _max_step(x: np.ndarray, d: np.ndarray) -> float:
    """Largest ``α`` with ``x + α d`` in every cone (``x`` interior; ``inf`` if none
    leaves): the smallest positive root of ``q(α) = (x + α d)ᵀ J (x + α d)``.  Leaving
    the cone's sheet means crossing ``q = 0`` first, and with ``q(0) > 0`` that root is
    ``c / (√(b² − a c) − b)`` for ``q = a α² + 2 b α + c`` whenever it exists."""
    return float(_max_step_kernel(x, d))


def _backend(backend: str) -> str:
    """``"auto"``: PARDISO when it loads (its numeric refactorization reuses the ordering
    across iterations), else the library default."""
    if backend == "auto":
        return "pardiso" if have_pardiso() else "auto"
    return backend


def flow_structure(mesh, keep: np.ndarray):
    """``(geometry, structure)`` of the interior-point solve on ``mesh``: tangent frames and
    interleaved divergence (:func:`solvers.emd.flow_geometry.flow_geometry`, all faces), and
    the normal matrix's pattern on the ``keep`` vertices.  Built once per mesh
    (``EMDOperators.interior_point_structure``)."""
    geo = flow_geometry(mesh, np.ones(mesh.n_faces))
    return geo, normal_structure(geo.div, np.asarray(mesh.faces)[geo.faces], keep)


def cone_start(u0: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """A strictly interior primal cone point ``(s_t, u_t)`` ``(F, 3)`` over the flow ``u0``
    ``(F, 2)``: ``s_t = ‖u_t‖`` plus a margin, the weighted mean norm."""
    norms = np.linalg.norm(u0, axis=1)
    x = np.empty((len(u0), 3))
    x[:, 1:] = u0
    x[:, 0] = norms + max(float(weights @ norms) / max(float(weights.sum()), 1e-300), 1e-300)
    return x


def _interior(x: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(x)) and np.all(x[:, 0] > 0) and np.all(_jdot(x, x) > 0))


def local_products(local: np.ndarray) -> np.ndarray:
    """``(F, 3, 9)``: per face the ``3 × 3`` products ``l0 l0ᵀ``, ``l0 l1ᵀ + l1 l0ᵀ``,
    ``l1 l1ᵀ`` of the divergence's local columns ``local`` ``(F, 3, 2)``, which the tangential
    entries of ``W⁻²`` weight in :func:`face_blocks`."""
    l0, l1 = local[:, :, 0], local[:, :, 1]

    def outer(a, b):
        return (a[:, :, None] * b[:, None, :]).reshape(-1, 9)

    return np.stack([outer(l0, l0), outer(l0, l1) + outer(l1, l0), outer(l1, l1)], axis=1)


@cached_njit()
def _face_blocks_kernel(v, p, beta, products):  # pragma: no cover - compiled
    n_faces = products.shape[0]
    out = np.empty((v.shape[0], 9))
    for t in range(v.shape[0]):
        f = t % n_faces
        v0, v1, v2, p1, p2 = v[t, 0], v[t, 1], v[t, 2], p[t, 1], p[t, 2]
        vv = 4.0 * (v0 * v0 + v1 * v1 + v2 * v2)
        scale = 1.0 / beta[t] ** 2
        t11 = scale * (vv * p1 * p1 - 2.0 * (p1 * v1 + v1 * p1) + 1.0)
        t12 = scale * (vv * p1 * p2 - 2.0 * (p1 * v2 + v1 * p2) + 0.0)
        t22 = scale * (vv * p2 * p2 - 2.0 * (p2 * v2 + v2 * p2) + 1.0)
        for j in range(9):
            out[t, j] = t11 * products[f, 0, j] + t12 * products[f, 1, j] \
                + t22 * products[f, 2, j]
    return out


def face_blocks(scaling: _Scaling, products: np.ndarray) -> np.ndarray:
    """Each face's ``3 × 3`` block ``D_t W_t⁻² D_tᵀ`` of the normal matrix, flattened
    ``(F', 9)``, from :func:`local_products` ``(F, 3, 9)``; ``scaling`` is over ``F' = k F``
    faces (``k`` stacked copies of the mesh's faces).  The tangential entries of ``W⁻²``
    are those of :meth:`_Scaling.inverse_square_tangent` (same expressions, one compiled
    pass)."""
    return _face_blocks_kernel(scaling.v, scaling.p, scaling.beta, products)


def normal_matrix_data(scaling: _Scaling, st: NormalStructure) -> np.ndarray:
    """CSR data (on ``st.pattern``) of the normal matrix ``D W⁻² Dᵀ`` on the kept vertices,
    from a 3×3 block per face."""
    blocks = face_blocks(scaling, local_products(st.local))
    return np.bincount(st.slots, blocks.reshape(-1)[st.kept], minlength=st.pattern.nnz)


def _factor_normal(data: np.ndarray, st: NormalStructure, factor, backend: str):
    """Factor (or refactor in place) the normal matrix with CSR ``data``; None if it is not
    finite."""
    return factor_normal_matrix(
        sp.csr_matrix((data, st.pattern.indices, st.pattern.indptr), shape=st.pattern.shape),
        factor, backend)


def factor_normal_matrix(normal: sp.csr_matrix, factor, backend: str, pardiso_effort: int = 0):
    """Factor ``normal``, or refactor ``factor`` in place when it can (PARDISO keeps the
    ordering and symbolic analysis of the fixed pattern); None if ``normal`` is not finite.
    ``pardiso_effort``: a first PARDISO factor's analysis effort (``factorize_spd``)."""
    if not np.all(np.isfinite(normal.data)):
        return None
    if factor is not None and hasattr(factor, "refactor"):
        factor.refactor(normal)
        return factor
    return factorize_spd(normal, _backend(backend), pardiso_effort=pardiso_effort)


def _iterate(x, z, st, newton, backend, factor):
    """One Mehrotra predictor-corrector step: ``(factor, Δx, Δy, Δz, α)``."""
    scaling = _nt_scaling(x, z)
    lam = scaling.lam
    mu = float(_dot(x, z).sum()) / len(x)
    factor = _factor_normal(normal_matrix_data(scaling, st), st, factor, backend)
    if factor is None:
        return None
    affine = -_jordan(lam, lam)
    dx_a, _, dz_a = newton(scaling, affine, factor)
    alpha_a = min(1.0, _max_step(x, dx_a), _max_step(z, dz_a))
    mu_a = float(_dot(x + alpha_a * dx_a, z + alpha_a * dz_a).sum()) / len(x)
    sigma = (max(mu_a, 0.0) / mu) ** 3
    rc = scaling.corrector_rhs(affine, dx_a, dz_a, sigma * mu)
    dx, dy, dz = newton(scaling, rc, factor)
    alpha = min(1.0, STEP_FRACTION * min(_max_step(x, dx), _max_step(z, dz)))
    return factor, dx, dy, dz, alpha


# What a failed Newton step raises at the end of the central path (a factorization or a
# solve losing positive definiteness to rounding).
STEP_FAILURES = (ValueError, RuntimeError, ZeroDivisionError, FloatingPointError)


def relative_gap(value: float, lower: float, floor: float = 1e-300) -> float:
    """``(value - lower) / max(|value|, floor)``: the certified relative error of ``value``."""
    return (value - lower) / max(abs(value), floor)


def certified_loop(state, advance, bounds, tol: float, max_iter: int, monitor,
                   floor: float = 1e-300):
    """The primal-dual loop every interior point here shares: ``advance(state)`` returns the
    next iterate, or None when the step failed or left the cones (rounding at the end of the
    path; a failure in :data:`STEP_FAILURES` counts the same), and the last iterate, which
    is still primal and dual feasible, is kept; ``bounds(state)`` gives ``(value,
    lower_bound)`` of an iterate.  Stops when :func:`relative_gap` (with ``floor``) is at
    most ``tol`` (converged), at ``max_iter``, or when ``monitor`` (called with the gap)
    reports a stall.  Returns ``(state, iterations, converged)``."""
    it, converged = 0, False
    for it in range(1, max_iter + 1):
        try:
            new = advance(state)
        except STEP_FAILURES:
            new = None
        if new is None:
            it -= 1
            break
        state = new
        gap = relative_gap(*bounds(state), floor)
        monitor(it, gap)
        if gap <= tol:
            converged = True
            break
        if monitor.stalled:
            break
    return state, it, converged


def nonneg_max_step(x: np.ndarray, d: np.ndarray) -> float:
    """Largest ``α`` with ``x + α d >= 0`` (``x > 0``; ``inf`` if ``d >= 0``)."""
    neg = d < 0
    return float((-x[neg] / d[neg]).min(initial=np.inf))


# Gondzio's centrality correctors: neighbourhood of the central path, in multiples of the
# target σμ, into which the products at a trial step are pulled, and the trial step's
# lengthening; a corrector is kept when it lengthens the step by a fraction of that.
CENTRALITY_BAND = (0.1, 10.0)
CORRECTOR_REACH = 0.2
CORRECTOR_GAIN = 0.1


def _max_steps(x, m, z, zm, dx, dm, dz, dzm) -> float:
    return min(_max_step(x, dx), _max_step(z, dz), nonneg_max_step(m, dm),
               nonneg_max_step(zm, dzm))


@cached_njit()
def _centrality_point(p0, p1, p2, lo, hi):  # pragma: no cover - compiled
    """One Lorentz cone's change of the Jordan product ``p`` that moves its spectral values
    ``p_0 ± ‖p̄‖`` into ``[lo, hi]`` (a decrease at most ``hi``, as in Gondzio 1996):
    ``((d1 + d2)/2, (d1 - d2)/2 · p̄/‖p̄‖)``."""
    norm = np.sqrt(p1 * p1 + p2 * p2)
    first, second = p0 + norm, p0 - norm
    d1 = max(min(max(first, lo), hi) - first, -hi)
    d2 = max(min(max(second, lo), hi) - second, -hi)
    half = 0.5 * (d1 - d2)
    if norm > 0:
        return 0.5 * (d1 + d2), half * (p1 / norm), half * (p2 / norm)
    return 0.5 * (d1 + d2), 0.0, 0.0


@cached_njit()
def _gondzio_rhs_kernel(x, dx, z, dz, trial, v, p, beta, rc, lo,
                        hi):  # pragma: no cover - compiled
    """``rc`` plus the centrality correction (:func:`_centrality_point`) of ``W (x + trial
    Δx) ∘ W⁻¹ (z + trial Δz)`` per face, in one pass (the same expressions as
    :func:`_scale_point` and :func:`_jordan_kernel`)."""
    out = np.empty(rc.shape)
    for t in range(x.shape[0]):
        a0, a1, a2 = _scale_point(v[t, 0], v[t, 1], v[t, 2], beta[t], x[t, 0] + trial * dx[t, 0],
                                  x[t, 1] + trial * dx[t, 1], x[t, 2] + trial * dx[t, 2], True)
        b0, b1, b2 = _scale_point(p[t, 0], p[t, 1], p[t, 2], beta[t], z[t, 0] + trial * dz[t, 0],
                                  z[t, 1] + trial * dz[t, 1], z[t, 2] + trial * dz[t, 2], False)
        j0, j1, j2 = _jordan_point(a0, a1, a2, b0, b1, b2)
        c0, c1, c2 = _centrality_point(j0, j1, j2, lo, hi)
        out[t, 0], out[t, 1], out[t, 2] = rc[t, 0] + c0, rc[t, 1] + c1, rc[t, 2] + c2
    return out


def _gondzio(x, m, z, zm, newton, direction, rc, rc_m, target: float, correctors: int):
    """Up to ``correctors`` centrality correctors (Gondzio 1996; Colombo & Gondzio 2008 for
    cones) on Mehrotra's ``direction`` ``(dx, dm, dy, dz, dzm)`` with right-hand sides
    ``rc``, ``rc_m``: the scaled products at a longer trial step are pulled into
    :data:`CENTRALITY_BAND` around ``target``, and the Newton system (same factorization)
    is solved again with that change added.  Returns the direction with its largest step."""
    sc = newton.scaling
    alpha = _max_steps(x, m, z, zm, *direction[:2], *direction[3:])
    lo, hi = CENTRALITY_BAND[0] * target, CENTRALITY_BAND[1] * target
    for _ in range(correctors):
        if alpha >= 1.0:
            break
        trial = min(1.0, alpha + CORRECTOR_REACH)
        dx, dm, _, dz, dzm = direction
        rc_new = _gondzio_rhs_kernel(x, dx, z, dz, float(trial), sc.v, sc.p, sc.beta, rc,
                                     float(lo), float(hi))
        p_m = (m + trial * dm) * (zm + trial * dzm)
        rc_m_new = rc_m + np.maximum(np.clip(p_m, lo, hi) - p_m, -hi)
        candidate = newton(rc_new, rc_m_new)
        step = _max_steps(x, m, z, zm, *candidate[:2], *candidate[3:])
        if step < alpha + CORRECTOR_GAIN * CORRECTOR_REACH:
            break
        direction, alpha, rc, rc_m = candidate, step, rc_new, rc_m_new
    return direction, alpha


def mehrotra_step(x, m, z, zm, newton, correctors: int = 0):
    """Mehrotra's predictor-corrector over Lorentz cones ``x, z`` ``(F, 3)`` and a
    non-negative block ``m, zm``: ``(dx, dm, dy, dz, dzm, α)``.  ``newton(rc, rc_m)`` solves
    the Newton system for complementarity right-hand sides (its ``scaling`` holds the
    cones' NT scaling); ``correctors``: at most that many of Gondzio's centrality
    correctors follow (:func:`_gondzio`, one more solve each with the same factorization)."""
    lam, lam_m = newton.scaling.lam, np.sqrt(m * zm)
    degree = len(x) + len(m)
    mu = (float(_dot(x, z).sum()) + float(m @ zm)) / degree
    affine = -_jordan(lam, lam)
    dx, dm, _, dz, dzm = newton(affine, -lam_m**2)
    alpha = min(1.0, _max_step(x, dx), _max_step(z, dz), nonneg_max_step(m, dm),
                nonneg_max_step(zm, dzm))
    mu_a = (float(_dot(x + alpha * dx, z + alpha * dz).sum())
            + float((m + alpha * dm) @ (zm + alpha * dzm))) / degree
    sigma = (max(mu_a, 0.0) / mu) ** 3
    sc = newton.scaling
    rc = sc.corrector_rhs(affine, dx, dz, sigma * mu)
    rc_m = -lam_m**2 - dzm * dm + sigma * mu
    direction = newton(rc, rc_m)
    if correctors:
        direction, longest = _gondzio(x, m, z, zm, newton, direction, rc, rc_m, sigma * mu,
                                      correctors)
    else:
        longest = _max_steps(x, m, z, zm, *direction[:2], *direction[3:])
    return (*direction, min(1.0, STEP_FRACTION * longest))


@dataclass
class InteriorPointOutput:
    u: np.ndarray  # (F, 2) flow u_t = A_t J_t in the tangent frames
    y: np.ndarray  # (V,) dual potential (0 at pinned vertices)
    value: float  # Σ w_t ‖u_t‖ of the returned (feasible) flow
    lower_bound: float  # yᵀ b, certified
    gap: float  # (value − lower_bound) / value
    iterations: int
    feasibility: float  # max |D u − b|
    converged: bool


def beckmann_interior_point(div: sp.csr_matrix, faces: np.ndarray, weights: np.ndarray,
                            b: np.ndarray, keep: np.ndarray, u0: np.ndarray, tol: float,
                            max_iter: int, monitor, backend: str = "auto",
                            structure: NormalStructure | None = None) -> InteriorPointOutput:
    """The primal-dual loop (see the module docstring).

    ``div`` ``(V, 3 F)`` interleaved weak divergence, ``faces`` ``(F, 3)`` vertex indices of
    its faces, ``weights`` ``(F,)``, ``b = m0 - m1``, ``keep`` all vertices but one per
    component, ``u0`` ``(F, 2)`` a flow with ``D u0 = b``; ``monitor`` a
    :class:`~solvers.monitor.Monitor` called with the certified relative gap."""
    st = structure if structure is not None else normal_structure(div, faces, keep)
    n_faces = len(faces)
    # primal start: u0 inside the cones; dual start y = 0, z = (w, 0, 0)
    x = cone_start(u0, weights)
    y = np.zeros(div.shape[0])
    z = np.zeros((n_faces, 3))
    z[:, 0] = weights
    n = div.shape[0]
    flat = faces.ravel()
    l0, l1 = st.local[:, :, 0], st.local[:, :, 1]  # (F, 3) each

    def newton(scaling: _Scaling, rc: np.ndarray, factor):
        # λ ∘ (W Δx + W⁻¹ Δz) = rc with D Δu = 0 and Δz = −Dᵀ Δy (primal and dual
        # residuals stay zero): (D W⁻² Dᵀ) Δy = −D (W⁻¹ q), q = λ \ rc
        wq = scaling.inverse_jordan_solve(rc)
        rhs = np.bincount(flat, (l0 * wq[:, 1:2] + l1 * wq[:, 2:3]).ravel(), minlength=n)
        dy = np.zeros(n)
        dy[st.keep] = factor.solve(-rhs[st.keep])
        yf = dy[faces]
        dz = np.zeros((n_faces, 3))
        dz[:, 1] = -(l0 * yf).sum(axis=1)
        dz[:, 2] = -(l1 * yf).sum(axis=1)
        dx = wq - scaling.apply_inverse_square(dz)
        return dx, dy, dz

    def advance(state):
        x, y, z, factor = state
        step = _iterate(x, z, st, newton, backend, factor)
        if step is None:
            return None
        factor, dx, dy, dz, alpha = step
        new = (x + alpha * dx, y + alpha * dy, z + alpha * dz, factor)
        ok = _interior(new[0]) and _interior(new[2]) and np.all(np.isfinite(new[1]))
        return new if ok else None

    def bounds(state):
        return float(weights @ np.linalg.norm(state[0][:, 1:], axis=1)), float(state[1] @ b)

    (x, y, z, _), it, converged = certified_loop((x, y, z, None), advance, bounds, tol,
                                                 max_iter, monitor)
    value, lower = bounds((x, y))
    u = x[:, 1:].copy()
    feasibility = float(np.abs(div @ np.column_stack([np.zeros(n_faces), u]).ravel()
                               - b).max())
    return InteriorPointOutput(u=u, y=y, value=value, lower_bound=lower,
                               gap=relative_gap(value, lower), iterations=it,
                               feasibility=feasibility, converged=converged)
