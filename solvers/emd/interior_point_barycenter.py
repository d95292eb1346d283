r"""W1 barycenters (thesis eq. 2.7) by the primal-dual interior point of
:mod:`solvers.emd.interior_point`, with vertex-sized Newton systems.

Eq. 2.7, :math:`\min_{\rho \ge 0,\ \int\rho = 1} \sum_i \alpha_i W_1(\rho_i, \rho)^2`, with each
:math:`W_1` in Beckmann form (eq. 2.3, one flow :math:`u_i` per input) and the epigraph
:math:`T_i = \sum_t w_t s_{i,t} \ge W_1(\rho_i, \rho)` is the cone QP

.. math::
    \min_{x_{i,t} = (s_{i,t}, u_{i,t}) \in \mathcal Q^3,\ \rho \ge 0}\
    \sum_i \alpha_i \Big(\sum_t w_t s_{i,t}\Big)^2
    \quad\text{s.t.}\quad D u_i - \rho = -m_i \quad (i = 1..k),

(``D`` the weak divergence; every block but the first drops one row per component, the
first keeps all rows and so fixes each component's mass of :math:`\rho`).  Its dual
variables are potentials :math:`y_i` with cone slacks :math:`z_{i,t} = (2\alpha_i T_i w_t,
-(D^\top y_i)_t) \in \mathcal Q^3` and :math:`z_\rho = \sum_i y_i \ge 0`; the dual
objective :math:`-\sum_i \alpha_i T_i^2 - \sum_i y_i^\top m_i` is a certified lower bound.

Newton systems.  With Nesterov–Todd scalings :math:`W_i` per face and :math:`d = \rho /
z_\rho`, the face variables and :math:`\rho` are eliminated in closed form; the objective's
Hessian :math:`2\alpha_i g g^\top` (``g`` = the weights on the ``s`` coordinates) is one
rank-one term per block, removed by Sherman–Morrison.  What is left are the normal equations
in the ``k`` potentials,

.. math::
    \Big(\operatorname{blkdiag}_i\, D W_i^{-2} D^\top + (\mathbf 1 \mathbf 1^\top) \otimes
    \operatorname{diag}(d) - \sum_i c_i \hat v_i \hat v_i^\top\Big)\, \Delta y = r ,

``k`` weighted Laplacians (those of the W1 solver) coupled through :math:`\rho` by a diagonal
between every pair of blocks, minus a rank-``k`` term.  Both parts go into one sparse SPD
matrix, the sparse part (the mesh's sparsity with ``k × k`` blocks per vertex) bordered by
``k`` rows and columns: :math:`\begin{pmatrix} A & V \\ V^\top & C^{-1}\end{pmatrix}`
(``V`` the :math:`\hat v_i`, ``C = diag(c)``), whose Schur complement on the potentials is
the normal matrix :math:`A - V C V^\top`; it is positive definite when that is (``C > 0``),
and its factor is that of ``A`` plus ``k`` dense rows, so each Newton solve is a single
solve (Woodbury's identity on ``A``'s factor would need ``k`` more right-hand sides per
iteration).  PARDISO factors it (ordering and symbolic analysis once, a numeric
refactorization per iteration), or cholespy.  Near the end of the path rounding
can cost the Cholesky a pivot; the matrix then goes to PARDISO's symmetric-indefinite
``L D Lᵀ`` (pivot perturbation, iterative refinement; the Cholesky's ordering reused) for
the remaining iterations.  Steps are Mehrotra's with Gondzio's centrality correctors
(:data:`CORRECTORS`).

The start is primal and dual feasible (uniform :math:`\rho`, the Poisson flows that carry it
to every input, :math:`y_1` a positive constant, the other potentials 0), and steps keep both
feasible (the Newton right-hand side also cancels the divergence residual rounding leaves),
so ``value - lower_bound`` certifies the objective; ``value`` is evaluated with the flows'
costs :math:`\sum_t w_t \lVert u_{i,t}\rVert`, the W1 upper bounds of a feasible point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.emd import interior_point as ip
from solvers.emd.beckmann import earth_movers_distance
from solvers.emd.operators import mesh_operators
from solvers.jit import cached_njit
from solvers.linalg import PardisoFactor

# Largest violation of the divergence constraints (mass units, total mass 1) with which a
# small gap counts as converged (as in solvers.emd.interior_point_exits).
FEASIBILITY_TOL = 1e-6
# Gondzio centrality correctors per iteration (solvers.emd.interior_point.mehrotra_step):
# the cones limit Mehrotra's steps to ~0.3-0.6 on this program; each corrector is one more
# solve with the iteration's factorization, cheaper than the factorizations of the iterations
# it saves up to 3 (bench/results/w1_applications.md: 0-4 compared at 10k vertices, 6 inputs).
CORRECTORS = 3
# PARDISO's analysis effort (:class:`solvers.linalg.PardisoFactor`'s ``effort``): the one
# analysis serves every iteration's refactorization and solves, and effort 1 made them
# cheaper (bench/results/w1_applications.md: 0, 1, 2, 5, 10 compared at 10k vertices).
PARDISO_EFFORT = 1
# Cost model of this route (bench/w1_applications.py fits it: measured times and PARDISO's
# factor sizes in bench/results/w1_applications.md).  Iterations grow slowly with the mesh
# and the inputs; each passes over the k F face cones and factors the (k V)-row normal matrix,
# a mesh Laplacian with dense k × k blocks per vertex: nested dissection gives a factor of
# ~k² V log V nonzeros, and its work grew like k^2.5 V^1.5 (k = 3 -> 6 at 10k vertices).
_ITERATIONS = 42.0  # at 10k vertices and 3 inputs; x (V / 10k)^0.2 (k / 3)^(1/3)
_FACE_SECONDS = 1.8e-6  # per face cone and iteration
_FACTOR_SECONDS = 2.0e-9  # per k^2.5 V^1.5 and iteration
_FACTOR_FILL = 2.0  # factor nonzeros per k² V log2(V)
_FACTOR_ENTRY_BYTES = 16  # PARDISO's memory per factor nonzero (values, indices, symbolic)
_FACE_FLOATS = 200  # cones, scalings, directions, per-face blocks: floats per face cone
# The compiled cone kernels' runtime (numba, LLVM) that a worker's first solve loads: measured
# peaks in a fresh process exceed the working arrays by 47-82 MiB.
_JIT_RUNTIME_BYTES = 96 << 20
MAX_ESTIMATED_SECONDS = 300.0
# Absolute floor of the relative gap's denominator (objective units: squared length on the
# unit-area mesh): the objective is 0 when the inputs coincide.
GAP_FLOOR = 1e-12


@dataclass(frozen=True)
class CostEstimate:
    seconds: float
    bytes: int


def estimated_cost(n_vertices: int, n_faces: int, k: int) -> CostEstimate:
    """Modelled run time (s, one core) and working memory of :func:`solve_barycenter_ipm`
    with ``k`` inputs of positive weight on a mesh of that size (constants above)."""
    k, n = float(max(k, 1)), float(max(n_vertices, 2))
    cones = k * float(max(n_faces, 1))
    iterations = _ITERATIONS * (n / 1e4) ** 0.2 * (k / 3.0) ** (1.0 / 3.0)
    per_iteration = _FACE_SECONDS * cones + _FACTOR_SECONDS * k**2.5 * n**1.5
    factor = _FACTOR_FILL * k**2 * n * np.log2(n)
    working = (_FACTOR_ENTRY_BYTES * factor + 8 * _FACE_FLOATS * cones + 8 * 40 * k * n
               + _JIT_RUNTIME_BYTES)
    return CostEstimate(seconds=iterations * per_iteration, bytes=int(working))


@dataclass
class BarycenterOutput:
    u: np.ndarray  # (k, F, 2) flows u_i = A_t J_i in the tangent frames, rho -> input i
    rho: np.ndarray  # (V,) barycenter masses
    y: np.ndarray  # (k, V) dual potentials
    distances: np.ndarray  # (k,) flow costs sum_t w_t |u_i,t| (>= W1(rho, rho_i))
    value: float  # sum_i alpha_i distances_i^2
    lower_bound: float
    gap: float  # relative, certified
    iterations: int
    feasibility: float  # max |D u_i - rho + m_i|
    converged: bool


class _CoupledPattern:
    """The bordered normal matrix's pattern over the ``k`` blocks of potentials and ``k``
    border rows, and the gather/slot maps that fill its CSR data from per-face blocks,
    ``d`` and the border (built once per solve).

    Block 0 holds every vertex (``full``), blocks 1.. the kept vertices (``kept``); rows
    ``size + i`` are the border's."""

    def __init__(self, full: ip.NormalStructure, kept: ip.NormalStructure, k: int, n: int):
        self.k, self.n = k, n
        self.sizes = [n] + [len(kept.keep)] * (k - 1)
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)])
        self.rows_of = [np.arange(n)] + [kept.keep] * (k - 1)  # vertex of each local row
        n_faces = len(full.faces)
        rows, cols, src = [], [], []
        for i, st in enumerate([full] + [kept] * (k - 1)):
            r, c = _slot_coordinates(st.pattern)
            entry = np.flatnonzero(st.kept)
            rows.append(self.offsets[i] + r[st.slots])
            cols.append(self.offsets[i] + c[st.slots])
            src.append(i * 9 * n_faces + entry)
        position = [np.full(n, -1, dtype=np.int64) for _ in range(k)]
        for i in range(k):
            position[i][self.rows_of[i]] = self.offsets[i] + np.arange(self.sizes[i])
        for i in range(k):  # d couples the blocks vertex by vertex
            for j in range(k):
                common = self.rows_of[i] if i > 0 or j == 0 else self.rows_of[j]
                rows.append(position[i][common])
                cols.append(position[j][common])
                src.append(k * 9 * n_faces + common)
        size = int(self.offsets[-1])  # the border: row/column size + i holds v_i, 1 / c_i
        for i in range(k):
            block = np.arange(self.offsets[i], self.offsets[i + 1] + 1)
            block[-1] = size + i
            rows.append(block)
            cols.append(np.full(len(block), size + i))
            src.append(k * 9 * n_faces + n + block)
        rows, cols, src = np.concatenate(rows), np.concatenate(cols), np.concatenate(src)
        upper = rows <= cols  # symmetric: PARDISO reads the upper triangle
        rows, cols, self.src = rows[upper], cols[upper], src[upper]
        self.size = size
        size += k
        self.pattern = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(size, size))
        self.pattern.sum_duplicates()
        self.pattern.sort_indices()
        keys = np.repeat(np.arange(size), np.diff(self.pattern.indptr)) * size \
            + self.pattern.indices
        self.slots = np.searchsorted(keys, rows * size + cols)

    def data(self, blocks: np.ndarray, d: np.ndarray, v: np.ndarray,
             c: np.ndarray) -> np.ndarray:
        """CSR data, on :attr:`pattern` (the upper triangle), of the bordered matrix from
        per-face blocks ``(k F, 9)``, ``d`` ``(V,)``, the border's columns ``v`` (``(k, V)``,
        :meth:`scatter` order) and ``c`` ``(k,)``."""
        tail = np.concatenate([d, self.scatter(v), 1.0 / c])
        return _assemble_kernel(blocks.reshape(-1), tail, self.src, self.slots,
                                self.pattern.nnz)

    def matrix(self, data: np.ndarray, full: bool) -> sp.csr_matrix:
        """The matrix of :meth:`data`: its upper triangle, or with ``full`` the whole
        symmetric matrix."""
        upper = sp.csr_matrix((data, self.pattern.indices, self.pattern.indptr),
                              shape=self.pattern.shape)
        return (upper + sp.triu(upper, 1).T).tocsr() if full else upper

    def scatter(self, per_block: np.ndarray) -> np.ndarray:
        """``(k, V)`` vertex arrays to one vector over the blocks' rows."""
        return np.concatenate([per_block[i, self.rows_of[i]] for i in range(self.k)], axis=0)

    def bordered(self, per_block: np.ndarray) -> np.ndarray:
        """:meth:`scatter` with the border's ``k`` rows (zero) appended: a right-hand side
        of the bordered matrix."""
        return np.concatenate([self.scatter(per_block), np.zeros(self.k)])

    def gather(self, vector: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`scatter` (``(k, V)``, zero on dropped rows; border rows of
        ``vector`` ignored); a trailing axis of ``vector`` is kept."""
        out = np.zeros((self.k, self.n) + vector.shape[1:])
        for i in range(self.k):
            out[i, self.rows_of[i]] = vector[self.offsets[i]:self.offsets[i + 1]]
        return out


@cached_njit()
def _assemble_kernel(blocks, tail, src, slots, nnz):  # pragma: no cover - compiled
    """``np.bincount(slots, concatenate([blocks, tail])[src])``: the sums in the same order."""
    out = np.zeros(nnz)
    m = blocks.shape[0]
    for j in range(src.shape[0]):
        s = src[j]
        out[slots[j]] += blocks[s] if s < m else tail[s - m]
    return out


def _slot_coordinates(pattern: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    return np.repeat(np.arange(pattern.shape[0]), np.diff(pattern.indptr)), pattern.indices


@cached_njit()
def _div_kernel(faces, l0, l1, x, n):  # pragma: no cover - compiled
    """Per block, ``Σ_t`` of face ``t``'s local divergence ``l0 x_1 + l1 x_2`` scattered to
    its vertices (faces in order: the sums of ``np.bincount``)."""
    out = np.zeros((x.shape[0], n))
    for i in range(x.shape[0]):
        for t in range(faces.shape[0]):
            for a in range(3):
                out[i, faces[t, a]] += l0[t, a] * x[i, t, 1] + l1[t, a] * x[i, t, 2]
    return out


@cached_njit()
def _div_adjoint_kernel(faces, l0, l1, y):  # pragma: no cover - compiled
    out = np.zeros((y.shape[0], faces.shape[0], 3))
    for i in range(y.shape[0]):
        for t in range(faces.shape[0]):
            y0, y1, y2 = y[i, faces[t, 0]], y[i, faces[t, 1]], y[i, faces[t, 2]]
            out[i, t, 1] = l0[t, 0] * y0 + l0[t, 1] * y1 + l0[t, 2] * y2
            out[i, t, 2] = l1[t, 0] * y0 + l1[t, 1] * y1 + l1[t, 2] * y2
    return out


@cached_njit()
def _direction_kernel(faces, l0, l1, dy, p, beta, wq, coef, h):  # pragma: no cover - compiled
    """Per block ``i`` and face ``t``, ``a = (0, Dᵀ Δy_i)_t`` (:func:`_div_adjoint_kernel`),
    ``Δx = (W⁻² a + wq) - coef_i h`` and ``Δz = -a`` (its first coordinate left 0 for
    the caller), in one pass with the same expressions as the separate kernels."""
    k, n_faces = wq.shape[0], wq.shape[1]
    dx, dz = np.empty(wq.shape), np.empty(wq.shape)
    for i in range(k):
        for t in range(n_faces):
            y0, y1, y2 = dy[i, faces[t, 0]], dy[i, faces[t, 1]], dy[i, faces[t, 2]]
            a1 = l0[t, 0] * y0 + l0[t, 1] * y1 + l0[t, 2] * y2
            a2 = l1[t, 0] * y0 + l1[t, 1] * y1 + l1[t, 2] * y2
            q0, q1, q2, b = p[i, t, 0], p[i, t, 1], p[i, t, 2], beta[i, t]
            s0, s1, s2 = ip._scale_point(q0, q1, q2, b, 0.0, a1, a2, False)
            s0, s1, s2 = ip._scale_point(q0, q1, q2, b, s0, s1, s2, False)
            dx[i, t, 0] = (s0 + wq[i, t, 0]) - coef[i] * h[i, t, 0]
            dx[i, t, 1] = (s1 + wq[i, t, 1]) - coef[i] * h[i, t, 1]
            dx[i, t, 2] = (s2 + wq[i, t, 2]) - coef[i] * h[i, t, 2]
            dz[i, t, 0], dz[i, t, 1], dz[i, t, 2] = 0.0, -a1, -a2
    return dx, dz


class _Program:
    """The data of one barycenter program: divergence as per-face ``3 × 2`` blocks
    ``local`` on ``faces``, face weights ``w``, weights ``alpha`` (k,), inputs ``m`` (k, V)."""

    def __init__(self, structure: ip.NormalStructure, w, alpha, m):
        self.faces, self.w, self.alpha, self.m = structure.faces, w, alpha, m
        self.products = ip.local_products(structure.local)
        self.l0 = np.ascontiguousarray(structure.local[:, :, 0])
        self.l1 = np.ascontiguousarray(structure.local[:, :, 1])
        self.k, self.n = m.shape

    def div(self, x: np.ndarray) -> np.ndarray:
        """``D u_i`` ``(k, V)`` of face vectors ``x`` ``(k, F, 3)`` (their ``u`` part)."""
        return _div_kernel(self.faces, self.l0, self.l1, x, self.n)

    def div_adjoint(self, y: np.ndarray) -> np.ndarray:
        """``(0, Dᵀ y_i)`` per face ``(k, F, 3)`` of potentials ``y`` ``(k, V)``."""
        return _div_adjoint_kernel(self.faces, self.l0, self.l1, y)

    def totals(self, x: np.ndarray) -> np.ndarray:
        """``T_i = Σ_t w_t s_{i,t}`` ``(k,)``."""
        return x[:, :, 0] @ self.w

    def dual_slacks(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``z_i = 2 α_i T_i (w, 0, 0) - (0, Dᵀ y_i)`` and ``z_ρ = Σ_i y_i``."""
        z = -self.div_adjoint(y)
        z[:, :, 0] = (2.0 * self.alpha * self.totals(x))[:, None] * self.w[None]
        return z, y.sum(axis=0)

    def bounds(self, x: np.ndarray, y: np.ndarray) -> tuple[float, float, np.ndarray]:
        """``(value, lower_bound, distances)`` of a feasible iterate."""
        distances = np.linalg.norm(x[:, :, 1:], axis=2) @ self.w
        lower = -float(self.alpha @ self.totals(x) ** 2) - float(np.sum(y * self.m))
        return float(self.alpha @ distances**2), lower, distances


class _Newton:
    """Newton directions for fixed scalings (module docstring): one factorization of the
    coupled sparse part bordered by the rank-``k`` objective term."""

    def __init__(self, prog: _Program, layout: _CoupledPattern, x, rho, z, z_rho, factor,
                 backend):
        k, n_faces = x.shape[:2]
        self.prog, self.layout = prog, layout
        self.residual = prog.div(x) - rho[None] + prog.m  # (k, V)
        self.scaling = ip._nt_scaling(x.reshape(-1, 3), z.reshape(-1, 3))
        self.lam_rho = np.sqrt(rho * z_rho)
        self.d = rho / z_rho
        self.z_rho = z_rho
        g = np.zeros((k * n_faces, 3))
        g[:, 0] = np.tile(prog.w, k)
        self.h = self.scaling.apply_inverse_square(g).reshape(k, n_faces, 3)  # W⁻² g
        ghg = self.h[:, :, 0] @ prog.w
        self.c = 2.0 * prog.alpha / (1.0 + 2.0 * prog.alpha * ghg)
        self.v = prog.div(self.h)  # (k, V): D (W⁻² g)_u per block
        data = layout.data(ip.face_blocks(self.scaling, prog.products), self.d, self.v,
                           self.c)
        self.factor = _factor_coupled(layout, data, factor, backend)

    def _solve(self, r: np.ndarray) -> np.ndarray:
        """``Δy`` (:meth:`_CoupledPattern.scatter` order) of the normal equations with
        right-hand side ``r`` ``(k, V)``: the bordered system's first rows."""
        return self.factor.solve(self.layout.bordered(r))[:self.layout.size]

    def _rhs(self, rc: np.ndarray, rc_rho: np.ndarray):
        """``(W⁻¹ (λ \\ rc), rc_ρ / z_ρ, gᵀ of the former, r)``: ``r`` ``(k, V)`` the
        normal equations' right-hand side."""
        prog, sc = self.prog, self.scaling
        wq = sc.inverse_jordan_solve(rc).reshape(prog.k, len(prog.faces), 3)
        wq_rho = rc_rho / self.z_rho
        g_wq = wq[:, :, 0] @ prog.w
        r = -prog.div(wq) + (self.c * g_wq)[:, None] * self.v + wq_rho[None] - self.residual
        return wq, wq_rho, g_wq, r

    def __call__(self, rc: np.ndarray, rc_rho: np.ndarray):
        """Directions ``(dx (k F, 3), dρ, dy (k, V), dz (k F, 3), dz_ρ)`` for the
        complementarity right-hand sides ``rc`` ``(k F, 3)`` and ``rc_rho`` ``(V,)``; they
        also cancel the primal residual ``e = D u_i - ρ + m_i`` (:attr:`residual`), which
        rounding leaves, so a full step restores the divergence constraints."""
        wq, wq_rho, g_wq, r = self._rhs(rc, rc_rho)
        return self._direction(wq, wq_rho, g_wq, self._solve(r))

    def _direction(self, wq, wq_rho, g_wq, solution):
        prog, sc, v = self.prog, self.scaling, self.v
        k, n_faces = prog.k, len(prog.faces)
        dy = self.layout.gather(solution)
        coef = self.c * (np.sum(v * dy, axis=1) + g_wq)
        dx, dz = _direction_kernel(prog.faces, prog.l0, prog.l1, dy, sc.p.reshape(k, n_faces, 3),
                                   sc.beta.reshape(k, n_faces), wq, coef, self.h)
        drho = -self.d * dy.sum(axis=0) + wq_rho
        dz[:, :, 0] = (2.0 * prog.alpha * (dx[:, :, 0] @ prog.w))[:, None] * prog.w[None]
        return dx.reshape(-1, 3), drho, dy, dz.reshape(-1, 3), dy.sum(axis=0)


def _factor_coupled(layout: _CoupledPattern, data: np.ndarray, factor, backend: str):
    """Factor of the bordered normal matrix with CSR ``data`` (:meth:`_CoupledPattern.
    data`), refactoring ``factor`` in place when it can (a PARDISO factor takes the values
    on the pattern it analysed); None if ``data`` is not finite."""
    if not np.all(np.isfinite(data)):
        return None
    pardiso = ip._backend(backend) == "pardiso"
    try:
        if isinstance(factor, PardisoFactor):
            factor.refactor_data(data)
            return factor
        return _first_factor(layout.matrix(data, full=not pardiso), backend)
    except ValueError:  # zero pivot: the Cholesky lost definiteness to rounding
        return _pivoting_factor(layout.matrix(data, full=not pardiso), factor, backend)


def _first_factor(normal: sp.csr_matrix, backend: str):
    """The first iteration's factor: PARDISO's Cholesky with the analysis that the later
    iterations' refactorizations reuse (:data:`PARDISO_EFFORT`), else ``backend``'s."""
    return ip.factor_normal_matrix(normal, None, backend, pardiso_effort=PARDISO_EFFORT)


def _pivoting_factor(normal: sp.csr_matrix, failed, backend: str):
    """The normal matrix's factor once its Cholesky ``failed`` met a zero pivot (rounding
    near the end of the path; the matrix is positive semidefinite in exact arithmetic):
    PARDISO's symmetric-indefinite ``L D Lᵀ`` with pivot perturbation and iterative
    refinement, which then refactors in place for the remaining iterations (the Cholesky's
    memory is released first: it is not used again, but its fill-reducing ordering is:
    the pattern is the same, so the analysis skips the ordering); without PARDISO, LU with
    partial pivoting (``normal`` is then the whole symmetric matrix)."""
    if ip._backend(backend) == "pardiso":
        ordering = "metis"
        if isinstance(failed, PardisoFactor):
            ordering = failed.permutation
            failed.release()
        return PardisoFactor(normal, ordering=ordering, pivoting=True, effort=PARDISO_EFFORT)
    return ip.factor_normal_matrix(normal, None, "splu")


def barycenter_interior_point(full: ip.NormalStructure, kept: ip.NormalStructure, w: np.ndarray,
                              alpha: np.ndarray, m: np.ndarray, u0: np.ndarray,
                              rho0: np.ndarray, tol: float, max_iter: int, monitor,
                              backend: str = "auto",
                              correctors: int = CORRECTORS) -> BarycenterOutput:
    """The primal-dual loop (module docstring).

    ``full``/``kept``: the divergence's structure on every vertex / on all but one vertex
    per component (same faces); ``w`` ``(F,)`` finite face weights; ``alpha`` ``(k,)``
    positive; ``m`` ``(k, V)`` the inputs' masses; ``rho0`` ``(V,)`` > 0 with the inputs'
    component masses and ``u0`` ``(k, F, 2)`` flows with ``D u0_i = rho0 - m_i``;
    ``monitor`` is called with the certified relative gap."""
    prog = _Program(full, w, alpha, m)
    k, n = m.shape
    layout = _CoupledPattern(full, kept, k, n)
    x = np.stack([ip.cone_start(u, w) for u in u0])  # (k, F, 3)
    # dual start: y_1 = δ (constant: Dᵀ y_1 = 0), so z_ρ = δ balances ρ z_ρ against the
    # cones' mean complementarity
    cone_mu = float(2.0 * alpha @ prog.totals(x) ** 2) / (k * len(prog.faces))
    y = np.zeros((k, n))
    y[0] = n * cone_mu
    z, z_rho = prog.dual_slacks(x, y)
    shape = x.shape

    def advance(state):
        x, rho, y, z, z_rho, factor = state
        newton = _Newton(prog, layout, x, rho, z, z_rho, factor, backend)
        if newton.factor is None:
            return None
        dx, drho, dy, dz, dz_rho, step = ip.mehrotra_step(x.reshape(-1, 3), rho,
                                                          z.reshape(-1, 3), z_rho, newton,
                                                          correctors)
        x, rho, y = x + step * dx.reshape(shape), rho + step * drho, y + step * dy
        # the slacks by the step (the linear dual relation holds to rounding); recomputing
        # them from y would add the rounding of Dᵀ y_1, y_1 ~ a large constant
        z, z_rho = z + step * dz.reshape(shape), z_rho + step * dz_rho
        ok = (ip._interior(x.reshape(-1, 3)) and ip._interior(z.reshape(-1, 3)) and np.all(rho > 0)
              and np.all(z_rho > 0) and np.all(np.isfinite(y)))
        return (x, rho, y, z, z_rho, newton.factor) if ok else None

    def bounds(state):
        return prog.bounds(state[0], state[2])[:2]

    state, it, converged = ip.certified_loop((x, rho0.copy(), y, z, z_rho, None), advance,
                                          bounds, tol, max_iter, monitor, GAP_FLOOR)
    x, rho, y = state[:3]
    value, lower, distances = prog.bounds(x, y)
    feasibility = float(np.abs(prog.div(x) - rho[None] + m).max())
    return BarycenterOutput(u=x[:, :, 1:].copy(), rho=rho, y=y, distances=distances,
                            value=value, lower_bound=lower,
                            gap=ip.relative_gap(value, lower, GAP_FLOOR), iterations=it,
                            feasibility=feasibility,
                            converged=converged and feasibility <= FEASIBILITY_TOL)


def _start(ops, mesh, m: np.ndarray, geo):
    """``(rho0, u0)``: each component's mass spread by area, and the Poisson flows
    carrying it to every input (``D u0_i = rho0 - m_i``)."""
    labels, areas = ops.labels, mesh.areas
    density = np.bincount(labels, m[0]) / np.bincount(labels, areas)
    rho0 = areas * density[labels]
    u0 = []
    for mi in m:
        _, v = ops.particular_flow(mi - rho0)
        u0.append(np.einsum("fc,fdc->fd", v, geo.frames) * mesh.face_areas[:, None])
    return rho0, np.stack(u0)


def solve_barycenter_ipm(mesh, M: np.ndarray, alpha: np.ndarray, face_weights: np.ndarray,
                         tol: float, max_iter: int, monitor) -> dict:
    """Eq. 2.7 on ``mesh`` for validated inputs ``M`` ``(V, k)`` and weights ``alpha``
    ``(k,)`` (summing to 1), finite ``face_weights`` ``(F,)``: the coupled interior point over
    the inputs with positive weight; an input of weight 0 does not change the optimum, and its
    distance and flow come from the W1 interior point (:func:`solvers.emd.beckmann.
    earth_movers_distance`) afterwards.  Returns the fields of a
    :class:`~solvers.emd.exact.W1BarycenterResult` (flows as ``(k, F, 2)`` tangent
    coordinates ``u``, with the operators' ``frames``)."""
    ops = mesh_operators(mesh)
    geo, kept = ops.interior_point_structure
    k = M.shape[1]
    positive = np.flatnonzero(alpha > 0)
    m = np.ascontiguousarray(M[:, positive].T)
    u = np.zeros((k, mesh.n_faces, 2))
    if len(positive) == 1:  # the input itself, exactly
        rho, out = m[0].copy(), None
    else:
        full = ip.normal_structure(geo.div, kept.faces, np.arange(mesh.n))
        rho0, u0 = _start(ops, mesh, m, geo)
        out = barycenter_interior_point(full, kept, face_weights, alpha[positive], m, u0, rho0,
                                        tol, max_iter, monitor)
        rho = out.rho
        u[positive] = out.u
    report = {"iterations": 0 if out is None else out.iterations,
              "feasibility": 0.0 if out is None else out.feasibility,
              "gap": 0.0 if out is None else out.gap,
              "lower_bound": 0.0 if out is None else out.lower_bound,
              "converged": True if out is None else out.converged}
    distances = np.zeros(k)
    if out is not None:
        distances[positive] = out.distances
    flows = np.einsum("kfd,fdc->kfc", u, geo.frames) / mesh.face_areas[None, :, None]
    for j in np.flatnonzero(alpha <= 0):
        distances[j], flows[j] = _zero_weight_distance(mesh, rho, M[:, j], face_weights, tol,
                                                       max_iter, report)
    return {"masses": rho, "distances": distances, "flows": flows,
            "value": float(alpha @ distances**2), **report}


def _zero_weight_distance(mesh, rho, target, face_weights, tol, max_iter, report):
    """W1 from the barycenter to an input of weight 0 (certified interior point); folds
    its convergence into ``report``."""
    res = earth_movers_distance(mesh, rho, target, method="ipm", face_weights=face_weights,
                                tol=tol, max_iter=max_iter)
    report["converged"] = report["converged"] and bool(res.converged)
    report["feasibility"] = max(report["feasibility"], float(res.primal_residual))
    return res.value, res.flow
