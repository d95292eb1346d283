r"""Distance matrices: every pair of a collection (or against a second set) in one call.

:func:`distance_matrix` computes :math:`D_{ij} = W(\mu_i, \nu_j)` for ``n`` distributions
``mu`` against ``m`` distributions ``nu`` (``others``), or the symmetric ``n x n`` matrix of
one collection (only the pairs ``i < j`` are solved; the diagonal is zero for the debiased
Sinkhorn divergence, the exact W2 and W1).

* ``metric="w2"`` — each pair gets exactly the decision of the single-pair default
  (:func:`~solvers.transport.decision.decide_distance`: method and regularization from
  the data alone), so every entry equals ``wasserstein_distance(domain, mu_i, nu_j, ...)``:

  - **exact method** (sparse supports): the cost matrix between all row supports and all
    column supports of the exact pairs is computed once (squared exact geodesics on meshes,
    one MMP solve per point of the smaller side; squared straight/periodic distances on
    grids and point clouds) and each pair is the transport LP (thesis eq. 1.1) on its
    sub-matrix (beyond :data:`SHARED_COST_ENTRIES` entries each pair computes its own, as
    a single-pair call does);
  - **convolutional method** (Alg. 1 / eq. 3.10, debiased as the defaults are): pairs that
    share a heat kernel (same ``t`` and ``substeps``) run as one block.  Every solver step
    gathers the log-inputs of all active pairs into one ``n x k`` block and applies the
    kernel once (one multi-column sparse solve per substep,
    :class:`~solvers.convolutional.common.LogKernel`); each pair keeps its own Anderson
    history, stopping rule and stagnation record (:func:`~solvers.convolutional.distance.
    pair_steps`, the very iteration of the single-pair solver), leaves the block when it
    stops, and the next pair enters.

* ``metric="w1"`` — :func:`solvers.emd.earth_movers_distance` (Beckmann problem, eq. 2.1)
  per pair, on the mesh's shared operators.

Progress is reported over pairs and cancellation keeps the finished entries: on
cancellation :class:`~solvers.errors.CancelledError` is raised with the partial
:class:`DistanceMatrixResult` in its ``partial`` attribute (pairs run in row order, so
finished rows come first).
"""

from __future__ import annotations

import threading
from collections import OrderedDict, deque
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from solvers.convolutional.common import prepare
from solvers.convolutional.distance import (
    ANDERSON_MEMORY,
    PairSolve,
    pair_steps,
    watch_stagnation,
)
from solvers.errors import CancelledError, InputError
from solvers.monitor import SolverResult, _arity
from solvers.parallel import thread_count
from solvers.regularization import sketch_of
from solvers.transport.decision import DistanceDecision, decide_distance, decide_method
from solvers.transport.exact import MAX_SUPPORT_PRODUCT, _finite_cost
from solvers.validation import check_choice, masses_block

METRICS = ("w2", "w1")
# Pairs advanced together: at most MAX_BLOCK_PAIRS, and as many as fit BLOCK_WORK_BYTES of
# per-pair state (Anderson history 2 x ANDERSON_MEMORY columns plus ~12 work vectors of n).
MAX_BLOCK_PAIRS = 64
BLOCK_WORK_BYTES = 256 * 2**20
_PAIR_VECTORS = 2 * ANDERSON_MEMORY + 12
# Largest shared cost matrix of the exact pairs (entries; 256 MB): beyond it each exact pair
# computes its own costs as a single-pair call does (bounded geodesic solves).
SHARED_COST_ENTRIES = 2**25
# Squared costs kept per row of the exact pairs (entries; 32 MB): :class:`_RowBlocks`.
ROW_BLOCK_ENTRIES = 2**22
# Exact pairs solved between two cancellation checks (LPs of ~150 x 150 points: ~0.1 s).
EXACT_CHUNK = 64
# Threads solving the exact pairs' LPs by default, at most (fewer when the process may use
# fewer CPUs): a fixed cap, so that a memory bound counting this many LP working sets
# (:func:`exact_route_bytes`) holds on any machine; more cores serve more worker processes.
EXACT_THREADS = 2
# Bytes per entry of one exact pair's LP (:func:`_support_lp`): its squared costs (8), their
# finite copy (8, pairs across components), the plan (8) and the network simplex's own
# per-arc arrays (~24, measured: peak RSS of ``emd_c`` on 1000^2 and 2000^2 entries is
# 32 bytes an entry above its input), and an allowance of 10 numbers per point of its
# supports (masses, potentials, the simplex's node arrays).
LP_ENTRY_BYTES = 48
LP_POINT_BYTES = 80


def exact_threads(threads: int | None = None) -> int:
    """Threads of the exact method: ``threads`` checked, or by default the CPUs this process
    may use, at most :data:`EXACT_THREADS`."""
    return thread_count(threads) if threads is not None else min(thread_count(),
                                                                 EXACT_THREADS)


def exact_route_bytes(row_supports, col_supports, width: int, pairs: int,
                      threads: int = EXACT_THREADS) -> int:
    """Bytes of the exact method's row cost blocks and LPs at most, beside its ground distances
    (:func:`_exact_pairs`): ``row_supports``, ``col_supports``: the support sizes of the
    exact pairs' rows and columns; ``width``: columns of the ground distances (the columns'
    support points, or every point where the domain's stored all-pairs ones serve); ``pairs``:
    the exact pairs.

    :class:`_RowBlocks` keeps blocks (``support x width`` entries each) within
    :data:`ROW_BLOCK_ENTRIES` or one block, adds the next before trimming, and each thread
    may hold one more (being built, or just trimmed while its pair is cut from it); each of
    ``min(threads, pairs)`` threads holds one LP (:data:`LP_ENTRY_BYTES` an entry), counted
    at the largest pair's size."""
    largest = max(row_supports, default=0)
    block = largest * int(width)
    kept = min(max(ROW_BLOCK_ENTRIES, block), int(sum(row_supports)) * int(width))
    running = min(int(threads), int(pairs))
    biggest = max(col_supports, default=0)
    lp = (LP_ENTRY_BYTES * min(largest * biggest, MAX_SUPPORT_PRODUCT)
          + LP_POINT_BYTES * (largest + biggest))
    return 8 * (kept + running * block) + running * lp


def prefers_stored_distances(n: int, covered_rows: int, covered_cols: int) -> bool:
    """Whether the exact method's ground distances are the domain's stored all-pairs ones
    (where it keeps them: ``Domain.stored_ground_distances``; ``n`` columns wide) rather
    than those between the supports (as wide as the columns' support): when the supports
    of its rows and those of its columns each cover at least half of the ``n`` points."""
    return 2 * min(int(covered_rows), int(covered_cols)) >= int(n)


def pair_state_bytes(n: int) -> int:
    """Bytes of one active convolutional pair's state on an ``n``-vertex domain."""
    return 8 * int(n) * _PAIR_VECTORS


def block_pairs(n: int) -> int:
    """Pairs advanced as one block on an ``n``-vertex domain (a function of ``n`` only)."""
    return int(max(1, min(MAX_BLOCK_PAIRS, BLOCK_WORK_BYTES // pair_state_bytes(n))))


@dataclass(kw_only=True)
class DistanceMatrixResult(SolverResult):
    r"""Result of :func:`distance_matrix`.

    Attributes
    ----------
    values : (n, m) array
        Distances (:math:`W_2^2` / Sinkhorn divergence in squared distance units, or
        :math:`W_1`), ``nan`` where not computed (cancelled).
    pair_iterations, pair_residuals, pair_converged : (n, m) array
        Per pair: each solver's iterations, measured stopping quantity and convergence.
    methods : (n, m) array of str
        ``"exact"``, ``"convolutional"``, ``"w1"``, ``"spectral"`` or ``"identical"`` (the
        diagonal of a symmetric matrix), ``""`` when not computed.
    computed : (n, m) bool array
        The pairs computed.
    metric : {"w2", "w1"}
        The metric.
    symmetric : bool
        One collection against itself.
    kernels : list of tuple
        The ``(gamma, t, substeps, debiased)`` groups solved as blocks.
    lower : (n, m) array or None
        ``metric="w1"``: the certified lower bound of every entry (interior point: of W1;
        spectral: of d_W^k, whose value is an upper bound of W1).
    w1_matrix_method : {"interior_point", "spectral"} or None
        ``metric="w1"``: the decided matrix method.
    k : int or None
        Eigenfunctions of the spectral method.
    reason : str
        The decision (:func:`solvers.emd.dwk_matrix.decide_w1_method`).
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
        ``iterations`` (sum), ``residual`` (max) and ``converged`` (every pair computed and
        converged) summarize the pairs.
    """

    values: np.ndarray
    pair_iterations: np.ndarray
    pair_residuals: np.ndarray
    pair_converged: np.ndarray
    methods: np.ndarray
    computed: np.ndarray
    metric: str = "w2"
    symmetric: bool = False
    kernels: list = field(default_factory=list)
    lower: np.ndarray | None = None
    w1_matrix_method: str | None = None
    k: int | None = None
    reason: str = ""

    @property
    def finished_rows(self) -> np.ndarray:
        """Indices of the rows whose every entry is computed."""
        return np.flatnonzero(self.computed.all(axis=1))


class _Table:
    """The matrix being filled, pair by pair (mirrored when symmetric)."""

    def __init__(self, n: int, m: int, symmetric: bool, metric: str, progress, total: int):
        self.values = np.full((n, m), np.nan)
        self.iterations = np.zeros((n, m), dtype=np.int64)
        self.residuals = np.full((n, m), np.nan)
        self.converged = np.zeros((n, m), dtype=bool)
        self.methods = np.full((n, m), "", dtype=object)
        self.symmetric, self.metric = symmetric, metric
        self.progress = progress
        self.with_fraction = progress is not None and _arity(progress) >= 3
        self.total, self.done, self.worst = max(total, 1), 0, 0.0
        self.kernels: list = []
        self.lower = np.full((n, m), np.nan) if metric == "w1" else None
        self.w1_matrix_method: str | None = None
        self.k: int | None = None
        self.reason = ""

    def put(self, i: int, j: int, value, iterations, residual, converged, method) -> None:
        cells = [(i, j), (j, i)] if self.symmetric and i != j else [(i, j)]
        for r, c in cells:
            self.values[r, c] = value
            self.iterations[r, c] = iterations
            self.residuals[r, c] = residual
            self.converged[r, c] = converged
            self.methods[r, c] = method
        if self.lower is not None and method == "identical":
            self.lower[i, j] = 0.0
        if method == "identical":
            return
        self.done += 1
        if np.isfinite(residual):
            self.worst = max(self.worst, float(residual))
        if self.progress is not None:
            if self.with_fraction:
                self.progress(self.done, self.worst, self.done / self.total)
            else:
                self.progress(self.done, self.worst)

    def result(self) -> DistanceMatrixResult:
        computed = self.methods != ""
        return DistanceMatrixResult(
            values=self.values, pair_iterations=self.iterations,
            pair_residuals=self.residuals, pair_converged=self.converged, methods=self.methods,
            computed=computed, metric=self.metric, symmetric=self.symmetric,
            kernels=list(self.kernels), lower=self.lower,
            w1_matrix_method=self.w1_matrix_method, k=self.k, reason=self.reason,
            iterations=int(self.iterations.sum()),
            residual=float(np.nanmax(self.residuals)) if computed.any() else float("nan"),
            converged=bool(computed.all() and self.converged[computed].all()))


def _collection(domain, values, name: str) -> np.ndarray:
    """``(n_vertices, k)`` normalized masses from an array of columns or a list of vectors."""
    if isinstance(values, (list, tuple)):
        try:
            values = np.stack([np.asarray(v, dtype=np.float64) for v in values], axis=1)
        except ValueError as exc:
            raise InputError(f"{name} must be distributions of {domain.n} values each",
                             field=name) from exc
    m = masses_block(domain, values, name)
    if m.ndim == 1:
        m = m[:, None]
    return m


def matrix_pairs(n: int, m: int, symmetric: bool,
                 diagonal: bool = False) -> list[tuple[int, int]]:
    """The pairs :func:`distance_matrix` solves, in its order: row-major (only ``i < j`` of a
    symmetric matrix, after its diagonal ``(i, i)`` when ``diagonal``: not zero by
    definition)."""
    if not symmetric:
        return [(i, j) for i in range(n) for j in range(m)]
    return ([(i, i) for i in range(n)] if diagonal else []) + [
        (i, j) for i in range(n) for j in range(i + 1, n)]


def distance_matrix(
    domain, distributions, others=None, *, metric: str = "w2", gamma: float | str = "auto",
    t: float | None = None, substeps: int | None = None, tol: float = 1e-5,
    max_iter: int | None = None, debiased: bool | None = None, method: str = "auto",
    k: int | None = None, w1_options: dict | None = None,
    progress: Callable[..., None] | None = None,
    should_cancel: Callable[[], bool] | None = None, threads: int | None = None,
    rows=None,
) -> DistanceMatrixResult:
    r"""Pairwise distances of a collection (``n x n``) or against ``others`` (``n x m``).

    Objective, per pair: with ``metric="w2"`` the value of
    :func:`~solvers.convolutional.distance.wasserstein_distance` (thesis Alg. 1 / eq. 3.10,
    or the exact LP eq. 1.1 on sparse supports) with the same arguments, decided per pair
    exactly as the single-pair default (module docstring); with ``metric="w1"`` the
    Beckmann W1 of :func:`solvers.emd.earth_movers_distance` (eq. 2.1).

    Parameters
    ----------
    domain : any domain (``"w1"``: a triangle mesh).
    metric : {"w2", "w1"}
        Convolutional (or exact) :math:`W_2^2`, or the Beckmann :math:`W_1`.
    distributions : ``(n_vertices, n)`` masses (one distribution per column) or a list of
        ``n`` vectors; normalized here.
    others : optional second set ``(n_vertices, m)``; None: the symmetric matrix of
        ``distributions`` (pairs ``i < j`` solved and mirrored).
    gamma, t, substeps, tol, max_iter, debiased : as in ``wasserstein_distance``
        (``"w2"`` only).
    method : ``"w2"``: as in ``wasserstein_distance`` (``"auto"``, ``"convolutional"``,
        ``"exact"``); ``"w1"``: ``"interior_point"`` (one certified W1 per pair,
        :func:`~solvers.emd.earth_movers_distance` with ``w1_options``), ``"spectral"``
        (the thesis' d_W^k, eq. 2.4 with the curl part in ``k`` Laplacian eigenfunctions:
        every distribution embedded once, then batched reduced problems with certified gaps,
        :func:`~solvers.emd.dwk_matrix.dwk_matrix`; an upper bound of W1 that converges
        slowly in ``k``: bench/results/dwk_matrix.md) or ``"auto"``: the interior point
        while its estimate fits 60 s, else spectral
        (:func:`~solvers.emd.dwk_matrix.decide_w1_method`, from the sizes alone; recorded
        as ``w1_matrix_method``, ``k`` and ``reason`` of the result).
    k : ``method="spectral"``: eigenfunctions of the reduced curl basis (default: the
        largest of ``(0, 5, 10, 20, 50, 100)`` estimated within 60 s,
        :func:`~solvers.emd.dwk_matrix.default_k`); given with ``"auto"``: spectral.
    w1_options : keyword arguments of ``earth_movers_distance`` (``"w1"``, interior point),
        or ``tol``, ``max_iter``, ``harmonic`` of ``dwk_matrix`` (spectral).
    progress : ``progress(pairs_done, worst_residual[, fraction])`` after each pair.
    should_cancel : checked before every block step, LP and W1 solve; when it returns True
        :class:`~solvers.errors.CancelledError` is raised with ``partial``, the result so
        far (finished entries kept, the rest ``nan``).
    threads : threads solving the exact method's LPs (default: the CPUs this process may
        use, at most :data:`EXACT_THREADS`); the values do not depend on it.
    rows : optional ``(start, stop)``, ``metric="w2"``: solve only the pairs of rows
        ``start <= i < stop`` (a block of the matrix, e.g. of a job split over processes);
        every other entry stays ``nan`` (``computed`` false).  Each pair gets the decision
        it gets in the whole matrix, so the block's entries equal the whole call's.
        Progress and ``partial`` count the block's pairs.

    Returns
    -------
    DistanceMatrixResult
        ``values`` ``(n, m)``, ``pair_iterations``, ``pair_residuals``, ``pair_converged``,
        ``methods``, ``computed``, ``iterations``, ``residual``, ``converged``, ...
    """
    _check_metric_and_callbacks(metric, method, k, progress, should_cancel)
    A = _collection(domain, distributions, "distributions")
    symmetric = others is None
    B = A if symmetric else _collection(domain, others, "others")
    domain.require_matching_component_masses(np.hstack([A, B]), max(tol, 1e-9),
                                             "distributions" if symmetric else "others")
    exact_threads(threads)  # checked before any work
    start, end = _row_range(rows, A.shape[1], metric)

    def block(all_pairs):  # the pairs of rows start <= i < end
        return [p for p in all_pairs if start <= p[0] < end]

    pairs = block(matrix_pairs(A.shape[1], B.shape[1], symmetric))
    table = _Table(A.shape[1], B.shape[1], symmetric, metric, progress, len(pairs))
    stop = _stopper(should_cancel, table)
    if symmetric and (metric == "w1" or zero_diagonal(domain, A, gamma, debiased, method)):
        for i in range(start, end):
            table.put(i, i, 0.0, 0, 0.0, True, "identical")
    elif symmetric:
        pairs = block(matrix_pairs(A.shape[1], B.shape[1], symmetric, diagonal=True))
        table.total = len(pairs)
    if metric == "w1":
        _w1_matrix(domain, A, None if symmetric else B, pairs, table, method=method, k=k,
                   options=w1_options or {}, stop=stop)
        return table.result()
    _w2_pairs(domain, A, B, pairs, table, stop, threads, tol=tol, max_iter=max_iter,
              method=method, gamma=gamma, t=t, substeps=substeps, debiased=debiased)
    return table.result()


def _row_range(rows, n: int, metric: str) -> tuple[int, int]:
    """``(start, stop)`` of the rows to solve: all (``rows`` None) or the checked range."""
    if rows is None:
        return 0, n
    try:
        start, end = (int(r) for r in rows)
    except (TypeError, ValueError) as exc:
        raise InputError("rows must be (start, stop)", field="rows") from exc
    if metric != "w2":
        raise InputError("rows (a block of the matrix) applies to metric 'w2'", field="rows")
    if not 0 <= start < end <= n:
        raise InputError(f"rows must satisfy 0 <= start < stop <= {n}, got {rows!r}",
                         field="rows")
    return start, end


def _stopper(should_cancel, table):
    """``stop(where)``: raises :class:`CancelledError` carrying the result so far
    (``partial``) when ``should_cancel`` says so."""
    def stop(where: str) -> None:
        if should_cancel is not None and should_cancel():
            error = CancelledError(f"cancelled {where}")
            error.partial = table.result()
            raise error

    return stop


def _w2_pairs(domain, A, B, pairs, table, stop, threads, *, tol, max_iter, **decision) -> None:
    """Solve the W2 ``pairs`` into ``table``, each by its own decision
    (:func:`decide_method` with the ``decision`` arguments): the exact LPs in threads, the
    convolutional ones grouped by kernel, one block per group."""
    sketch = sketch_of(domain).remembering_paths()
    decisions = [decide_method(sketch, A[:, i], B[:, j], **decision) for i, j in pairs]
    exact = [p for p, d in zip(pairs, decisions, strict=True) if d.method == "exact"]
    if exact:
        _exact_pairs(domain, A, B, exact, table, stop, threads)
    groups: dict[tuple, list] = {}
    for p, d in zip(pairs, decisions, strict=True):
        if d.method != "exact":
            groups.setdefault(kernel_key(d), []).append((p, d))
    for members in groups.values():
        _convolutional_pairs(domain, A, B, members, table, tol=tol, max_iter=max_iter,
                             stop=stop)


def _check_metric_and_callbacks(metric, method, k, progress, should_cancel) -> None:
    """Raise unless ``metric`` is one of :data:`METRICS`, ``method`` and ``k`` fit it, and
    the callbacks are callable (or ``None``)."""
    check_choice(metric, METRICS, "metric")
    if metric == "w2" and (method in W1_ONLY or k is not None):
        raise InputError(f"method {method!r} and k choose the W1 algorithm (metric 'w1')",
                         field="k" if k is not None else "method")
    if should_cancel is not None and not callable(should_cancel):
        raise InputError("should_cancel must be callable", field="should_cancel")
    if progress is not None and not callable(progress):
        raise InputError("progress must be callable", field="progress")


def zero_diagonal(domain, A, gamma, debiased, method) -> bool:
    """Whether ``D(mu_i, mu_i) = 0`` by definition: the pair's own decision is the exact
    method or a debiased divergence (decided on the first distribution; a numeric ``gamma``
    decides the same for every pair)."""
    d = decide_distance(domain, A[:, 0], A[:, 0], method=method, gamma=gamma,
                        debiased=debiased)
    return d.method == "exact" or bool(d.debiased)


def kernel_key(d: DistanceDecision) -> tuple:
    """``(t, substeps)``: the heat kernel a convolutional pair runs with (pairs sharing it
    run as one block)."""
    return (d.t if d.t is not None else d.gamma / 4.0, int(d.substeps))


def _exact_pairs(domain, A, B, pairs, table: _Table, stop, threads: int | None = None) -> None:
    """The exact method: the ground distances between the supports of the exact pairs' rows
    and those of their columns, computed once, then one transport LP per pair on its squared
    sub-matrix, cut from its row's block (:class:`_RowBlocks`).  The LPs run in ``threads``
    threads (POT's network simplex releases the GIL; each pair's LP is the same whichever
    thread solves it) and enter the table in row order (:func:`_in_order`), so cancellation,
    checked every :data:`EXACT_CHUNK` pairs, keeps the finished rows."""
    rows = np.flatnonzero((A[:, sorted({i for i, _ in pairs})] > 0).any(axis=1))
    cols = np.flatnonzero((B[:, sorted({j for _, j in pairs})] > 0).any(axis=1))
    if len(rows) * len(cols) > SHARED_COST_ENTRIES:
        _exact_single_pairs(domain, A, B, pairs, table, stop)
        return
    row_support = {i: np.flatnonzero(A[:, i] > 0) for i in {i for i, _ in pairs}}
    col_support = {j: np.flatnonzero(B[:, j] > 0) for j in {j for _, j in pairs}}
    for i, j in pairs:
        src, dst = row_support[i], col_support[j]
        if len(src) * len(dst) > MAX_SUPPORT_PRODUCT:
            raise InputError(f"the exact method's LP of pair ({i}, {j}) has {len(src)} x "
                             f"{len(dst)} entries, above its limit of {MAX_SUPPORT_PRODUCT}",
                             field="method")
    stop("before the cost matrix")
    blocks = _RowBlocks(*_support_distances(domain, rows, cols, stop))

    def solve(pair: tuple[int, int]) -> tuple:
        i, j = pair
        src, dst = row_support[i], col_support[j]
        return _support_lp(A[src, i], B[dst, j], blocks.costs(i, src, dst))

    for (i, j), solved in _in_order(solve, pairs, exact_threads(threads), stop):
        table.put(i, j, *solved, "exact")


class _RowBlocks:
    """Squared costs of the exact pairs, cut row by row.

    ``distances[at_row[v], at_col[w]]`` is the ground distance (or, ``squared``, its square)
    between vertices ``v`` and ``w``.  A pair's costs are gathered from its row's block (the
    squared costs from the row's support to every column point, contiguous) rather than
    from the whole matrix: pairs run row by row, so a block serves a row's pairs from cache,
    where gathering each pair from the whole matrix misses it.  The last blocks are kept
    within :data:`ROW_BLOCK_ENTRIES` entries (at least one); the values do not depend on it.
    """

    def __init__(self, distances, at_row, at_col, squared: bool):
        self.distances, self.at_row, self.at_col = distances, at_row, at_col
        self.squared = squared
        self.kept: OrderedDict = OrderedDict()
        self.lock = threading.Lock()

    def block(self, i: int, src: np.ndarray) -> np.ndarray:
        with self.lock:
            block = self.kept.get(i)
        if block is None:
            block = np.take(self.distances, self.at_row[src], axis=0)
            if block.dtype != np.float64:  # stored (float32) geodesics: squared in float64
                block = block.astype(np.float64)
            if not self.squared:
                np.square(block, out=block)
            with self.lock:
                self.kept[i] = block
                while (len(self.kept) > 1
                       and sum(b.size for b in self.kept.values()) > ROW_BLOCK_ENTRIES):
                    self.kept.popitem(last=False)
        return block

    def costs(self, i: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
        """``(len(src), len(dst))`` squared costs of row ``i``'s pair with support ``dst``."""
        return np.take(self.block(i, src), self.at_col[dst], axis=1)


def _in_order(solve, pairs: list, count: int, stop) -> Iterator[tuple]:
    """``(pair, solve(pair))`` in the order of ``pairs``, solved by ``count`` threads.

    ``stop`` runs before each run of :data:`EXACT_CHUNK` pairs is collected.  Up to one
    chunk is submitted ahead of the pair being collected, so threads never idle at a chunk
    boundary (the slowest LP of a chunk does not hold the next chunk back)."""
    if count == 1:
        for k, pair in enumerate(pairs):
            if k % EXACT_CHUNK == 0:
                stop(f"before pair {pair}")
            yield pair, solve(pair)
        return
    pool = ThreadPoolExecutor(count)
    try:
        pending = deque((pair, pool.submit(solve, pair)) for pair in pairs[:EXACT_CHUNK])
        for k in range(len(pairs)):
            if k + EXACT_CHUNK < len(pairs):
                later = pairs[k + EXACT_CHUNK]
                pending.append((later, pool.submit(solve, later)))
            pair, future = pending.popleft()
            if k % EXACT_CHUNK == 0:
                stop(f"before pair {pair}")
            yield pair, future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _support_lp(a: np.ndarray, b: np.ndarray, sub: np.ndarray) -> tuple:
    """``(value, 1, residual, converged)`` of the transport LP (eq. 1.1) between the
    support masses ``a``, ``b`` on the squared costs ``sub``.

    The very solve of ``ot.emd(a, b, sub)`` (POT's network simplex, ``b`` rescaled to the
    mass of ``a`` as ``ot.emd`` does), called through its compiled core: the wrapper's
    backend and marginal checks, dual centering and result conversions are per-pair Python
    work held under the GIL while the other thread's LP waits for it.
    """
    from ot.lp.emd_wrap import emd_c

    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    finite = _finite_cost(sub)
    plan, value, _, _, code = emd_c(a, b * (a.sum() / b.sum()),
                                    np.ascontiguousarray(finite, dtype=np.float64),
                                    10_000_000, 1, None, None)
    if finite is not sub:  # priced-above arcs carry no flow; a plan using one costs inf
        used = plan > 0
        value = np.sum(plan[used] * sub[used])
    residual = float(np.abs(plan.sum(axis=1) - a).sum() + np.abs(plan.sum(axis=0) - b).sum())
    return float(value), 1, residual, int(code) == 1


def _should_cancel(stop, where: str) -> Callable[[], bool]:
    """A solver's ``should_cancel()`` from ``stop(where)``: True where ``stop`` raises."""

    def cancelled() -> bool:
        try:
            stop(where)
        except CancelledError:
            return True
        return False

    return cancelled


def _exact_single_pairs(domain, A, B, pairs, table: _Table, stop) -> None:
    """Exact pairs one at a time (:func:`~solvers.transport.exact.
    exact_wasserstein_distance`): when the shared cost matrix would be too large."""
    from solvers.transport.exact import exact_wasserstein_distance

    cancelled = _should_cancel(stop, "between geodesic solves")
    for i, j in pairs:
        stop(f"before pair ({i}, {j})")
        try:
            res = exact_wasserstein_distance(domain, A[:, i], B[:, j], should_cancel=cancelled)
        except CancelledError:
            stop(f"in pair ({i}, {j})")
            raise
        table.put(i, j, res.value, res.iterations, res.residual, res.converged, "exact")


def _support_distances(domain, rows: np.ndarray, cols: np.ndarray, stop) -> tuple:
    """``(distances, at_row, at_col, squared)`` between the vertices ``rows`` and ``cols``
    (:class:`_RowBlocks`): the domain's ground distances between them (squared straight or
    periodic distances on grids and point clouds, exact geodesics on meshes: one MMP solve
    per point of the smaller side), or its stored all-pairs ones where it keeps them
    (small meshes) and :func:`prefers_stored_distances`, indexed by vertex."""
    cancelled = _should_cancel(stop, "between geodesic solves")
    try:
        every = (domain.stored_ground_distances(should_cancel=cancelled)
                 if prefers_stored_distances(domain.n, len(rows), len(cols)) else None)
        if every is not None:
            return every[0], np.arange(domain.n), np.arange(domain.n), every[1]
        d, squared = domain.ground_distances(rows, cols, should_cancel=cancelled)
    except CancelledError:
        stop("between geodesic solves")  # re-raise with the partial result
        raise
    at_row, at_col = np.full(domain.n, -1), np.full(domain.n, -1)
    at_row[rows], at_col[cols] = np.arange(len(rows)), np.arange(len(cols))
    return d, at_row, at_col, squared


def _convolutional_pairs(domain, A, B, members, table: _Table, *, tol, max_iter, stop) -> None:
    """Pairs sharing one heat kernel, advanced as blocks (module docstring)."""
    first = members[0][1]
    setups = {}

    def setup_of(d: DistanceDecision):
        key = (d.gamma, d.t, d.substeps)
        if key not in setups:
            setups[key] = prepare(domain, gamma=d.gamma, t=d.t, substeps=d.substeps, tol=tol,
                                  max_iter=max_iter, progress=None, should_cancel=None)
        return setups[key]

    base = setup_of(first)
    table.kernels.append((first.gamma, base.t, base.substeps, bool(first.debiased)))

    def jobs() -> Iterator:
        for (i, j), d in members:
            setup = setup_of(d)
            monitor = watch_stagnation(setup, project=max_iter is None)
            yield (i, j), pair_steps(setup.areas, np.ascontiguousarray(A[:, i]),
                                     np.ascontiguousarray(B[:, j]), gamma=setup.gamma,
                                     debiased=bool(d.debiased), tol=setup.tol,
                                     max_iter=setup.max_iter, monitor=monitor)

    def done(key, solve: PairSolve) -> None:
        table.put(key[0], key[1], solve.value, solve.iterations, solve.residual,
                  solve.converged, "convolutional")

    run_block(base.logk, jobs(), block_pairs(domain.n), done, stop)


def run_block(logk, jobs: Iterator, capacity: int, done, stop) -> None:
    """Advance step generators (``yield`` a log-input, receive ``logk`` of it) as blocks.

    At most ``capacity`` generators are active; every step stacks their pending inputs
    (a vector or an ``(n, c)`` block each) into one Fortran-ordered block, applies ``logk``
    once and sends each its columns.  A finished generator's return value goes to
    ``done(key, value)`` and the next job enters.  ``stop(where)`` runs before each step.
    """
    active: list[list] = []

    def admit() -> None:
        while len(active) < capacity:
            job = next(jobs, None)
            if job is None:
                return
            key, steps = job
            active.append([key, steps, next(steps)])

    with np.errstate(over="ignore", under="ignore"):
        admit()
        while active:
            stop("between block steps")
            widths = [1 if x.ndim == 1 else x.shape[1] for _, _, x in active]
            block = np.empty((active[0][2].shape[0], sum(widths)), order="F")
            start = 0
            for (_, _, x), w in zip(active, widths, strict=True):
                block[:, start:start + w] = x[:, None] if x.ndim == 1 else x
                start += w
            out = logk(block)
            still = []
            start = 0
            for (key, steps, x), w in zip(active, widths, strict=True):
                answer = out[:, start] if x.ndim == 1 else out[:, start:start + w]
                start += w
                try:
                    still.append([key, steps, steps.send(np.array(answer))])
                except StopIteration as finished:
                    done(key, finished.value)
            active[:] = still
            admit()


def _w1_pairs(domain, A, B, pairs, table: _Table, options: dict, stop) -> None:
    from solvers.emd import earth_movers_distance

    cancelled = _should_cancel(stop, "in a W1 solve")
    for i, j in pairs:
        stop(f"before pair ({i}, {j})")
        try:
            res = earth_movers_distance(domain, A[:, i], B[:, j], should_cancel=cancelled,
                                        **options)
        except CancelledError:
            stop(f"in pair ({i}, {j})")
            raise
        table.put(i, j, res.value, res.iterations, res.residual, res.converged, "w1")
        table.lower[i, j] = res.lower_bound
        if table.symmetric:
            table.lower[j, i] = res.lower_bound


SPECTRAL_OPTIONS = ("tol", "max_iter", "harmonic")
#: Values of ``method`` that apply to ``metric="w1"`` only.
W1_ONLY = ("interior_point", "spectral")


def _w1_matrix(domain, A, B, pairs, table: _Table, *, method: str, k, options: dict,
               stop) -> None:
    """``metric="w1"``: decide (:func:`solvers.emd.dwk_matrix.decide_w1_method`, from the
    sizes alone; recorded on the result), then one certified interior-point W1 per pair, or
    d_W^k for all pairs (:func:`solvers.emd.dwk_matrix.dwk_matrix`; ``B`` None: symmetric).
    """
    from solvers.emd.dwk_matrix import decide_w1_method

    n_faces = int(getattr(domain, "n_faces", 2 * domain.n))
    count = A.shape[1] + (0 if B is None else B.shape[1])
    decision = decide_w1_method(domain.n, n_faces, count, len(pairs), method, k)
    table.w1_matrix_method, table.k = decision.method, decision.k
    table.reason = decision.reason
    if decision.method == "interior_point":
        _w1_pairs(domain, A, A if B is None else B, pairs, table, options, stop)
        return
    unknown = sorted(set(options) - set(SPECTRAL_OPTIONS))
    if unknown:
        raise InputError(f"w1_options {unknown} do not apply to method 'spectral' (it takes "
                         f"{', '.join(SPECTRAL_OPTIONS)})", field="w1_options")
    _spectral_pairs(domain, A, B, table, decision.k, options, stop)


def _spectral_pairs(domain, A, B, table: _Table, k: int, options: dict, stop) -> None:
    """d_W^k of every pair into ``table`` (method ``"spectral"``, residual = the certified
    gap), progress passed through, cancellation with the finished row blocks."""
    from solvers.emd.dwk_matrix import dwk_matrix

    def report(done: int, worst: float) -> None:
        table.done, table.worst = done, max(table.worst, worst)
        if table.progress is not None:
            if table.with_fraction:
                table.progress(done, table.worst, done / table.total)
            else:
                table.progress(done, table.worst)

    try:
        res = dwk_matrix(domain, A, B, k=k, progress=report,
                         should_cancel=_should_cancel(stop, "between blocks of pairs"),
                         **options)
    except CancelledError as exc:
        _fill_spectral(table, exc.partial)
        error = CancelledError(str(exc))
        error.partial = table.result()
        raise error from exc
    _fill_spectral(table, res)


def _fill_spectral(table: _Table, res) -> None:
    done = res.computed.copy()
    if table.symmetric:
        np.fill_diagonal(done, False)  # the table's "identical" entries
    table.values[done], table.lower[done] = res.values[done], res.lower[done]
    table.iterations[done] = res.pair_iterations[done]
    table.residuals[done] = res.gaps[done]
    table.converged[done] = res.gaps[done] <= res.tol
    table.methods[done] = "spectral"
