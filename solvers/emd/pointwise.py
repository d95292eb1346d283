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
  target.  ``route="green"`` reads ``G_x - G_y`` from the dense Green's matrix ``L⁺``
  of the mesh (:mod:`solvers.emd.green`: built once per mesh with ``V`` unit Poisson
  solves, cached on the mesh operators, 4·V² bytes, float32) and runs a compiled
  parallel face pass over all targets; ``route="solve"`` does one Poisson solve per
  target (``L z = e_x - e_y``, batched) and a sparse-gradient face pass (single
  precision).  Measured against a float64 evaluation: ≤ 1e-7 relative on average
  (solves: ~1e-6), up to 5e-5 (solves: 1.3e-4) at a nearest neighbour of the source
  across a short edge.  ``d_W^0`` is the L¹ norm of a difference of gradient fields, hence
  a metric (exact triangle inequality).
* ``k > 0``: a k-dimensional convex problem per target, solved for blocks of
  targets at once by Weiszfeld iterations (Fig. 2.4).  Minimizing over nested
  subspaces gives ``d_W^0 ≥ d_W^k ≥ d_W^{k'} (k < k')``, decreasing towards the
  full curl-basis W1 between the two Diracs, which approaches geodesic distance.

Solves are batched: targets are processed ``block`` at a time as one multi-RHS
solve with the prefactored Laplacian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.emd.bases import SpectralBasis
from solvers.emd.beckmann import check_mesh
from solvers.emd.green import GREEN_MAX_VERTICES, dw0_from_green
from solvers.errors import InputError
from solvers.monitor import Monitor, SolverResult

ROUTES = ("auto", "green", "solve")

# Cost model of the estimate (seconds on 2 cores; rough fit of spot, k = 20 and 50, 128
# targets, 25-34 iterations): a Poisson solve per target and vertex; per Weiszfeld
# iteration and target, a pass over the faces plus the (m x m) normal equations per face.
_SOLVE_SECONDS = 5e-7
_WEISZFELD_FACE_SECONDS = 3e-7
_WEISZFELD_SECONDS = 1.5e-10
_WEISZFELD_ITERATIONS = 30  # typical iterations per target (active targets only)
MAX_ESTIMATED_SECONDS = 300.0
WEISZFELD_PATIENCE = 30


@dataclass
class PointwiseDistanceResult(SolverResult):
    """``distances[y] = d_W^k(source, y)`` for every target ``y`` (unit-area lengths)."""

    distances: np.ndarray
    source: int
    k: int
    targets: np.ndarray


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
                        tol: float = 1e-6, max_iter: int = 300, block: int = 512,
                        route: str = "auto", green_max_vertices: int = GREEN_MAX_VERTICES,
                        max_seconds: float | None = MAX_ESTIMATED_SECONDS,
                        progress=None, should_cancel=None) -> PointwiseDistanceResult:
    r"""``d_W^k(source, y)`` for all vertices ``y`` (or ``targets``), thesis §2.5.

    Parameters
    ----------
    mesh : TriangleMesh.
    source : source vertex index.
    k : number of Laplacian eigenfunctions in the curl basis (0: Green's-function form).
    targets : optional vertex indices (default: all vertices).
    tol, max_iter : Weiszfeld stopping rule for ``k > 0`` (relative change per target).
    block : targets per multi-RHS solve (``route="solve"`` and ``k > 0``).
    route : ``k = 0`` only. ``"green"``: dense Green's matrix + compiled face pass (the
        matrix, ``4 V²`` bytes, is built on first use and kept in the mesh's operator
        store; build and query times in bench/results/emd.md); ``"solve"``: blocked Poisson solves
        per call (no memory beyond a block); ``"auto"``: ``"green"`` when the matrix is
        already built, or when the mesh has at most ``green_max_vertices`` vertices and
        at least a quarter of them are targets; ``"solve"`` otherwise.
    green_max_vertices : largest mesh for the dense matrix (``route="green"`` raises
        InputError(field="route") above it); default :data:`GREEN_MAX_VERTICES` (20000,
        1.6 GB).
    max_seconds : runs estimated above this (:func:`estimate_seconds`) are refused with an
        InputError naming the limit and the faster option (None: no limit).
    progress, should_cancel : called every Weiszfeld iteration / solve block; Weiszfeld
        stops a block as stalled when its worst change has not improved for
        ``WEISZFELD_PATIENCE`` iterations (converged False, measured change).

    Returns
    -------
    PointwiseDistanceResult with ``distances`` (len(targets),) — (V,) by default.
    """
    ops = check_mesh(mesh)
    source, k, targets = _check_inputs(ops, source, k, targets, route)
    monitor = Monitor(progress, should_cancel, tol=tol, patience=WEISZFELD_PATIENCE)
    green = k == 0 and route != "solve" and (
        route == "green" or ops.has_green_matrix
        or (mesh.n <= green_max_vertices and 4 * len(targets) >= mesh.n))
    check_cost(mesh.n, ops.n_faces, k, len(targets), green, max_seconds)
    if green:
        return _dw0_green(ops, source, targets, monitor, green_max_vertices)
    if k == 0:
        return _dw0_solve(ops, source, targets, block, monitor)
    return _dwk_weiszfeld(ops, source, k, targets, harmonic, tol, max_iter, block, monitor)


def estimate_seconds(n_vertices: int, n_faces: int, k: int, n_targets: int,
                     green: bool) -> float:
    """Estimated seconds of :func:`pointwise_distances` (``green``: the dense route; its
    one-time build is ``n_vertices`` solves, then a face pass per target)."""
    solves = n_targets * _SOLVE_SECONDS * n_vertices
    if k == 0:
        return (n_vertices * _SOLVE_SECONDS * n_vertices * 0.05 + n_targets * n_faces * 2e-9
                if green else solves)
    m = k + 4  # eigenfunctions plus (up to) harmonic fields
    per_iteration = _WEISZFELD_FACE_SECONDS * n_faces + _WEISZFELD_SECONDS * n_faces * m * m
    return solves + n_targets * _WEISZFELD_ITERATIONS * per_iteration


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
                    f"fit), or allow the dense Green's route above {GREEN_MAX_VERTICES} "
                    f"vertices (green_max_vertices; {4 * n_vertices ** 2 / 1e9:.1f} GB)")
            field = "targets"
        raise InputError(f"d_W^{k} to {n_targets} targets on {n_vertices} vertices is "
                         f"estimated at {est:.0f} s, above the limit of {max_seconds:.0f} s: "
                         f"{hint}", field=field)
    return est


def _check_inputs(ops, source, k, targets, route) -> tuple[int, int, np.ndarray]:
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
    if route not in ROUTES:
        raise InputError(f"route must be one of {ROUTES}, got {route!r}", field="route")
    if route == "green" and k > 0:
        raise InputError("route='green' evaluates d_W^0 only (k = 0)", field="route")
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


def _dwk_weiszfeld(ops, source, k, targets, harmonic, tol, max_iter, block, monitor
                   ) -> PointwiseDistanceResult:
    """``d_W^k`` (k > 0): the flow ``∇(G_x - G_y)`` corrected in the spectral curl basis,
    minimizing ``∫ |J|`` by Weiszfeld iterations, all targets of a block at once."""
    area = ops.face_areas
    basis = SpectralBasis(ops, k, harmonic=harmonic)
    fields = basis.fields
    if basis.n_harmonic:
        fields = np.concatenate([fields, basis.harmonic.transpose(1, 2, 0)], axis=2)
    m = fields.shape[2]
    local_gram = np.einsum("fck,fcl->fkl", fields, fields).reshape(len(fields), m * m)
    flat_fields = fields.reshape(-1, m)  # (3F, m)
    out = np.empty(len(targets))
    worst_change, max_its, converged, total = 0.0, 0, True, 0
    for start in range(0, len(targets), block):
        chunk = targets[start:start + block]
        diff = ops.grad(_pair_potentials(ops, source, chunk))  # (F, 3, B)
        flow = diff
        cost = np.einsum("f,fb->b", area, np.sqrt(np.einsum("fcb,fcb->fb", flow, flow)))
        active = np.arange(len(chunk))  # targets still iterating (converged ones drop out)
        block_monitor = Monitor(monitor.progress, monitor.should_cancel, tol=tol,
                                patience=monitor.patience)
        block_monitor.offset = total
        change = 0.0
        for it in range(1, max_iter + 1):
            d_a, f_a = diff[:, :, active], flow[:, :, active]
            norms = np.sqrt(np.einsum("fcb,fcb->fb", f_a, f_a))
            floor = np.maximum(1e-9 * norms.max(axis=0), 1e-12)
            omega = area[:, None] / np.maximum(norms, floor)  # (F, B)
            gram = (omega.T @ local_gram).reshape(len(active), m, m)
            rhs = -(flat_fields.T @ (omega[:, None, :] * d_a).reshape(-1, len(active)))
            coef = np.linalg.solve(gram, rhs.T[:, :, None])[:, :, 0]  # (B, m)
            f_a = d_a + (flat_fields @ coef.T).reshape(d_a.shape)
            flow[:, :, active] = f_a
            new = np.einsum("f,fb->b", area, np.sqrt(np.einsum("fcb,fcb->fb", f_a, f_a)))
            changes = np.abs(cost[active] - new) / np.maximum(new, 1e-300)
            cost[active] = new
            change = float(changes.max())
            max_its = max(max_its, it)
            block_monitor(it, change)
            active = active[changes > tol]
            if not len(active) or block_monitor.stalled:
                break
        total += max_its
        worst_change = max(worst_change, change)
        converged = converged and change <= tol
        out[start:start + len(chunk)] = cost
    return PointwiseDistanceResult(distances=out, source=source, k=k, targets=targets,
                                   iterations=max_its, residual=worst_change,
                                   converged=converged)
