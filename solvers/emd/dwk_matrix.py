r"""W1 matrices of a collection by the thesis' ``d_W^k`` (§2.5, eq. 2.4), embedded once.

Every distribution ``ρ_i`` (vertex masses ``m_i``) is embedded **once** as its gradient
field ``g_i = ∇Δ⁻¹ρ_i``: one multi-column Poisson solve with the prefactored Laplacian,
``L f_i = m_i - r_i`` (``r_i`` the uniform area density with ``m_i``'s mass on each
component; equal for every member, so it cancels in differences), then ``g_i = G f_i``
written in the per-face tangent frame and scaled by ``sqrt(a_f)``
(:func:`solvers.emd.dwk.frame_gradient`; float32, ``(n, 2F)``).  For a pair, ``g_i - g_j``
is the particular flow of eq. 2.4 (``L (f_i - f_j) = m_i - m_j``), so

.. math::

    d_W^k(\rho_i, \rho_j) = \min_{c \in \mathbb{R}^m}
        \sum_f \sqrt{a_f}\,\Big| (g_i - g_j)_f + (Q c)_f \Big| ,

``Q`` ``(2F, m)`` the orthonormalized reduced curl basis of the first ``k`` Laplacian
eigenfunctions plus the ``2·genus`` harmonic fields (:func:`solvers.emd.dwk.
reduced_spectral_problem`, once per mesh and ``k``).  The pairs' problems are solved in
blocks by the batched ADMM of :mod:`solvers.emd.dwk` (thesis Fig. 2.5), each pair stopping
at a certified relative duality gap ``tol``: its value is an upper bound of ``d_W^k`` and
``lower`` a certified lower bound.

``k = 0`` is the fastest member: no optimization, ``d_W^0 = Σ_f sqrt(a_f) |g_i - g_j|_f``,
a weighted L¹ norm of the difference of two embedded fields, evaluated for all pairs by a
compiled dense pass (:func:`solvers.emd._dwk_kernels.pair_l1`); exact up to float32
rounding (gap 0).

Properties (thesis §2.5): ``d_W^k`` is a metric for every ``k``; minimizing over nested
subspaces gives ``d_W^0 ≥ d_W^k ≥ d_W^{k'} ≥ W1`` (``k < k'``; ``W1`` over all flows, the
certified interior point of :func:`solvers.emd.earth_movers_distance`).

**Accuracy against W1 converges slowly in k** for spread distributions (measured, bumps of
radius 0.05–0.2 at random centres, 20 pairs on spot against the interior-point W1; median /
worst relative excess): ``k = 0``: 46 % / 101 %; 5: 39 % / 78 %; 20: 23 % / 55 %; 50: 14 % /
30 %; 100: 11 % / 23 %; 200: 9 % / 17 % (the curl basis' own limit is ~3 % above W1 on
spot).  On nefertiti (6 pairs; the curl basis is ~1 % above W1 there): 0: 38 %; 5: 29 %;
20: 15 %; 50: 7.1 %; 100: 4.4 % (worst 12 %); ``bench/results/dwk_matrix.md``.  The default ``k``
(:func:`default_k`) is therefore a time budget, not an accuracy promise: the largest ``k``
of :data:`K_LADDER` whose estimated time fits :data:`DEFAULT_SECONDS`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.emd.dwk import frame_gradient, gaps, reduced_spectral_problem, solve_block
from solvers.errors import CancelledError, InputError
from solvers.monitor import SolverResult

#: Default certified relative duality gap per pair (k > 0).
DWK_MATRIX_TOL = 1e-3
#: Candidate ``k`` of the default policy, smallest first.
K_LADDER = (0, 5, 10, 20, 50, 100)
#: Time budget (estimated seconds, this machine) of the default ``k``.
DEFAULT_SECONDS = 60.0
#: Distributions embedded per multi-column Poisson solve.
EMBED_BLOCK = 64
#: Rows embedded and solved together (rows x columns: the columns are embedded once, the
#: rows block by block, so memory is ``(columns + ROW_BLOCK) x 8F`` bytes of fields).
ROW_BLOCK = 64
#: Working memory of one ADMM block of pairs (about six ``(2F, B)`` float32 arrays).
ADMM_WORK_BYTES = 128 * 2**20
# Cost model (seconds on this machine's 2 cores, fit to bench/results/dwk_matrix.md,
# nefertiti): a Poisson solve per distribution and vertex (blocked multi-column solves);
# the k = 0 pass per pair and face; per ADMM iteration, pair and frame component a fused
# pass plus two products with the (2F, m) basis (read once per block of pairs).
_SOLVE_SECONDS = 1.5e-7
_PASS_SECONDS = 2e-10
_ADMM_FACE_SECONDS = 2e-9
_ADMM_BASIS_SECONDS = 1e-10
_ADMM_ITERATIONS = 40  # mean iterations per pair: 40 + 0.4 k (measured 44, 44, 59, 80 at
_ADMM_ITERATIONS_PER_K = 0.4  # k = 5, 20, 50, 100 to the default gap)
_TILE = 1024  # faces per tile of the k = 0 pass


#: Algorithms of a W1 matrix (:func:`decide_w1_method`).
W1_METHODS = ("auto", "interior_point", "spectral")
#: Seconds of one certified interior-point W1 per vertex (bench/results/w1_accuracy.md and
#: emd.md: 0.2-0.4 s at 3k vertices, 0.5-1.2 s at 10k, 7 s at 50k).
IPM_SECONDS_PER_VERTEX = 1.5e-4
#: ``method="auto"`` keeps the interior point (one certified W1 per pair) while its
#: estimate fits this many seconds, and takes ``"spectral"`` (d_W^k) above it.
IPM_MATRIX_SECONDS = 60.0


@dataclass
class W1MatrixDecision:
    """How a W1 matrix is computed: ``method`` (``"interior_point"``: one certified W1 per
    pair; ``"spectral"``: :func:`dwk_matrix`), ``k`` (spectral), the estimated seconds of
    the interior point and ``reason``; a function of the sizes and the request only."""

    method: str
    k: int | None
    ipm_seconds: float
    reason: str


def decide_w1_method(n_vertices: int, n_faces: int, n_distributions: int, n_pairs: int,
                     method: str = "auto", k: int | None = None) -> W1MatrixDecision:
    """The W1 matrix decision from the sizes alone (:class:`W1MatrixDecision`).

    ``"auto"``: ``"interior_point"`` when ``n_pairs x IPM_SECONDS_PER_VERTEX x n_vertices``
    is at most :data:`IPM_MATRIX_SECONDS` and no ``k`` is given, else ``"spectral"`` with
    ``k`` or :func:`default_k`.  ``k`` with ``"interior_point"`` is refused (field ``k``).
    """
    if method not in W1_METHODS:
        raise InputError(f"method must be one of {W1_METHODS} for metric 'w1', got "
                         f"{method!r}", field="method")
    if k is not None and not (isinstance(k, (int, np.integer)) and not isinstance(k, bool)
                              and k >= 0):
        raise InputError(f"k must be a non-negative integer, got {k!r}", field="k")
    if k is not None and method == "interior_point":
        raise InputError("k selects the spectral d_W^k; the interior point takes none",
                         field="k")
    ipm = n_pairs * IPM_SECONDS_PER_VERTEX * n_vertices
    if method == "interior_point" or (method == "auto" and k is None
                                      and ipm <= IPM_MATRIX_SECONDS):
        why = "requested" if method == "interior_point" else (
            f"{n_pairs} certified interior-point W1 estimated at {ipm:.0f} s <= "
            f"{IPM_MATRIX_SECONDS:.0f} s")
        return W1MatrixDecision("interior_point", None, ipm, why)
    chosen = default_k(n_vertices, n_faces, n_distributions, n_pairs) if k is None else k
    why = "requested" if method == "spectral" else (
        "k given" if k is not None else f"{n_pairs} interior-point W1 estimated at "
        f"{ipm:.0f} s > {IPM_MATRIX_SECONDS:.0f} s")
    return W1MatrixDecision("spectral", int(chosen), ipm,
                            f"{why}; k = {chosen}" + (" (default_k)" if k is None else ""))


@dataclass(kw_only=True)
class DwkMatrixResult(SolverResult):
    """``d_W^k`` between pairs of distributions, with certified bounds.

    ``values``: ``(n, m)`` upper bounds of ``d_W^k`` (the objective at the coefficients
    found; ``nan`` where not computed), ``lower``: certified lower bounds, ``gaps``:
    ``(values - lower) / values`` (0 for ``k = 0``, a direct evaluation), ``pair_iterations``
    ADMM iterations per pair, ``computed`` the entries solved; ``k``, ``method``
    (``"spectral"``), ``tol``.  ``iterations`` (max), ``residual`` (worst gap) and
    ``converged`` (every computed gap ≤ ``tol``) summarize them.

    Attributes
    ----------
    values : (n, m) array
        Upper bounds of :math:`d_W^k` (``nan`` where not computed).
    lower : (n, m) array
        Certified lower bounds.
    gaps : (n, m) array
        ``(values - lower) / values``.
    pair_iterations : (n, m) array
        ADMM iterations per pair.
    computed : (n, m) bool array
        The entries solved.
    k : int
        Eigenfunctions of the curl basis.
    method : str
        ``"spectral"``.
    tol : float
        The certified relative gap aimed at.
    iterations, residual, converged : int, float, bool
        Summaries: max iterations, worst gap, every computed gap within ``tol``.
    """

    values: np.ndarray
    lower: np.ndarray
    gaps: np.ndarray
    pair_iterations: np.ndarray
    computed: np.ndarray
    k: int
    method: str = "spectral"
    tol: float = DWK_MATRIX_TOL


def estimate_seconds(n_vertices: int, n_faces: int, k: int, n_distributions: int,
                     n_pairs: int) -> float:
    """Estimated seconds of :func:`dwk_matrix` (embedding plus pairs; the spectral
    reduction, once per mesh and ``k``, is not counted)."""
    embed = n_distributions * _SOLVE_SECONDS * n_vertices
    if k == 0:
        return embed + n_pairs * n_faces * _PASS_SECONDS
    m = k + 4
    per_iteration = 2 * n_faces * (_ADMM_FACE_SECONDS + _ADMM_BASIS_SECONDS * m)
    iterations = _ADMM_ITERATIONS + _ADMM_ITERATIONS_PER_K * k
    return embed + n_pairs * iterations * per_iteration


def working_bytes(n_vertices: int, n_faces: int, k: int, n_rows: int, n_columns: int,
                  symmetric: bool) -> int:
    """Bytes :func:`dwk_matrix` holds at most beside the mesh's operators: the embedded
    fields (float32, ``2F`` each: every distribution when ``symmetric``, else the columns
    and one :data:`ROW_BLOCK` of rows), one embedding block's Poisson solve (float64), the
    reduced basis and its transpose (float32, ``2F x (k + 4)``), the eigenvectors (float64,
    ``V x k``, twice while built) and the ADMM blocks (:data:`ADMM_WORK_BYTES`)."""
    field = 4 * 2 * int(n_faces)
    fields = field * (n_rows if symmetric else n_columns + min(n_rows, ROW_BLOCK))
    embed_block = 8 * int(n_vertices) * EMBED_BLOCK * 3 + field * EMBED_BLOCK
    if k == 0:
        return fields + embed_block
    basis = 2 * field * (k + 4) + 2 * 8 * int(n_vertices) * k
    return fields + embed_block + basis + ADMM_WORK_BYTES


def default_k(n_vertices: int, n_faces: int, n_distributions: int, n_pairs: int,
              seconds: float = DEFAULT_SECONDS) -> int:
    """The default ``k``: the largest of :data:`K_LADDER` whose :func:`estimate_seconds`
    is at most ``seconds`` (``0`` when none is); a function of the sizes only."""
    fits = [k for k in K_LADDER
            if estimate_seconds(n_vertices, n_faces, k, n_distributions, n_pairs) <= seconds]
    return max(fits, default=0)


def embed(ops, masses: np.ndarray, check=None) -> np.ndarray:
    """``(n, 2F)`` float32: row ``i`` the frame field ``sqrt(a_f) ∇Δ⁻¹ρ_i`` of column ``i``
    of ``masses`` ``(V, n)`` (module docstring), :data:`EMBED_BLOCK` columns per solve;
    ``check()`` runs between solves (cancellation)."""
    gradient = frame_gradient(ops)
    labels = ops.labels
    vertex_areas = np.asarray(ops.mesh.areas, dtype=np.float64)
    comp_area = np.bincount(labels, weights=vertex_areas, minlength=ops.n_components)
    out = np.empty((masses.shape[1], gradient.shape[0]), dtype=np.float32)
    for lo in range(0, masses.shape[1], EMBED_BLOCK):
        if check is not None:
            check()
        block = masses[:, lo:lo + EMBED_BLOCK]
        comp_mass = np.stack([np.bincount(labels, weights=c, minlength=ops.n_components)
                              for c in block.T], axis=1)
        rhs = block - vertex_areas[:, None] * (comp_mass / comp_area[:, None])[labels]
        out[lo:lo + block.shape[1]] = (gradient @ ops.solve_poisson(rhs)).T
    return out


def _pairs(problem, weights, left, right, rows, cols, tol, max_iter, stop):
    """``(upper, lower, iterations)`` of the pairs ``(left[rows[p]], right[cols[p]])``:
    the compiled d_W^0 pass (``problem`` None), or the batched ADMM over blocks of pairs
    within :data:`ADMM_WORK_BYTES`, ``stop()`` between blocks."""
    n = len(rows)
    if problem is None:
        from solvers.emd._dwk_kernels import pair_l1

        out = np.zeros(n)
        pair_l1(left, right, weights, rows.astype(np.int64), cols.astype(np.int64), _TILE,
                out)
        return out, out.copy(), np.zeros(n, dtype=np.int64)
    block = max(16, ADMM_WORK_BYTES // (24 * problem.basis.shape[0]))
    upper, lower = np.empty(n), np.empty(n)
    iterations = np.zeros(n, dtype=np.int64)
    for lo in range(0, n, block):
        stop()
        sl = slice(lo, min(n, lo + block))
        data = np.ascontiguousarray((left[rows[sl]] - right[cols[sl]]).T)
        upper[sl], lower[sl], iterations[sl] = solve_block(problem, data, tol=tol,
                                                           max_iter=max_iter)
    return upper, lower, iterations


class _Matrix:
    """The result being filled, row block by row block (mirrored when symmetric)."""

    def __init__(self, n: int, m: int, symmetric: bool, k: int, tol: float):
        self.values, self.lower = np.full((n, m), np.nan), np.full((n, m), np.nan)
        self.iterations = np.zeros((n, m), dtype=np.int64)
        self.symmetric, self.k, self.tol = symmetric, k, tol
        if symmetric:
            np.fill_diagonal(self.values, 0.0)
            np.fill_diagonal(self.lower, 0.0)

    def put(self, rows, cols, upper, lower, iterations) -> None:
        for r, c in ((rows, cols), (cols, rows)) if self.symmetric else ((rows, cols),):
            self.values[r, c], self.lower[r, c], self.iterations[r, c] = upper, lower, \
                iterations

    def result(self) -> DwkMatrixResult:
        computed = ~np.isnan(self.values)
        g = np.full(self.values.shape, np.nan)
        g[computed] = gaps(self.values[computed], self.lower[computed])
        return DwkMatrixResult(
            values=self.values, lower=self.lower, gaps=g, pair_iterations=self.iterations,
            computed=computed, k=self.k, tol=self.tol,
            iterations=int(self.iterations.max()) if self.iterations.size else 0,
            residual=float(g[computed].max()) if computed.any() else float("nan"),
            converged=bool(computed.all() and np.all(g <= self.tol)))


def _index(values, n: int, name: str) -> np.ndarray:
    if values is None:
        return np.arange(n)
    idx = np.asarray(values)
    if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer) or (
            len(idx) and (idx.min() < 0 or idx.max() >= n)):
        raise InputError(f"{name} must be indices in [0, {n - 1}]", field=name)
    return idx.astype(np.int64)


def _check_k(k, ops) -> int | None:
    if k is None:
        return None
    if not (isinstance(k, (int, np.integer)) and not isinstance(k, bool) and k >= 0):
        raise InputError(f"k must be a non-negative integer, got {k!r}", field="k")
    limit = ops.n_vertices - 3
    if k > limit:
        raise InputError(f"k must be at most {limit} on this mesh, got {k}", field="k")
    return int(k)


def dwk_matrix(mesh, distributions, others=None, *, k: int | None = None, rows=None,
               columns=None, harmonic: bool = True, tol: float = DWK_MATRIX_TOL,
               max_iter: int = 2000, progress=None, should_cancel=None) -> DwkMatrixResult:
    r"""``d_W^k`` between every pair of a collection, or rows x columns (thesis §2.5).

    Objective per pair (module docstring; eq. 2.4 with the curl part in the first ``k``
    Laplacian eigenfunctions): :math:`\min_c \sum_f \sqrt{a_f} |(g_i - g_j)_f + (Qc)_f|`
    with ``g_i = ∇Δ⁻¹ρ_i`` embedded once per distribution.

    Parameters
    ----------
    mesh : TriangleMesh.
    distributions : ``(V, n)`` masses, one distribution per column (normalized here).
    others : optional ``(V, m)``; None: pairs within ``distributions`` (symmetric; only
        ``i < j`` are solved, the diagonal is 0).
    k : eigenfunctions of the reduced curl basis; None: :func:`default_k` of the sizes.
    rows, columns : optional index lists selecting the rows (into ``distributions``) and
        columns (into ``others``, or ``distributions``) of the matrix; only the selected
        distributions are embedded.  Given with ``others=None``, every (row, column) pair is
        solved (no symmetry assumed).
    harmonic : add the ``2·genus`` harmonic fields to the basis (``k > 0``).
    tol, max_iter : ``k > 0``: each pair stops at a certified relative gap ``tol`` or after
        ``max_iter`` ADMM iterations.
    progress : ``progress(pairs_done, worst_gap)`` after each block of pairs.
    should_cancel : checked between blocks; True raises :class:`CancelledError` with
        ``partial`` (the result so far, unsolved entries ``nan``).

    Returns
    -------
    DwkMatrixResult
        ``values``, ``lower``, ``gaps`` of shape ``(len(rows), len(columns))``, and ``k``.
    """
    from solvers.emd.beckmann import check_mesh
    from solvers.validation import normalize_masses

    ops = check_mesh(mesh)
    A = np.atleast_2d(normalize_masses(distributions, mesh.n, "distributions").T).T
    B = A if others is None else np.atleast_2d(normalize_masses(others, mesh.n, "others").T).T
    symmetric = others is None and rows is None and columns is None
    r_idx = _index(rows, A.shape[1], "rows")
    c_idx = _index(columns, B.shape[1], "columns")
    mesh.require_matching_component_masses(np.hstack([A[:, r_idx], B[:, c_idx]]), 1e-9,
                                           "distributions" if others is None else "others")
    n, m = len(r_idx), len(c_idx)
    n_pairs = n * (n - 1) // 2 if symmetric else n * m
    k = _check_k(k, ops)
    if k is None:
        k = default_k(mesh.n, ops.n_faces, n + (0 if symmetric else m), n_pairs)
    return _solve(ops, A[:, r_idx], None if symmetric else B[:, c_idx], k, harmonic, tol,
                  max_iter, progress, should_cancel)


def _solve(ops, A, B, k, harmonic, tol, max_iter, progress, should_cancel):
    """Embed the columns (``B``, or ``A`` when symmetric) once, then :data:`ROW_BLOCK`
    rows at a time: embed them (``B`` given) and solve their pairs; only ``i < j`` when
    symmetric.  Cancellation keeps the finished row blocks."""
    symmetric = B is None
    n = A.shape[1]
    out = _Matrix(n, n if symmetric else B.shape[1], symmetric, k, tol)

    def stop() -> None:
        if should_cancel is not None and should_cancel():
            error = CancelledError("cancelled between blocks of pairs")
            error.partial = out.result()
            raise error

    problem = reduced_spectral_problem(ops, k, harmonic) if k else None
    weights = frame_weights(ops)
    right = embed(ops, A if symmetric else B, check=stop)
    done, worst = 0, 0.0
    for lo in range(0, n, ROW_BLOCK):
        stop()
        hi = min(n, lo + ROW_BLOCK)
        left = right[lo:hi] if symmetric else embed(ops, A[:, lo:hi], check=stop)
        if symmetric:
            rows, cols = np.triu_indices(hi - lo, 1, n - lo)
            cols = cols + lo
        else:
            rows = np.repeat(np.arange(hi - lo), right.shape[0])
            cols = np.tile(np.arange(right.shape[0]), hi - lo)
        upper, lower, its = _pairs(problem, weights, left, right, rows, cols, tol, max_iter,
                                   stop)
        out.put(rows + lo, cols, upper, lower, its)
        done += len(rows)
        if len(rows):
            worst = max(worst, float(gaps(upper, lower).max()))
        if progress is not None:
            progress(done, worst)
    return out.result()


def frame_weights(ops) -> np.ndarray:
    """``sqrt(a_f)`` (F,) float32: the weights of the frame fields' L¹ norm."""
    return np.sqrt(ops.face_areas).astype(np.float32)
