r"""Path planning (eq. 2.6) by the primal-dual interior-point method of
:mod:`solvers.emd.interior_point`, with vertex-sized Newton systems.

The program of :mod:`solvers.emd.path_planning`,

.. math::
    \min_{x_t = (s_t, u_t) \in \mathcal Q^3,\ m \ge 0} \sum_t w_t s_t
    + \tfrac12 m^\top P m
    \quad\text{s.t.}\quad D u + E m = m_0 ,

(``E`` places the exit masses ``m`` on their vertices, ``P = diag(2 ε / A_v)``), adds one
non-negative variable per exit to the Beckmann cones.  Its dual is
:math:`\max_y\ y^\top m_0 - \tfrac12 m^\top P m` with :math:`\lVert(D^\top y)_t\rVert \le
w_t` and :math:`z_m = P m - E^\top y \ge 0`.  Eliminating the face and exit variables
leaves the normal equations :math:`(D W^{-2} D^\top + E\,\mathrm{diag}(d / (1 + dP))
E^\top)\,\Delta y = r` with :math:`d = m / z_m`: the weighted Laplacian of the Beckmann
solver plus a diagonal on the exits.

The start is primal and dual feasible (exit masses spread evenly over each component's
exits, the Poisson flow that carries them, ``y = -δ`` on components with exits), and the
steps keep both feasible, so ``value - lower_bound`` (the duality gap) certifies the
objective, as for W1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.emd.interior_point import (
    NormalStructure,
    _factor_normal,
    _interior,
    _nt_scaling,
    certified_loop,
    cone_start,
    mehrotra_step,
    normal_matrix_data,
    relative_gap,
)

# Largest violation of ``D u + E m = m0`` (mass units; total mass 1) with which a small gap
# counts as converged: the steps keep the iterates feasible in exact arithmetic, but with a
# large congestion weight (P = 2 eps / A) the Newton solves lose feasibility to rounding,
# and a gap between infeasible iterates certifies nothing.
FEASIBILITY_TOL = 1e-6


@dataclass
class ExitsOutput:
    u: np.ndarray  # (F, 2) flow A_t J_t in the tangent frames
    m: np.ndarray  # (S,) exit masses
    y: np.ndarray  # (V,) dual potential
    value: float  # Σ w ‖u‖ + ½ mᵀPm
    lower_bound: float
    gap: float
    iterations: int
    feasibility: float  # max |D u + E m − m0|
    converged: bool


def _diagonal_slots(st: NormalStructure, rows: np.ndarray) -> np.ndarray:
    """CSR data indices of the diagonal entries ``(r, r)`` of ``st.pattern``."""
    indptr, indices = st.pattern.indptr, st.pattern.indices
    return np.array([indptr[r] + int(np.searchsorted(indices[indptr[r]:indptr[r + 1]], r))
                     for r in rows], dtype=np.int64)


class _ExitNewton:
    """Newton directions for fixed scalings (cones: NT scaling; exits: ``d = m / z_m``)."""

    def __init__(self, st, div_local, faces, n, exits_pos, exits, p_diag, scaling, m, zm,
                 factor, backend):
        self.st, self.faces, self.n = st, faces, n
        self.l0, self.l1 = div_local
        self.exits, self.p = exits, p_diag
        self.scaling, self.m, self.zm = scaling, m, zm
        d = m / zm
        self.d = d
        self.shrink = 1.0 / (1.0 + d * p_diag)
        data = normal_matrix_data(scaling, st)
        data[exits_pos] += d * self.shrink
        self.factor = _factor_normal(data, st, factor, backend)

    def __call__(self, rc, rc_m):
        sc, st, n = self.scaling, self.st, self.n
        wq = sc.inverse_jordan_solve(rc)
        lam_m = np.sqrt(self.m * self.zm)
        wq_m = (rc_m / lam_m) * np.sqrt(self.m / self.zm)
        rhs = np.bincount(self.faces.ravel(), (self.l0 * wq[:, 1:2] + self.l1 * wq[:, 2:3])
                          .ravel(), minlength=n)
        rhs[self.exits] += wq_m * self.shrink
        dy = np.zeros(n)
        dy[st.keep] = self.factor.solve(-rhs[st.keep])
        yf = dy[self.faces]
        dz = np.zeros_like(wq)
        dz[:, 1] = -(self.l0 * yf).sum(axis=1)
        dz[:, 2] = -(self.l1 * yf).sum(axis=1)
        dx = wq - sc.apply_inverse_square(dz)
        dm = (wq_m + self.d * dy[self.exits]) * self.shrink
        dzm = self.p * dm - dy[self.exits]
        return dx, dm, dy, dz, dzm


def exits_interior_point(div, st: NormalStructure, weights, m0, exits, p_diag, u0, m_start,
                         y_start, tol, max_iter, monitor, backend="auto") -> ExitsOutput:
    """The primal-dual loop (module docstring).  ``div`` (V, 3F) interleaved divergence,
    ``st`` its structure on the kept rows, ``exits`` (S,) vertex indices, ``p_diag`` (S,)
    the diagonal of P, ``u0`` (F, 2) and ``m_start`` (S,) > 0 with ``D u0 + E m_start =
    m0``, ``y_start`` (V,) constant per component with ``y < 0`` on the exits."""
    faces, n = st.faces, div.shape[0]
    x = cone_start(u0, weights)
    m, y = m_start.copy(), y_start.copy()
    z = np.zeros_like(x)
    z[:, 0] = weights
    zm = p_diag * m - y[exits]
    position = np.full(n, -1, dtype=np.int64)
    position[st.keep] = np.arange(len(st.keep))
    exits_pos = _diagonal_slots(st, position[exits])
    local = (st.local[:, :, 0], st.local[:, :, 1])

    def bounds(state):
        x, m, y = state[:3]
        quad = 0.5 * float(p_diag @ m**2)
        return float(weights @ np.linalg.norm(x[:, 1:], axis=1)) + quad, \
            float(y[st.keep] @ m0[st.keep]) - quad

    def advance(state):
        x, m, y, z, zm, factor = state
        newton = _ExitNewton(st, local, faces, n, exits_pos, exits, p_diag,
                             _nt_scaling(x, z), m, zm, factor, backend)
        if newton.factor is None:
            return None
        dx, dm, dy, dz, dzm, alpha = mehrotra_step(x, m, z, zm, newton)
        new = (x + alpha * dx, m + alpha * dm, y + alpha * dy, z + alpha * dz, zm + alpha * dzm,
               newton.factor)
        ok = (_interior(new[0]) and _interior(new[3]) and np.all(new[1] > 0)
              and np.all(new[4] > 0) and np.all(np.isfinite(new[2])))
        return new if ok else None

    state, it, converged = certified_loop((x, m, y, z, zm, None), advance, bounds, tol,
                                          max_iter, monitor)
    value, lower = bounds(state)
    x, m, y = state[:3]
    u = x[:, 1:].copy()
    flow = div @ np.column_stack([np.zeros(len(faces)), u]).ravel()
    flow[exits] += m
    feasibility = float(np.abs(flow - m0)[st.keep].max())
    return ExitsOutput(u=u, m=m, y=y, value=value, lower_bound=lower,
                       gap=relative_gap(value, lower), iterations=it, feasibility=feasibility,
                       converged=converged and feasibility <= FEASIBILITY_TOL)
