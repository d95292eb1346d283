r"""Pointwise earth mover's distances ``d_W^k`` from one source to every vertex (thesis §2.5).

For two points the Beckmann problem has the particular flow
``v_xy = ∇G_x - ∇G_y`` where ``G_p`` is the Green's function of the cotangent
Laplacian (``L G_p = e_p - a``), so

.. math::

    d_W^k(x, y) = \min_{c \in \mathbb{R}^k} \int_M
        \Big\|\nabla G_x - \nabla G_y + \sum_{i\le k} c_i\, R\nabla\phi_i\Big\|\,dA ,

with ``φ_i`` the first ``k`` Laplacian eigenfunctions (the truncated curl basis,
plus the ``2g`` harmonic fields for ``k > 0`` on surfaces with handles).

* ``k = 0`` (the Green's-function form): no optimization, one pass over the faces per
  target.  ``method="green"`` reads ``G_x - G_y`` from the dense Green's matrix ``L⁺``
  of the mesh (:mod:`solvers.emd.green`: built once per mesh with ``V`` unit Poisson
  solves, cached on the mesh operators, 4·V² bytes, float32) and runs a compiled
  parallel face pass over all targets; ``method="solve"`` does one Poisson solve per
  target (``L z = e_x - e_y``, batched) and a sparse-gradient face pass (single
  precision).  Measured against a float64 evaluation: ≤ 1e-7 relative on average
  (solves: ~1e-6), up to 5e-5 (solves: 1.3e-4) at a nearest neighbour of the source
  across a short edge.  ``d_W^0`` is the L¹ norm of a difference of gradient fields, hence
  a metric (exact triangle inequality).
* ``k > 0``: a k-dimensional convex problem per target.  The mesh's spectral basis is
  reduced once (tangent frames, orthonormalized; cached on the mesh) and the problems of
  a block of targets are solved together by one ADMM (Fig. 2.5) sharing that basis, each
  target stopping at a certified duality gap (:mod:`solvers.emd.dwk`).  Minimizing over nested
  subspaces gives ``d_W^0 ≥ d_W^k ≥ d_W^{k'} (k < k')``, decreasing towards the
  full curl-basis W1 between the two Diracs, which approaches geodesic distance.

Solves are batched: targets are processed ``block`` at a time as one multi-RHS
solve with the prefactored Laplacian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.emd.beckmann import check_mesh
from solvers.emd.dwk import gaps, reduced_spectral_problem, solve_block
from solvers.emd.green import GREEN_MAX_VERTICES, dw0_from_green
from solvers.errors import InputError
from solvers.monitor import Monitor, SolverResult
from solvers.validation import check_choice

METHODS = ("auto", "green", "solve")

# Cost model of the estimate (seconds on 2 cores; fit in bench/results/dwk.md): a Poisson
# solve per target and vertex; per ADMM iteration and target a fused pass over the 2F
# frame components plus two products with the (2F x m) reduced basis.
_SOLVE_SECONDS = 5e-7
_ADMM_FACE_SECONDS = 2e-9  # per face component, target and iteration
_ADMM_BASIS_SECONDS = 2e-11  # per face component, basis field, target and iteration
_ADMM_ITERATIONS = 100  # typical iterations per target to the default gap (k = 20..100)
_EIGEN_SECONDS = 1.5e-8  # spectral reduction, per vertex and squared k (once per mesh and k)
MAX_ESTIMATED_SECONDS = 300.0
#: Working memory of the ADMM state of one block of targets (bounds the block size).
ADMM_WORK_BYTES = 128 * 2**20
#: Default certified relative duality gap per target for k > 0.
DWK_TOL = 1e-3
#: ADMM iterations without a 0.1 % decrease of a block's worst gap: stalled.
ADMM_PATIENCE = 200


@dataclass
class PointwiseDistanceResult(SolverResult):
    """``distances[y] = d_W^k(source, y)`` for every target ``y`` (unit-area lengths).

    Per target (k > 0; for k = 0 the evaluation is direct): ``residuals`` the certified
    relative gap ``(distance - lower_bound) / distance``, ``lower_bounds`` the dual bound
    (the true ``d_W^k`` lies in ``[lower_bound, distance]``), ``target_iterations`` the
    ADMM iterations and ``converged_targets`` ``residuals <= tol``.  ``residual`` and
    ``converged`` summarize them (worst gap; all converged).

    Attributes
    ----------
    distances : (len(targets),) array
        :math:`d_W^k` (source, y) per target.
    source : int
        The source vertex.
    k : int
        Eigenfunctions in the curl basis (0: Green's-function form).
    targets : array of int
        The target vertices.
    residuals, lower_bounds : (len(targets),) array or None
        Certified relative gaps and dual bounds (``k > 0``).
    target_iterations : (len(targets),) array or None
        ADMM iterations per target.
    converged_targets : (len(targets),) bool array or None
        ``residuals <= tol``.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    distances: np.ndarray
    source: int
    k: int
    targets: np.ndarray
    residuals: np.ndarray | None = None
    lower_bounds: np.ndarray | None = None
    target_iterations: np.ndarray | None = None
    converged_targets: np.ndarray | None = None

    def __post_init__(self):
        if self.residuals is None:  # k = 0: a direct evaluation, exact up to rounding
            n = len(self.distances)
            self.residuals = np.zeros(n)
            self.lower_bounds = np.asarray(self.distances, dtype=np.float64)
            self.target_iterations = np.zeros(n, dtype=np.int64)
            self.converged_targets = np.ones(n, dtype=bool)


def _pair_potentials(ops, source: int, targets: np.ndarray) -> np.ndarray:
    """``G_x - G_y`` for every target y: one multi-RHS solve of ``L Z = e_x - e_Y`` (V, B)."""
    rhs = np.zeros((ops.n_vertices, len(targets)))
    rhs[source] += 1.0
    rhs[targets, np.arange(len(targets))] -= 1.0
    return ops.solve_poisson(rhs)


def _split_gradient(ops) -> list:
    """The three (F, V) component blocks of ``G`` in float32, for the k = 0 face pass."""
    return ops.gradient_components32


def pointwise_distances(mesh, source: int, *, k: int = 0, targets=None, harmonic: bool = True,
                        tol: float = DWK_TOL, max_iter: int = 2000, block: int = 512,
                        method: str = "auto", green_max_vertices: int = GREEN_MAX_VERTICES,
                        max_seconds: float | None = MAX_ESTIMATED_SECONDS,
                        progress=None, should_cancel=None) -> PointwiseDistanceResult:
    r"""``d_W^k(source, y)`` for all vertices ``y`` (or ``targets``), thesis §2.5.

    .. math::

        d_W^k(x, y) = \min_{c \in \mathbb{R}^k} \int_M
            \Big\|\nabla G_x - \nabla G_y + \sum_{i\le k} c_i\, R\nabla\phi_i\Big\|\,dA

    with :math:`G_p` the Green's function of the cotangent Laplacian and :math:`\phi_i`
    the first ``k`` Laplacian eigenfunctions (module docstring).

    Parameters
    ----------
    mesh : TriangleMesh.
    source : source vertex index.
    k : number of Laplacian eigenfunctions in the curl basis (0: Green's-function form).
    targets : optional vertex indices (default: all vertices).
    harmonic : ``k > 0``: include the harmonic fields (genus > 0) in the flow space.
    tol, max_iter : ``k > 0``: each target stops at a certified relative duality gap
        ``tol`` (:mod:`solvers.emd.dwk`), or after ``max_iter`` ADMM iterations.
    block : targets per multi-RHS solve (``method="solve"`` and ``k > 0``).
    method : ``k = 0`` only. ``"green"``: dense Green's matrix + compiled face pass (the
        matrix, ``4 V²`` bytes, is built on first use and kept in the mesh's operator
        store; build and query times in bench/results/emd.md); ``"solve"``: blocked Poisson solves
        per call (no memory beyond a block); ``"auto"``: ``"green"`` when the matrix is
        already built, or when the mesh has at most ``green_max_vertices`` vertices and
        at least a quarter of them are targets; ``"solve"`` otherwise.
    green_max_vertices : largest mesh for the dense matrix (``method="green"`` raises
        InputError(field="method") above it); default :data:`GREEN_MAX_VERTICES` (20000,
        1.6 GB).
    max_seconds : runs estimated above this (:func:`estimate_seconds`) are refused with an
        InputError naming the limit and the faster option (None: no limit).
    progress, should_cancel : called at every gap check / solve block; the ADMM stops a
        block as stalled when its worst gap has not improved for ``ADMM_PATIENCE``
        iterations (those targets: converged False, their measured gap).

    Returns
    -------
    PointwiseDistanceResult with ``distances`` (len(targets),) — (V,) by default.
    """
    ops = check_mesh(mesh)
    source, k, targets = _check_inputs(ops, source, k, targets, method)
    monitor = Monitor(progress, should_cancel, tol=tol, patience=ADMM_PATIENCE)
    green = k == 0 and method != "solve" and (
        method == "green" or ops.has_green_matrix
        or (mesh.n <= green_max_vertices and 4 * len(targets) >= mesh.n))
    check_cost(mesh.n, ops.n_faces, k, len(targets), green, max_seconds)
    if green:
        return _dw0_green(ops, source, targets, monitor, green_max_vertices)
    if k == 0:
        return _dw0_solve(ops, source, targets, block, monitor)
    return _dwk_admm(ops, source, k, targets, harmonic, tol, max_iter, block, monitor)


def estimate_seconds(n_vertices: int, n_faces: int, k: int, n_targets: int,
                     green: bool) -> float:
    """Estimated seconds of :func:`pointwise_distances` (``green``: the dense method; its
    one-time build is ``n_vertices`` solves, then a face pass per target)."""
    solves = n_targets * _SOLVE_SECONDS * n_vertices
    if k == 0:
        return (n_vertices * _SOLVE_SECONDS * n_vertices * 0.05 + n_targets * n_faces * 2e-9
                if green else solves)
    m = k + 4  # eigenfunctions plus (up to) harmonic fields
    per_iteration = 2 * n_faces * (_ADMM_FACE_SECONDS + _ADMM_BASIS_SECONDS * m)
    reduction = _EIGEN_SECONDS * n_vertices * k * k  # counted even when already cached
    return solves + reduction + n_targets * _ADMM_ITERATIONS * per_iteration


def check_cost(n_vertices: int, n_faces: int, k: int, n_targets: int, green: bool,
               max_seconds: float | None = MAX_ESTIMATED_SECONDS) -> float:
    """Refuse (InputError naming the limit and the faster option) a run estimated above
    ``max_seconds`` (None: no limit); returns the estimate."""
    est = estimate_seconds(n_vertices, n_faces, k, n_targets, green)
    if max_seconds is not None and est > max_seconds:
        if k > 0:
            hint = (f"use a smaller k (k = 0 is the Green's-function form) or fewer targets "
                    f"(about {max(int(n_targets * max_seconds / est), 1)} fit)")
            field = "k"
        else:
            hint = (f"pass fewer targets (about {max(int(n_targets * max_seconds / est), 1)} "
                    f"fit), or allow the dense Green's method above {GREEN_MAX_VERTICES} "
                    f"vertices (green_max_vertices; {4 * n_vertices ** 2 / 1e9:.1f} GB)")
            field = "targets"
        raise InputError(f"d_W^{k} to {n_targets} targets on {n_vertices} vertices is "
                         f"estimated at {est:.0f} s, above the limit of {max_seconds:.0f} s: "
                         f"{hint}", field=field)
    return est


def _check_inputs(ops, source, k, targets, method) -> tuple[int, int, np.ndarray]:
    """Validated ``(source, k, targets)``; targets must share the source's component."""
    n = ops.n_vertices
    if not (isinstance(source, (int, np.integer)) and 0 <= int(source) < n):
        raise InputError(f"source must be a vertex index in [0, {n - 1}], got {source!r}",
                         field="source")
    source = int(source)
    if not (isinstance(k, (int, np.integer)) and k >= 0):
        raise InputError(f"k must be a non-negative integer, got {k!r}", field="k")
    if targets is None:
        targets = np.arange(n)
    else:
        targets = np.asarray(targets)
        if targets.ndim != 1 or not np.issubdtype(targets.dtype, np.integer) or (
                len(targets) and (targets.min() < 0 or targets.max() >= n)):
            raise InputError(f"targets must be vertex indices in [0, {n - 1}]", field="targets")
    check_choice(method, METHODS, "method")
    if method == "green" and k > 0:
        raise InputError("method='green' evaluates d_W^0 only (k = 0)", field="method")
    labels = ops.labels
    other = targets[labels[targets] != labels[source]]
    if len(other):
        from solvers.errors import UnsupportedDomainError

        raise UnsupportedDomainError(
            f"target {int(other[0])} lies on another connected component than the source",
            field="targets")
    return source, int(k), targets


def _dw0_green(ops, source, targets, monitor, green_max_vertices) -> PointwiseDistanceResult:
    """``d_W^0`` from the cached dense Green's matrix and the compiled face pass."""
    monitor(0, 0.0)
    green = ops.green_matrix(check=lambda: monitor(0, 0.0), max_vertices=green_max_vertices)
    n = ops.n_vertices
    full = len(targets) == n and np.array_equal(targets, np.arange(n))
    out = dw0_from_green(green, source, None if full else targets)
    return PointwiseDistanceResult(distances=out, source=source, k=0, targets=targets,
                                   iterations=0, residual=0.0, converged=True)  # direct


def _dw0_solve(ops, source, targets, block, monitor) -> PointwiseDistanceResult:
    """``d_W^0`` by blocked Poisson solves: ``∫ |∇(G_x - G_y)|`` per target, float32 faces."""
    area32 = ops.face_areas.astype(np.float32)
    out = np.empty(len(targets))
    for start in range(0, len(targets), block):
        monitor(start // block, 0.0)
        chunk = targets[start:start + block]
        z32 = _pair_potentials(ops, source, chunk).astype(np.float32)
        acc = None
        for gc in _split_gradient(ops):
            comp = gc @ z32
            acc = comp * comp if acc is None else acc + comp * comp
        np.sqrt(acc, out=acc)
        out[start:start + len(chunk)] = area32 @ acc
    return PointwiseDistanceResult(distances=out, source=source, k=0, targets=targets,
                                   iterations=0, residual=0.0, converged=True)


def _dwk_admm(ops, source, k, targets, harmonic, tol, max_iter, block, monitor
              ) -> PointwiseDistanceResult:
    """``d_W^k`` (k > 0): the spectral reduction of the mesh (built once, cached) and the
    batched ADMM of :mod:`solvers.emd.dwk`, ``block`` targets per multi-RHS solve."""
    problem = reduced_spectral_problem(ops, k, harmonic)
    # about six (2F, block) float32 arrays per block: bound the block by the working budget
    block = max(16, min(block, ADMM_WORK_BYTES // (24 * 2 * ops.n_faces)))
    n = len(targets)
    upper, lower = np.empty(n), np.empty(n)
    iterations = np.zeros(n, dtype=np.int64)
    for start in range(0, n, block):
        chunk = targets[start:start + block]
        data = problem.gradient @ _pair_potentials(ops, source, chunk)
        block_monitor = monitor.next_stage()
        block_monitor.offset = int(iterations.max()) if start else 0
        up, lo, its = solve_block(problem, np.ascontiguousarray(data, dtype=np.float32),
                                  tol=tol, max_iter=max_iter, monitor=block_monitor)
        upper[start:start + len(chunk)] = up
        lower[start:start + len(chunk)] = lo
        iterations[start:start + len(chunk)] = its
    residuals = gaps(upper, lower)
    return PointwiseDistanceResult(
        distances=upper, source=source, k=k, targets=targets,
        iterations=int(iterations.max()) if n else 0,
        residual=float(residuals.max()) if n else 0.0,
        converged=bool(np.all(residuals <= tol)), residuals=residuals,
        lower_bounds=lower, target_iterations=iterations, converged_targets=residuals <= tol)
