r"""Harmonic extension: the Dirichlet problem on the unlabeled nodes for many columns at once.

Given values :math:`V_L` (``k × c``) at the labeled nodes :math:`L`, the minimizer of the
Dirichlet energy :math:`\operatorname{tr}(X^\top \mathcal{L} X)` with :math:`X_L = V_L`
solves, on the unlabeled nodes :math:`U`,

.. math::  \mathcal{L}_{UU} X_U = -\mathcal{L}_{UL} V_L .

One factorization of :math:`\mathcal{L}_{UU}` (positive definite when every connected
component holds a labeled node), one block solve for all ``c`` columns.  Before solving,
the columns are compressed: with the thin SVD :math:`V_L - \bar V = P S Q^\top` (column
means :math:`\bar V` extend to constants), only the ``r`` columns of :math:`P S` with
:math:`s_i > \text{rank\_tol}\, s_0` are solved and :math:`X_U = Y Q_r^\top + \bar V`
(the solve is linear in the columns); when ``r > 0.8 c`` all columns are solved as they
are.  Inverse CDFs of real
labels are smooth in the level, so ``r`` is far below ``c``; the largest truncation error
on the labels is measured and reported (with non-negative weights the maximum principle
bounds the error everywhere by it).

``linear_method``: ``"direct"`` (sparse Cholesky, :func:`solvers.linalg.factorize_spd`) or
``"amg"`` (conjugate gradients preconditioned by one smoothed-aggregation hierarchy from
pyamg, shared by all columns); ``"auto"`` is ``"direct"``, faster at every size measured
(``bench/results/histograms.md``).  The direct factorization is MKL PARDISO's supernodal
Cholesky (METIS ordering, multithreaded) when the ``mkl`` wheel is installed (the
``pardiso`` extra), else cholespy's; ``factorization=`` in :func:`dirichlet_system` picks
one explicitly.  The block solve goes a few columns at a time, and each block's residual
is measured as soon as it is solved, so the solution overwrites the right-hand sides
(no second ``n × r`` array).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.domains.base import Domain
from solvers.errors import ConvergenceError, InputError
from solvers.histograms.graphs import component_labels, graph_laplacian
from solvers.linalg import Backend, factorize_spd, have_pardiso
from solvers.monitor import Monitor
from solvers.validation import check_anchored_components, check_choice, check_node_indices

LINEAR_METHODS = ("auto", "direct", "amg")


@dataclass
class DirichletSystem:
    """A factored (or preconditioned) reduced Laplacian :math:`\\mathcal{L}_{UU}`."""

    n: int
    labeled: np.ndarray
    free: np.ndarray
    A: sp.csr_matrix  # L_UU
    coupling: sp.csr_matrix  # L_UL
    linear_method: str
    factor: object = None
    hierarchy: object = None

    @property
    def nbytes(self) -> int:
        own = self.A.data.nbytes * 2 + self.coupling.data.nbytes * 2
        fac = getattr(self.factor, "nbytes", 0) or 0
        return int(own + fac + self.free.nbytes + self.labeled.nbytes)


def check_labeled(graph, labeled, L: sp.spmatrix | None = None,
                  field: str = "labeled") -> np.ndarray:
    """Validate labeled nodes: distinct indices, at least one in every connected component.

    Parameters
    ----------
    graph : Graph, TriangleMesh, PointCloud, Grid or (n, n) sparse matrix
        The domain, or a symmetric non-negative weight matrix (see :mod:`.graphs`).
    labeled : (k,) int array
        Node indices.
    L : (n, n) sparse matrix, optional
        The graph's Laplacian, if already built.
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised.

    Returns
    -------
    (k,) int array
    """
    n = graph.n if isinstance(graph, Domain) else graph.shape[0]
    nodes = check_node_indices(labeled, n, field)
    _, labels = component_labels(graph, L if L is not None else graph_laplacian(graph))
    check_anchored_components(labels, nodes, field)
    return nodes


def direct_backend(factorization: Backend = "auto") -> Backend:
    """The factorization behind ``linear_method="direct"``: PARDISO when it loads, else cholespy's
    (``"auto"``); an explicit name is passed through."""
    if factorization != "auto":
        return factorization
    return "pardiso" if have_pardiso() else "auto"


def _reduced(L: sp.csr_matrix, free: np.ndarray, labeled: np.ndarray
             ) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """``(L_UU, L_UL)``: the free rows once, then their two column blocks."""
    Lr = L[free]
    return Lr[:, free].tocsr(), Lr[:, labeled].tocsr()


def _build(L: sp.csr_matrix, labeled: np.ndarray, linear_method: str,
           factorization: Backend = "auto") -> DirichletSystem:
    n = L.shape[0]
    mask = np.zeros(n, dtype=bool)
    mask[labeled] = True
    free = np.flatnonzero(~mask)
    A, coupling = _reduced(L, free, labeled)
    system = DirichletSystem(n, labeled, free, A, coupling, linear_method)
    if len(free) == 0:
        return system
    if linear_method == "direct":
        system.factor = factorize_spd(A, backend=direct_backend(factorization))
    else:
        try:
            import pyamg
        except ImportError as exc:  # pragma: no cover
            raise InputError("linear_method='amg' needs pyamg installed",
                             field="linear_method") from exc
        system.hierarchy = pyamg.smoothed_aggregation_solver(A, symmetry="symmetric")
    return system


def dirichlet_system(graph, labeled, *, laplacian: str = "auto", linear_method: str = "auto",
                     field: str = "labeled", factorization: Backend = "auto"
                     ) -> DirichletSystem:
    r"""The reduced system :math:`\mathcal{L}_{UU}` for ``labeled`` nodes (Prop. 13).

    Factored once and cached in the domain's operator store.

    Parameters
    ----------
    graph : Graph, TriangleMesh, PointCloud, Grid or (n, n) sparse matrix
        The domain, or a symmetric non-negative weight matrix (see :mod:`.graphs`).
    labeled : (k,) int array
        Labeled nodes, at least one per connected component.
    laplacian : {"auto", "robust", "cotan"}
        The Laplacian of a mesh (cotangent or robust); other domains have one.
    linear_method : {"auto", "direct", "amg"}
        Sparse Cholesky, or AMG-preconditioned CG.
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised.
    factorization : {"auto", "pardiso", "cholespy", "splu"}
        Backend of ``linear_method="direct"`` (``"auto"``: :func:`direct_backend`).

    Returns
    -------
    DirichletSystem
        The factored (or preconditioned) :math:`\mathcal{L}_{UU}`, the coupling
        :math:`\mathcal{L}_{UL}` and the index sets.
    """
    check_choice(linear_method, LINEAR_METHODS, "linear_method")
    linear_method = "direct" if linear_method == "auto" else linear_method
    L = graph_laplacian(graph, laplacian)
    nodes = check_labeled(graph, labeled, L, field)
    if not isinstance(graph, Domain):
        return _build(L, np.sort(nodes), linear_method, factorization)
    digest = hashlib.sha1(np.sort(nodes).tobytes()).hexdigest()
    backend = direct_backend(factorization) if linear_method == "direct" else ""
    key = ("histograms.dirichlet", laplacian, linear_method, backend, len(nodes), digest)
    system = graph.operators.get(key, lambda: _build(L, np.sort(nodes), linear_method,
                                                     factorization))
    return system


def _amg_solve(system: DirichletSystem, B: np.ndarray, tol: float, max_iter: int,
               monitor: Monitor) -> tuple[np.ndarray, int]:
    """Preconditioned CG, one column after another, on one shared AMG hierarchy."""
    X = np.empty_like(B)
    total = 0
    for j in range(B.shape[1]):
        residuals: list[float] = []
        X[:, j] = system.hierarchy.solve(B[:, j], tol=tol, maxiter=max_iter, accel="cg",
                                         residuals=residuals)
        total += len(residuals)
        monitor(j, residuals[-1] / max(residuals[0], 1e-300) if residuals else 0.0)
    return X, total


@dataclass
class Extension:
    values: np.ndarray  # (n, c)
    rank: int
    compression_error: float
    residual: float
    iterations: int


def harmonic_extension(system: DirichletSystem, values: np.ndarray, *, rank_tol: float = 1e-9,
                       tol: float = 1e-10, max_iter: int = 500, progress=None,
                       should_cancel=None) -> Extension:
    r"""Harmonic extension of labeled values.

    Solves :math:`\mathcal{L}_{UU} Y = -\mathcal{L}_{UL} X` for the free nodes.
    The columns of ``values`` are compressed (truncated SVD) before one block solve.

    Parameters
    ----------
    system : DirichletSystem
        From :func:`dirichlet_system`.
    values : (k, c) array
        Labeled values, rows in ``labeled`` order.
    rank_tol : float
        Relative singular-value cut of the column compression.
    tol : float
        Relative residual tolerance of CG (``linear_method="amg"``).
    max_iter : int
        CG iteration budget.
    progress, should_cancel : callable, optional
        As in :func:`~solvers.histograms.propagate_histograms`.

    Returns
    -------
    Extension
        ``values`` ``(n, c)``, the ``rank`` solved, the ``compression_error``, the measured
        ``residual`` :math:`\|A Y - B\|_F / \|B\|_F` and the ``iterations``.
    """
    V = np.asarray(values, dtype=np.float64)
    if V.ndim != 2 or V.shape[0] != len(system.labeled):
        raise InputError(f"values must be ({len(system.labeled)}, c), got {V.shape}",
                         field="values")
    monitor = Monitor(progress, should_cancel, tol=tol)
    monitor.check_cancel("before the Dirichlet solve")
    n, c = system.n, V.shape[1]
    out = np.empty((n, c))
    out[system.labeled] = V
    if len(system.free) == 0:
        return Extension(out, 0, 0.0, 0.0, 0)
    # compress the columns: Vc = P S Q^T (from the c x c Gram matrix), keep
    # s_i > rank_tol * s_0; solve for Vc Q_r and expand with Q_r^T. Worth it only when
    # the rank is well below c; else all columns are solved as they are.
    shift = V.mean(axis=0)  # constants extend to constants: solve only the rest
    Vc = V - shift
    Qt = None
    r, err = c, 0.0
    if c > 1:
        evals, evecs = np.linalg.eigh(Vc.T @ Vc)
        sv = np.sqrt(np.clip(evals[::-1], 0.0, None))
        r = int(np.sum(sv > rank_tol * sv[0])) if sv[0] > 0 else 0
        if r == 0:
            out[system.free] = shift
            return Extension(out, 0, float(np.abs(Vc).max()), 0.0, 0)
        if r <= 0.8 * c:
            Qr = evecs[:, ::-1][:, :r]
            Qt = Qr.T.copy()
            basis = Vc @ Qr
            err = float(np.abs(Vc - basis @ Qt).max())
        else:
            r = c
    if Qt is None:
        basis = Vc
    # B = -L_UL basis; only rows next to a labeled node are nonzero. PARDISO works on
    # columns, so B is laid out in Fortran order for it (its blocks are then no copies)
    column_major = getattr(system.factor, "backend", "") == "pardiso"
    B = np.zeros((len(system.free), r), order="F" if column_major else "C")
    touched = np.flatnonzero(np.diff(system.coupling.indptr))
    B[touched] = -(system.coupling[touched] @ basis)
    num = den = 0.0
    if system.factor is not None:
        from solvers.histograms._kernels import block_residual_parts

        # blocks of columns (the linear solver's copies stay ~128 MB); each block's residual is
        # measured right away (a compiled pass, no n x w product), then its solution
        # overwrites the block of B
        width = _block_columns(r, len(system.free))
        for j in range(0, r, width):
            Bj = B[:, j:j + width]
            Xj = system.factor.solve(Bj)
            nj, dj = block_residual_parts(system.A.indptr, system.A.indices, system.A.data,
                                          Xj, Bj)
            num += float(nj)
            den += float(dj)
            Bj[...] = Xj
        Y, iterations = B, 1
    else:
        Y, iterations = _amg_solve(system, B, tol, max_iter, monitor)
        num, den = _residual_parts(system.A, Y, B)
    del B
    # a non-finite value in Y makes the residual sum non-finite (one check, no pass over Y)
    if not np.isfinite(num) and not np.all(np.isfinite(Y)):
        raise ConvergenceError("the Dirichlet solve produced non-finite values")
    residual = float(np.sqrt(num / den)) if den > 0 else 0.0
    monitor(iterations, residual)
    rows = max(1, 2**22 // max(c, 1))  # back to c columns (plus the means) in row blocks
    for s in range(0, len(system.free), rows):
        block = Y[s:s + rows] if Qt is None else Y[s:s + rows] @ Qt
        block += shift
        out[system.free[s:s + rows]] = block
    return Extension(out, r, err, residual, iterations)


def _block_columns(r: int, n: int) -> int:
    """Columns per block solve: the linear solver's copies of a block stay ~128 MB."""
    return max(1, min(r, 2**24 // max(n, 1)))


def _residual_parts(A: sp.csr_matrix, Y: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """``(‖A Y − B‖², ‖B‖²)`` a few rows at a time (no second ``n × r`` temporary)."""
    num = den = 0.0
    height = max(1, 2**22 // max(Y.shape[1], 1))
    for i in range(0, A.shape[0], height):
        Bi = B[i:i + height]
        Ri = A[i:i + height] @ Y
        Ri -= Bi
        num += float(np.einsum("ij,ij->", Ri, Ri))
        den += float(np.einsum("ij,ij->", Bi, Bi))
    return num, den
