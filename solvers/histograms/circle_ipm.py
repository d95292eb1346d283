r"""Structure-exploiting primal-dual interior-point method for the §5.4 propagation LP.

The LP of :mod:`solvers.histograms.circle` over *all* :math:`m B^2` plan entries,

.. math::  \min \sum_{e = (u, v)} w_e \langle C, \pi_e \rangle \quad\text{s.t.}\quad
           \pi_e \mathbf 1 = \mu_u,\; (\pi_e^\top \mathbf 1)_{j < B} = (\mu_v)_{j < B},\;
           \mathbf 1^\top \mu_v = 1 \text{ (unlabeled } v),\; \pi_e, \mu_v \ge 0,

(the last column marginal of every plan follows from the others; the same ``2B - 1``
independent rows per edge as the column-generation model) is solved by Mehrotra's
predictor-corrector method in standard form :math:`\min c^\top x,\ Ax = b,\ x \ge 0`.
Each iteration's normal equations :math:`A D A^\top \Delta y = g`
(:math:`D = X S^{-1}`) are never formed:

* per edge, the ``(2B - 1)``-square block :math:`K_e = A_{\pi_e} D_e A_{\pi_e}^\top =
  \begin{pmatrix} \operatorname{diag}(D_e \mathbf 1) & D_e' \\ D_e'^\top &
  \operatorname{diag}(\mathbf 1^\top D_e') \end{pmatrix}` (:math:`D_e'`: the plan's
  scaling without its last column) is inverted in closed form through its ``(B - 1)``-square
  Schur complement, batched over all edges;
* the edge duals are eliminated onto the unlabeled histograms: :math:`H = D_\mu^{-1} +
  A_\mu^\top K^{-1} A_\mu` (``n_free B`` unknowns, one dense ``B × B`` block per node and
  per edge between unlabeled nodes) is factored by a sparse Cholesky (MKL PARDISO with
  one symbolic analysis for all iterations, else CHOLMOD through cholespy);
* the normalization rows are handled by the augmented matrix :math:`G = H + E R E^\top`
  (:math:`E`: per-node sums, :math:`R` diagonal) and a preconditioned conjugate-gradient
  solve of the ``n_free``-square Schur system :math:`E^\top G^{-1} E`, a few iterations.

Status: the iterations are cheap (all edges batched), but in double precision the
normal equations lose accuracy as the scalings spread (condition numbers beyond
:math:`10^{16}`); with the small primal/dual regularization and iterative refinement used
here (``K + \delta I``, ``D \leftarrow (D^{-1} + \rho)^{-1}``) it stalls at a relative gap of
about :math:`10^{-3}` after 40-50 iterations (the 30- and 100-node k-NN cases of
``bench/histograms_circle.py``), so it is not a certified solver on its own.
:func:`solve_ipm` stops there and returns its best iterate;
:func:`solvers.histograms.circle.propagate_circular` (``lp_method="hybrid"``) uses its plans
and reduced costs as the starting support of the exact column generation.  Whatever ``y``
it returns, :func:`dual_bound` gives a valid lower bound
:math:`b^\top y + \sum_k \min(c - A^\top y, 0)_k` on the LP optimum (all variables lie in
``[0, 1]``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.errors import ConvergenceError


class _PatternCholesky:
    """Numeric Cholesky factorizations on the fixed upper-triangular pattern of ``H``.
    PARDISO keeps its ordering and symbolic analysis across calls
    (:meth:`solvers.linalg.PardisoFactor.refactor`); without the mkl wheel, cholespy
    factors the symmetrized matrix anew each time."""

    def __init__(self, indptr, indices, n, backend="auto"):
        from solvers.linalg import have_pardiso

        self.indptr, self.indices, self.n = indptr, indices, n
        if backend == "pardiso" and not have_pardiso():
            raise RuntimeError("PARDISO is not available")
        self.backend = "pardiso" if backend in ("auto", "pardiso") and have_pardiso() \
            else "cholespy"
        self._factor = None

    def factor(self, data) -> bool:
        """Factor the matrix with values ``data`` on the pattern; False if not SPD."""
        from solvers.linalg import PardisoFactor, factorize_spd

        upper = sp.csr_matrix((np.asarray(data, dtype=np.float64), self.indices, self.indptr),
                              shape=(self.n, self.n))
        try:
            if self.backend == "pardiso":
                if self._factor is None:
                    self._factor = PardisoFactor(upper)
                else:
                    self._factor.refactor(upper)
            else:
                self._factor = factorize_spd((upper + sp.triu(upper, 1).T).tocsr())
        except (ValueError, RuntimeError):  # not positive definite (numerically)
            return False
        return True

    def solve(self, rhs):
        return self._factor.solve(rhs)


class StructuredLP:
    r"""The §5.4 LP's data and its structured operators.

    ``X`` ``(m, B, B)`` plans, ``mu`` ``(n_free, B)`` unlabeled histograms; row duals
    ``yr`` ``(m, B)`` (row marginals), ``yc`` ``(m, B)`` (column marginals, last column
    always 0: that row is not in the LP), ``z`` ``(n_free,)`` (normalizations)."""

    def __init__(self, n, edges, w, nodes, h, cost, backend="auto"):
        B = cost.shape[0]
        m = len(edges)
        self.B, self.m = B, m
        edges = np.asarray(edges, dtype=np.int64)
        is_label = np.zeros(n, dtype=bool)
        is_label[nodes] = True
        self.free = np.flatnonzero(~is_label)
        nf = len(self.free)
        self.nf = nf
        fidx = np.full(n, -1, dtype=np.int64)
        fidx[self.free] = np.arange(nf)
        lrow = np.full(n, -1, dtype=np.int64)
        lrow[nodes] = np.arange(len(nodes))
        u, v = edges[:, 0], edges[:, 1]
        self.fu, self.fv = fidx[u], fidx[v]
        self.c = np.asarray(w, dtype=np.float64)[:, None, None] * cost[None]
        # right-hand sides of the edge rows (labeled ends) and of the normalizations
        self.br = np.zeros((m, B))
        self.bc = np.zeros((m, B))
        lu, lv = self.fu < 0, self.fv < 0
        self.br[lu] = h[lrow[u[lu]]]
        self.bc[lv] = h[lrow[v[lv]]]
        self.bc[:, -1] = 0.0
        # incidence of free nodes in edge ends (n_free, m)
        eu, ev = np.flatnonzero(~lu), np.flatnonzero(~lv)
        self.Su = sp.csr_matrix((np.ones(len(eu)), (self.fu[eu], eu)), shape=(nf, m))
        self.Sv = sp.csr_matrix((np.ones(len(ev)), (self.fv[ev], ev)), shape=(nf, m))
        self.aug = 1.0  # G = H + aug * E R E^T
        self.delta = 0.0  # dual regularization K + delta I
        self._pattern(backend)

    # --- the sparse pattern of H (upper triangle, B x B dense blocks) ------------------
    def _pattern(self, backend):
        B, nf = self.B, self.nf
        both = np.flatnonzero((self.fu >= 0) & (self.fv >= 0) & (self.fu != self.fv))
        a = np.minimum(self.fu[both], self.fv[both])
        b = np.maximum(self.fu[both], self.fv[both])
        pairs, inverse = np.unique(np.c_[a, b], axis=0, return_inverse=True)
        inverse = np.asarray(inverse).ravel()
        self.both = both
        self.flip = self.fu[both] > self.fv[both]
        self.P = sp.csr_matrix((np.ones(len(both)), (inverse, np.arange(len(both)))),
                               shape=(len(pairs), len(both)))
        self.pairs = pairs
        ii, jj = np.meshgrid(np.arange(B), np.arange(B), indexing="ij")
        up = (jj >= ii).ravel()
        # entries: diagonal blocks (upper triangles), then off-diagonal blocks (full)
        rd = (np.arange(nf)[:, None] * B + ii.ravel()[up][None]).ravel()
        cd = (np.arange(nf)[:, None] * B + jj.ravel()[up][None]).ravel()
        src_d = (np.arange(nf)[:, None] * B * B + np.flatnonzero(up)[None]).ravel()
        ro = (pairs[:, 0][:, None] * B + ii.ravel()[None]).ravel()
        co = (pairs[:, 1][:, None] * B + jj.ravel()[None]).ravel()
        src_o = nf * B * B + np.arange(len(pairs) * B * B)
        rows, cols = np.r_[rd, ro], np.r_[cd, co]
        src = np.r_[src_d, src_o]
        N = nf * B
        A = sp.csr_matrix((src.astype(np.float64) + 1.0, (rows, cols)), shape=(N, N))
        A.sort_indices()
        self.src = A.data.astype(np.int64) - 1
        self.N = N
        self.solver = _PatternCholesky(A.indptr, A.indices, N, backend)
        self.backend = self.solver.backend

    # --- A, A^T ----------------------------------------------------------------------
    def A_x(self, X, mu):
        """Edge-row and normalization-row values of ``A x``."""
        ar = X.sum(axis=2)
        ac = X.sum(axis=1)
        ac[:, -1] = 0.0
        if self.nf:
            ar[self.fu >= 0] -= mu[self.fu[self.fu >= 0]]
            sel = self.fv >= 0
            ac[sel, :-1] -= mu[self.fv[sel], :-1]
        return ar, ac, mu.sum(axis=1)

    def At_y(self, yr, yc, z):
        """Plan and histogram parts of ``A^T y`` (``yc[:, -1]`` taken as 0)."""
        yc = yc.copy()
        yc[:, -1] = 0.0
        tp = yr[:, :, None] + yc[:, None, :]
        tm = -(self.Su @ yr) - (self.Sv @ yc) + z[:, None]
        return tp, tm

    def b_dot(self, yr, yc, z):
        return float(np.sum(self.br * yr) + np.sum(self.bc[:, :-1] * yc[:, :-1]) + z.sum())

    # --- normal equations ------------------------------------------------------------
    def prepare(self, D, Dmu):
        """Factor the normal equations for scalings ``D`` (plans) and ``Dmu``."""
        B = self.B
        delta = self.delta
        a = D.sum(axis=2) + delta                           # (m, B)
        Wc = D[:, :, :-1]                                   # (m, B, B-1)
        Mt = Wc / a[:, :, None]
        # Schur complement T = diag(1^T Wc + delta) - Wc^T diag(a)^{-1} Wc of K + delta I: a
        # weighted Laplacian on the first B - 1 columns plus a grounding term.  Its diagonal
        # is assembled from the (positive) off-diagonal weights and the grounding, not by the
        # cancelling difference, so T stays diagonally dominant in floating point.
        T = -np.matmul(Wc.transpose(0, 2, 1), Mt)
        idx = np.arange(B - 1)
        T[:, idx, idx] = 0.0
        ground = np.einsum("eij,ei->ej", Mt, D[:, :, -1] + delta)
        T[:, idx, idx] = ground - T.sum(axis=2) + delta
        L = np.linalg.cholesky(T)
        Linv = np.linalg.inv(L)
        Tinv = np.matmul(Linv.transpose(0, 2, 1), Linv)
        MT = np.matmul(Mt, Tinv)                            # (m, B, B-1)
        Krr = np.matmul(MT, Mt.transpose(0, 2, 1))
        Krr[:, np.arange(B), np.arange(B)] += 1.0 / a
        self.Krr, self.Krc, self.Kcc = Krr, -MT, Tinv
        if self.nf == 0:
            return
        m = self.m
        Kcc_pad = np.zeros((m, B, B))
        Kcc_pad[:, :-1, :-1] = Tinv
        Krc_pad = np.zeros((m, B, B))
        Krc_pad[:, :, :-1] = -MT
        Hd = (self.Su @ Krr.reshape(m, B * B) + self.Sv @ Kcc_pad.reshape(m, B * B))
        Hd = Hd.reshape(self.nf, B, B)
        Hd[:, np.arange(B), np.arange(B)] += 1.0 / Dmu
        diag = np.einsum("vii->vi", Hd).copy()
        # R_v = 1 / (1^T H_vv^{-1} 1) <= 1 / (E^T H^{-1} E)_vv: the scale of H in the
        # direction of node v's total mass (the Schur system's Jacobi preconditioner)
        ones = np.ones((self.nf, B, 1))
        Lv = np.linalg.cholesky(Hd)
        hv = np.linalg.solve(Lv, ones)[..., 0]
        self.R = self.aug / np.einsum("vi,vi->v", hv, hv)
        Hd += self.R[:, None, None]
        off = Krc_pad[self.both]
        off[self.flip] = off[self.flip].transpose(0, 2, 1)
        Ho = self.P @ off.reshape(len(self.both), B * B)
        data = np.concatenate([Hd.ravel(), np.asarray(Ho).ravel()])[self.src]
        ok = self.solver.factor(data)
        shift = 1e-12 * float(diag.max())
        while not ok:
            Hd[:, np.arange(B), np.arange(B)] += shift
            data = np.concatenate([Hd.ravel(), np.asarray(Ho).ravel()])[self.src]
            ok = self.solver.factor(data)
            shift *= 100.0
            if shift > 1e-2 * float(diag.max()):
                raise ConvergenceError("the IPM's normal equations are not positive definite")

    def K_solve(self, gr, gc):
        """``K^{-1}`` of edge-row vectors (``gc[:, -1]`` ignored, returned as 0)."""
        gcc = gc[:, :-1]
        yr = np.einsum("eij,ej->ei", self.Krr, gr) + np.einsum("eij,ej->ei", self.Krc, gcc)
        yc = np.zeros_like(gc)
        yc[:, :-1] = (np.einsum("eji,ej->ei", self.Krc, gr)
                      + np.einsum("eij,ej->ei", self.Kcc, gcc))
        return yr, yc

    def normal_solve(self, gr, gc, gz, cg_tol=1e-12, cg_max=200):
        """Solve ``A D A^T (yr, yc, z) = (gr, gc, gz)`` with the prepared factors."""
        kr, kc = self.K_solve(gr, gc)
        if self.nf == 0:
            return kr, kc, np.zeros(0), 0
        B = self.B
        q = -(self.Su @ kr) - (self.Sv @ kc)              # A_mu^T K^{-1} g
        solve = self.solver.solve
        t = solve(q.ravel()).reshape(self.nf, B)
        # E^T G^{-1} E omega = gz - E^T t0, preconditioned by R
        rhs = gz - t.sum(axis=1)
        omega = np.zeros(self.nf)
        r = rhs.copy()
        p = self.R * r
        rz = float(r @ p)
        norm0 = float(np.linalg.norm(rhs)) + 1e-300
        its = 0
        while its < cg_max and float(np.linalg.norm(r)) > cg_tol * max(norm0, 1e-30):
            its += 1
            Gp = solve(np.repeat(p, B)).reshape(self.nf, B)
            Sp = Gp.sum(axis=1)
            alpha = rz / float(p @ Sp)
            omega += alpha * p
            t += alpha * Gp
            r -= alpha * Sp
            zr = self.R * r
            rz_new = float(r @ zr)
            p = zr + (rz_new / rz) * p
            rz = rz_new
            if float(np.linalg.norm(r)) <= 1e-15 * norm0:
                break
        z = omega - self.R * gz
        # edge duals: K y_e = g_e - A_mu t  (A_mu t = -t_u on row-rows, -t_v on col-rows)
        tr = np.zeros((self.m, B))
        tc = np.zeros((self.m, B))
        su, sv = self.fu >= 0, self.fv >= 0
        tr[su] = t[self.fu[su]]
        tc[sv] = t[self.fv[sv]]
        yr, yc = self.K_solve(gr + tr, gc + tc)
        return yr, yc, z, its

    def ADAt(self, D, Dmu, yr, yc, z):
        tp, tm = self.At_y(yr, yc, z)
        return self.A_x(D * tp, Dmu * tm)


def _max_step(x, dx):
    neg = dx < 0
    if not np.any(neg):
        return np.inf
    return float(np.min(-x[neg] / dx[neg]))


def _direction(lp: StructuredLP, state, rcp, rcm, refine):
    """Newton direction for the complementarity right-hand side ``(rcp, rcm)``: the normal
    equations solved with the prepared (regularized) factors and refined against the
    unregularized ``A D A^T``."""
    X, mu, S, Smu, D, Dmu, (rpr, rpc, rpz), (rdp, rdm) = state
    # g = r_p - A (S^{-1} r_c - D r_d)
    gr_, gc_, gz_ = lp.A_x(rcp / S - D * rdp, rcm / Smu - Dmu * rdm)
    gr, gc, gz = rpr - gr_, rpc - gc_, rpz - gz_
    gc[:, -1] = 0.0
    dyr, dyc, dz, its = lp.normal_solve(gr, gc, gz)
    scale = max(float(np.abs(gr).max()), float(np.abs(gc).max()),
                float(np.abs(gz).max(initial=0)), 1e-300)
    for _ in range(refine):
        er, ec, ez = lp.ADAt(D, Dmu, dyr, dyc, dz)
        er, ec, ez = gr - er, gc - ec, gz - ez
        ec[:, -1] = 0.0
        err = max(float(np.abs(er).max()), float(np.abs(ec).max()),
                  float(np.abs(ez).max(initial=0)))
        if err <= 1e-12 * scale:
            break
        cr, cc, cz, its2 = lp.normal_solve(er, ec, ez)
        dyr, dyc, dz = dyr + cr, dyc + cc, dz + cz
        its += its2
    dyc[:, -1] = 0.0
    tp, tm = lp.At_y(dyr, dyc, dz)
    dSp, dSm = rdp - tp, rdm - tm
    dXp = (rcp - X * dSp) / S
    dXm = (rcm - mu * dSm) / Smu
    return dXp, dXm, dyr, dyc, dz, dSp, dSm, its


def _mehrotra_start(lp: StructuredLP):
    """Mehrotra's starting point ``(X, mu, S, Smu, yr, yc, z)``: x = A^T (A A^T)^{-1} b,
    y = (A A^T)^{-1} A c, s = c - A^T y, shifted to the interior."""
    B, m, nf = lp.B, lp.m, lp.nf
    ones, ones_mu = np.ones((m, B, B)), np.ones((nf, B))
    lp.prepare(ones, ones_mu)
    bc0 = lp.bc.copy()
    yr0, yc0, z0, _ = lp.normal_solve(lp.br, bc0, np.ones(nf))
    X, mu = lp.At_y(yr0, yc0, z0)
    ar, ac, az = lp.A_x(lp.c, np.zeros((nf, B)))
    yr, yc, z, _ = lp.normal_solve(ar, ac, az)
    yc[:, -1] = 0.0
    tp, tm = lp.At_y(yr, yc, z)
    S, Smu = lp.c - tp, -tm
    dx = max(-1.5 * min(float(X.min()), float(mu.min(initial=np.inf))), 0.0)
    ds = max(-1.5 * min(float(S.min()), float(Smu.min(initial=np.inf))), 0.0)
    X, mu, S, Smu = X + dx, mu + dx, S + ds, Smu + ds
    xs = float(np.sum(X * S) + np.sum(mu * Smu))
    dx2 = 0.5 * xs / (float(S.sum()) + float(Smu.sum()))
    ds2 = 0.5 * xs / (float(X.sum()) + float(mu.sum()))
    X, mu, S, Smu = X + dx2, mu + dx2, S + ds2, Smu + ds2
    return X, mu, S, Smu, yr, yc, z


def _residuals(lp: StructuredLP, X, mu, S, Smu, yr, yc, z):
    """Primal ``(rpr, rpc, rpz)`` and dual ``(rdp, rdm)`` residuals of an iterate."""
    ar, ac, am = lp.A_x(X, mu)
    rpr, rpc, rpz = lp.br - ar, lp.bc - ac, 1.0 - am
    rpc[:, -1] = 0.0
    tp, tm = lp.At_y(yr, yc, z)
    rdp, rdm = lp.c - tp - S, -tm - Smu
    return (rpr, rpc, rpz), (rdp, rdm)


def _predictor_corrector_step(lp: StructuredLP, iterate, residuals, mu_c, eta, refine):
    """One Mehrotra step on the iterate ``(X, mu, S, Smu, yr, yc, z)``, in place, with the
    normal equations already prepared; returns the CG iterations of its two solves."""
    X, mu, S, Smu, yr, yc, z = iterate
    total = X.size + mu.size
    st = (X, mu, S, Smu, X / S, mu / Smu, *residuals)

    def direction(rcp, rcm):
        return _direction(lp, st, rcp, rcm, refine)

    # predictor
    aff = direction(-X * S, -mu * Smu)
    ap = min(1.0, _max_step(X, aff[0]), _max_step(mu, aff[1]))
    ad = min(1.0, _max_step(S, aff[5]), _max_step(Smu, aff[6]))
    mu_aff = (float(np.sum((X + ap * aff[0]) * (S + ad * aff[5])))
              + float(np.sum((mu + ap * aff[1]) * (Smu + ad * aff[6])))) / total
    sigma = (mu_aff / mu_c) ** 3
    # corrector
    cor = direction(-X * S - aff[0] * aff[5] + sigma * mu_c,
                    -mu * Smu - aff[1] * aff[6] + sigma * mu_c)
    dXp, dXm, dyr, dyc, dz, dSp, dSm, _ = cor
    ap = min(1.0, eta * _max_step(X, dXp), eta * _max_step(mu, dXm))
    ad = min(1.0, eta * _max_step(S, dSp), eta * _max_step(Smu, dSm))
    X += ap * dXp
    mu += ap * dXm
    S += ad * dSp
    Smu += ad * dSm
    yr += ad * dyr
    yc += ad * dyc
    z += ad * dz
    yc[:, -1] = 0.0
    return aff[-1] + cor[-1]


def solve_ipm(n, edges, w, nodes, h, cost, monitor, *, tol=1e-9, max_iter=200,
              backend="auto", time_limit=None, reg=1e-10, reg_p=1e-10, refine=3):
    """Mehrotra predictor-corrector on :class:`StructuredLP`.

    Stops at ``max(relative gap, primal, dual residual) <= tol``, after ``max_iter``
    iterations, at ``time_limit`` seconds, or when the normal equations break down
    numerically (the merit grows tenfold above its best, or the factorization fails);
    returns the *best* iterate seen (by that merit) as a dict: histograms ``mu``
    ``(n_free, B)``, plans ``X`` ``(m, B, B)``, duals ``yr, yc, z``, the :class:`StructuredLP`
    ``lp``, ``iterations``, ``status``, ``merit`` and the per-iteration ``history``
    ``(iteration, primal objective, dual objective, gap, primal res., dual res.)``.
    ``reg``/``reg_p``: dual/primal regularization of the normal equations (iterative
    refinement against the unregularized ones, ``refine`` steps at most)."""
    import time

    t_start = time.perf_counter()
    lp = StructuredLP(n, edges, w, nodes, h, cost, backend=backend)
    X, mu, S, Smu, yr, yc, z = _mehrotra_start(lp)
    total = X.size + mu.size
    b_norm = 1.0 + max(float(np.abs(lp.br).max(initial=0)), float(np.abs(lp.bc).max(initial=0)),
                       1.0)
    c_norm = 1.0 + float(np.abs(lp.c).max())
    history = []
    best = (np.inf,)
    cg_total = 0
    it = 0
    status = "max_iter"
    while it < max_iter:
        residuals = _residuals(lp, X, mu, S, Smu, yr, yc, z)
        (rpr, rpc, rpz), (rdp, rdm) = residuals
        pobj = float(np.sum(lp.c * X))
        dobj = lp.b_dot(yr, yc, z)
        gap = abs(pobj - dobj) / (1.0 + abs(pobj))
        pres = max(float(np.abs(rpr).max()), float(np.abs(rpc).max()),
                   float(np.abs(rpz).max(initial=0))) / b_norm
        dres = max(float(np.abs(rdp).max()), float(np.abs(rdm).max(initial=0))) / c_norm
        mu_c = (float(np.sum(X * S)) + float(np.sum(mu * Smu))) / total
        history.append((it, pobj, dobj, gap, pres, dres))
        merit = max(gap, pres, dres)
        monitor(it, merit)
        if merit < best[0]:
            best = (merit, it, X.copy(), mu.copy(), yr.copy(), yc.copy(), z.copy())
        if merit <= tol:
            status = "optimal"
            break
        if merit > 10.0 * best[0] or not np.isfinite(merit):
            status = "stalled"
            break
        if time_limit is not None and time.perf_counter() - t_start > time_limit:
            status = "time_limit"
            break
        monitor.check_cancel("in the IPM")
        it += 1
        lp.delta = reg
        try:
            lp.prepare(1.0 / (S / X + reg_p), 1.0 / (Smu / mu + reg_p))
        except (ConvergenceError, np.linalg.LinAlgError):
            status = "breakdown"
            break
        cg_total += _predictor_corrector_step(lp, (X, mu, S, Smu, yr, yc, z), residuals, mu_c,
                                              0.99 if it > 1 else 0.9, refine)
    merit, best_it, X, mu, yr, yc, z = best
    return {"lp": lp, "X": X, "mu": mu, "yr": yr, "yc": yc, "z": z, "iterations": it,
            "best_iteration": best_it, "merit": merit, "status": status, "history": history,
            "cg_iterations": cg_total}


def dual_bound(lp: StructuredLP, yr, yc, z) -> tuple[float, float]:
    r"""Lower bound :math:`b^\top y + \sum_k \min(c - A^\top y, 0)_k` on the full LP (every
    variable lies in ``[0, 1]``) and the most negative reduced cost."""
    yc = yc.copy()
    yc[:, -1] = 0.0
    tp, tm = lp.At_y(yr, yc, z)
    rp, rm = lp.c - tp, -tm
    neg = float(np.minimum(rp, 0.0).sum() + np.minimum(rm, 0.0).sum())
    return lp.b_dot(yr, yc, z) + neg, min(float(rp.min()), float(rm.min(initial=0)))

