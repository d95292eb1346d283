r"""Soft maps by Wasserstein propagation with compatibility (thesis §3.7, eq. 3.17-3.18).

The source mesh :math:`M_0` is a graph (farthest-point samples and their Voronoi adjacency,
weights :math:`\omega_e \propto 1/\ell_e^2`, :mod:`solvers.softmaps.sampling`); every node
``u`` carries a distribution :math:`\mu_u` over the target mesh :math:`M`.  Landmark pairs
:math:`(x_l, y_l)` are fixed nodes :math:`\mu_{x_l} = \delta_{y_l}`; the others solve

.. math::  \min_{\{\mu_u\}} \sum_{e=(u,u')} \omega_e\, W^2_{2,H_t}(\mu_u, \mu_{u'})
           \;+\; \tau \sum_u \int_M c(u, y)\, d\mu_u(y),

:math:`c` the normalized compatibility cost (:mod:`solvers.softmaps.compatibility`, mean 1)
and :math:`\tau` its weight.  Since every edge plan has :math:`\mu_u` as its marginal at
``u``, the linear term is shared among the edges at ``u`` (share
:math:`\omega_e / W_u`, :math:`W_u = \sum_{e\ni u}\omega_e`), which turns each edge's
kernel into the diagonally rescaled :math:`K_e = D_{d_u} H_t D_{d_{u'}}` with
:math:`d_u = \exp(-\tau c(u,\cdot) / (\gamma W_u))` -- eq. 3.18.  The problem is then one
Wasserstein propagation (Alg. 4) on the target's heat kernel with batched sweeps
(:func:`solvers.convolutional.wasserstein_propagation`, ``node_scalings``).
"""

from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from solvers.convolutional import wasserstein_propagation
from solvers.domains import supports
from solvers.errors import InputError, UnsupportedDomainError
from solvers.memory import map_large_blocks, release_free_heap
from solvers.monitor import SolverResult
from solvers.softmaps.coarse_target import Prolongation, coarse_target
from solvers.softmaps.compatibility import NORMS, compatibility_cost
from solvers.softmaps.descriptors import (
    LANDMARK_METHODS,
    check_landmarks,
    eigenpairs,
    landmark_descriptors,
    wave_kernel_signature,
    wks_energies,
)
from solvers.softmaps.energies import dirichlet_from_edge_values
from solvers.softmaps.extraction import EXTRACTIONS, REFINEMENTS, extract_correspondence
from solvers.softmaps.sampling import farthest_point_samples
from solvers.validation import check_choice, check_int, check_positive

# Samples (and coarse target points) of the first solve of ``multiscale=True``.
MULTISCALE_SAMPLES = 128
# ZoomOut's steps before the last read out this many farthest-point source vertices (None:
# all of them); the last one reads out every vertex (bench/results/softmaps.md).
ZOOMOUT_QUERIES = 1024
# "auto" solves over a coarse target when it has at most 1/AUTO_COARSENING of the vertices.
AUTO_COARSENING = 1.5
# Storage of the propagation's edge-end log-scalings (its largest array: 2 x edges x
# target points) over a coarse target: float32 halves it; the sweeps compute in float64.
SCALINGS_DTYPE = np.float32
# Smallest default gamma over a coarse target (unit-area target).  Below it the sweeps'
# slow mode -- mass moving between the two modes of left/right-ambiguous rows -- stalls:
# 4,096 samples (gamma 4 h^2 = 1.1e-3 of the coarse target) stood at a residual of 5.2e-4
# after 1,050 sweeps against tol 1e-4.  The floor is what the default solves from 512
# samples on (4 h^2: 9.3e-3 at 512, 5.0e-3 at 1,024); the rows are then blurrier than the
# sample spacing, which the refinement does not mind: errors with and without the floor in
# bench/results/softmaps.md.
COARSE_GAMMA_MIN = 0.01


def check_mesh_for_soft_map(mesh, field: str) -> None:
    """A soft map needs a triangle mesh with one connected component."""
    if not supports(mesh, "faces"):
        raise UnsupportedDomainError(f"{field} must be a triangle mesh, got a "
                                     f"{getattr(mesh, 'kind', type(mesh).__name__)}", field=field)
    if mesh.n_components > 1:
        raise UnsupportedDomainError(
            f"{field} has {mesh.n_components} connected components; transport cannot cross "
            "them, so a soft map needs a connected mesh", field=field)


def check_landmark_pairs(landmarks, n_source: int, n_target: int) -> np.ndarray:
    """``(L, 2)`` int64 pairs ``(source vertex, target vertex)`` in range."""
    if landmarks is None or len(landmarks) == 0:
        return np.zeros((0, 2), np.int64)
    try:
        x = np.asarray(landmarks)
    except (TypeError, ValueError) as exc:
        raise InputError("landmarks must be (source, target) vertex pairs",
                         field="landmarks") from exc
    if x.ndim != 2 or x.shape[1] != 2:
        raise InputError(f"landmarks must have shape (L, 2), got {x.shape}", field="landmarks")
    check_landmarks(x[:, 0], n_source, "landmarks.source")
    if not np.issubdtype(x.dtype, np.integer):
        raise InputError("landmark indices must be integers", field="landmarks")
    x = x.astype(np.int64)
    bad = np.flatnonzero((x[:, 1] < 0) | (x[:, 1] >= n_target))
    if len(bad):
        raise InputError(f"landmarks.target[{int(bad[0])}] = {int(x[bad[0], 1])} is outside "
                         f"[0, {n_target - 1}]", field="landmarks.target")
    return x


EDGES_PER_SAMPLE = 3.0  # source edges per farthest-point sample (a surface's sample graph)


# Bytes per source and target vertex beyond the descriptors: ZoomOut's (vertices x k_end)
# products and contiguous copies of the bases (k_end 80: 2 x 80 floats per vertex), the
# sampling's and extraction's per-vertex arrays.
PER_VERTEX_BYTES = 2 * 80 * 8 + 256


def estimated_bytes(n_samples: int, n_target: int, edges_per_sample: float = EDGES_PER_SAMPLE,
                    target_points: int | None = None, n_source: int = 0, k: int = 0,
                    n_energies: int = 0, landmarks: int = 0, whole_rows: bool = False) -> int:
    """Peak bytes of :func:`soft_map` for ``n_samples`` over ``n_target`` target vertices,
    solved over ``target_points`` coarse points (``None``: all ``n_target`` vertices).

    Over a coarse target, per (sample, coarse point): the edge-end log-scalings (2 per
    edge), the node log-rescalings and the barycenters, which become the rows
    (:data:`SCALINGS_DTYPE`); the final masses' temporaries over a block of nodes; the
    prolongation (up to 4 entries per target vertex) and one block of prolonged rows
    (gathered float32), or with ``whole_rows`` (an extraction other than the mode, or a
    Sinkhorn refinement) all of them (float32, float64 in the projection).  At full
    resolution (float64), per (sample, target vertex): the edge-end log-scalings, the node
    log-rescalings, barycenters and masses with two temporaries, the float32 rows and the
    extraction's float64 copy of them.  The descriptors of both
    meshes (``k`` eigenpairs, ``n_energies`` WKS energies and one column per landmark,
    float64) and
    :data:`PER_VERTEX_BYTES` per vertex.  Measured peaks: bench/results/softmaps.md,
    bench/results/softmap_memory.md and bench/results/operation_memory.md.
    """
    from solvers.convolutional.propagation import MASS_COLUMNS
    from solvers.softmaps.coarse_target import APPLY_ROWS

    if target_points is None:  # float64 throughout (bench/results/softmap_memory.md)
        total = n_samples * n_target * (2 * edges_per_sample * 8 + 6 * 8 + 4 + 8)
    else:
        item = np.dtype(SCALINGS_DTYPE).itemsize
        total = n_samples * target_points * (2 * edges_per_sample + 2) * item
        total += min(n_samples, MASS_COLUMNS) * target_points * 32
        total += n_target * 4 * 16
        total += (n_samples if whole_rows else APPLY_ROWS) * n_target * 16
    total += (k + n_energies + landmarks) * (n_source + n_target) * 8
    total += PER_VERTEX_BYTES * (n_source + n_target)
    return int(total)


def wholly_prolonged(extraction: str, refine: str) -> bool:
    """Whether the extraction forms every prolonged row at once (only the mode and ZoomOut
    read them a block at a time)."""
    return extraction != "mode" or refine.startswith("sinkhorn")


def solved_points(target_points, n_samples: int, n_target: int) -> int | None:
    """The number of coarse target points a soft map solves over, or ``None`` for all
    ``n_target`` vertices.

    ``"auto"``: as many as the source samples, when that is at most ``n_target /``
    :data:`AUTO_COARSENING` (else the coarse target would save too little); an integer:
    that many (``None`` when it is at least ``n_target``); ``None``: all vertices.
    """
    if target_points is None:
        return None
    if isinstance(target_points, str):
        if target_points != "auto":
            raise InputError("target_points must be 'auto', an integer or None",
                             field="target_points")
        return n_samples if n_samples * AUTO_COARSENING <= n_target else None
    points = check_int(target_points, "target_points", low=4)
    return None if points >= n_target else points


def default_gamma(n_samples: int, target, coarse: bool = False) -> float:
    r"""Twice the squared spacing of ``n_samples`` uniform samples of a unit-area surface
    (:math:`2 \cdot 2/(\sqrt3 N)`), and at least :math:`4h^2` (``h``: edge length of the
    target solved over); over a coarse target (``coarse``) at least
    :data:`COARSE_GAMMA_MIN` as well."""
    gamma = max(4.0 / (np.sqrt(3.0) * n_samples), 4.0 * target.mean_edge_length**2)
    return max(gamma, COARSE_GAMMA_MIN) if coarse else gamma


@dataclass(kw_only=True)
class SoftMapResult(SolverResult):
    r"""A soft map :math:`\mu: M_0 \to \mathrm{Prob}(M)` on source samples.

    With ``top_k``, ``soft_map`` is ``None`` and ``top_indices``/``top_masses`` keep the
    ``k`` largest masses per row over the target's vertices.  :meth:`row` and
    :meth:`target_rows` give rows on every target vertex.

    Attributes
    ----------
    iterations, residual, converged : int, float, bool
        Convergence data of the propagation (:class:`~solvers.monitor.SolverResult`).
    samples : (N,) int array
        Source sample vertices.
    labels : (n_source,) int array
        Sample of each source vertex's cell.
    cell_areas : (N,) array
        Areas of the cells.
    edges : (m, 2) int array
        The source graph's edges.
    edge_weights : (m,) array
        Their weights :math:`\omega_e`.
    soft_map : (N, target_points or n_target) float32 array or None
        Masses per sample on the points solved over (rows sum to 1).
    top_indices, top_masses : (N, k) array or None
        With ``top_k``: the ``k`` largest masses per row and their target vertices.
    dropped_mass : (N,) array or None
        With ``top_k``: the mass not kept.
    correspondence : (n_source,) int array
        Target vertex of every source vertex (extracted, then refined if asked).
    sample_correspondence : (N,) int array
        The extraction before refinement.
    dirichlet : DirichletEnergy
        Dirichlet energy from the final edge plans (convolutional :math:`W^2` on the points
        solved over, not debiased).
    descriptor_energy : float
        eq. 4.6 with the normalized cost.
    gamma : float
        Entropic regularization used.
    tau : float
        Compatibility weight used.
    timings : dict
        Seconds per stage.
    sinkhorn : SinkhornProjection or None
        The projection of ``refine="sinkhorn"``, without its rows (``soft_map`` stays the
        unprojected map).
    n_target : int
        Target vertices.
    target_points : int or None
        Coarse target points eq. 3.18 was solved over (:mod:`solvers.softmaps.coarse_target`),
        ``None`` when solved over every target vertex.
    prolongation : Prolongation or None
        Takes coarse masses to every target vertex.
    """

    samples: np.ndarray
    labels: np.ndarray
    cell_areas: np.ndarray
    edges: np.ndarray
    edge_weights: np.ndarray
    soft_map: np.ndarray | None
    top_indices: np.ndarray | None = None
    top_masses: np.ndarray | None = None
    dropped_mass: np.ndarray | None = None
    correspondence: np.ndarray
    sample_correspondence: np.ndarray
    dirichlet: object = None
    descriptor_energy: float = 0.0
    gamma: float = 0.0
    tau: float = 0.0
    timings: dict = field(default_factory=dict)
    sinkhorn: object = None
    n_target: int = 0
    target_points: int | None = None
    prolongation: Prolongation | None = None

    def row(self, i: int) -> np.ndarray:
        """Dense ``(n_target,)`` masses of sample ``i`` on every target vertex (prolonged
        from the coarse target; zeros outside the top-k).

        Parameters
        ----------
        i : int
            Sample index.

        Returns
        -------
        (n_target,) array
        """
        if self.soft_map is not None:
            r = np.asarray(self.soft_map[i], dtype=np.float64)
            return r if self.prolongation is None else self.prolongation.apply(r)
        out = np.zeros(self.n_target)
        out[self.top_indices[i]] = self.top_masses[i]
        return out

    def target_rows(self) -> np.ndarray:
        """``(N, n_target)`` float32 masses of every sample on every target vertex."""
        if self.soft_map is None:
            out = np.zeros((len(self.top_indices), self.n_target), np.float32)
            np.put_along_axis(out, self.top_indices, self.top_masses, axis=1)
            return out
        return self.soft_map if self.prolongation is None else \
            self.prolongation.apply(self.soft_map)


def descriptors_for_pair(source, target, landmarks, *, k: int = 100, n_energies: int = 100,
                         wks_weight: float = 1.0, landmark_weight: float = 1.0,
                         landmark_method: str = "geodesic"):
    """Stacked descriptors of two meshes: WKS on shared energies, and landmark descriptors.

    Each block is divided by its width so ``wks_weight``/``landmark_weight`` weigh blocks.

    Parameters
    ----------
    source, target : TriangleMesh
        The two surfaces.
    landmarks : (L, 2) int array or None
        Pairs ``(source vertex, target vertex)``.
    k : int
        Eigenpairs of the WKS.
    n_energies : int
        WKS energies.
    wks_weight, landmark_weight : float
        Weights of the two blocks (0 leaves a block out).
    landmark_method : {"geodesic", "heat"}
        See :func:`landmark_descriptors`.

    Returns
    -------
    f0 : (n0, d) array
        Source descriptors.
    f : (n1, d) array
        Target descriptors.
    """
    lam0, _ = eigenpairs(source, k)
    lam1, _ = eigenpairs(target, k)
    energies, sigma = wks_energies(lam0, lam1, n_energies=n_energies)
    blocks0, blocks1 = [], []
    if wks_weight > 0:
        blocks0.append(wks_weight * wave_kernel_signature(source, k, energies, sigma)
                       / n_energies)
        blocks1.append(wks_weight * wave_kernel_signature(target, k, energies, sigma)
                       / n_energies)
    if len(landmarks) and landmark_weight > 0:
        check_choice(landmark_method, LANDMARK_METHODS, "landmark_method")
        scale = landmark_weight / len(landmarks)
        blocks0.append(scale * landmark_descriptors(source, landmarks[:, 0],
                                                    method=landmark_method))
        blocks1.append(scale * landmark_descriptors(target, landmarks[:, 1],
                                                    method=landmark_method))
    if not blocks0:
        raise InputError("no descriptor: give wks_weight > 0 or landmarks", field="descriptors")
    return np.concatenate(blocks0, axis=1), np.concatenate(blocks1, axis=1)


def _one_blas_thread(fn):
    """Run ``fn`` with BLAS on one thread: the soft map parallelizes its own loops
    (propagation chunks, nearest rows) over the cores, and BLAS threads on top of those
    oversubscribed them (ad hoc: a cold default call took 51 s unpinned at load 4.8 against
    18 s pinned)."""
    @functools.wraps(fn)
    def pinned(*args, **kwargs):
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return pinned


@_one_blas_thread
def soft_map(
    source, target, landmarks=None, *, samples: int = 1024,
    target_points: int | str | None = "auto", tau: float = 0.05, gamma: float | None = None,
    substeps: int = 1, k: int = 100, n_energies: int = 100, wks_weight: float = 1.0,
    landmark_weight: float = 1.0, landmark_method: str = "geodesic", norm: str = "l1",
    descriptors: tuple | None = None, tol: float = 1e-4, max_iter: int = 1000,
    acceleration: str = "over-relaxation", top_k: int | None = None,
    extraction: str = "mode", refine: str = "symmetric-zoomout",
    zoomout_range: tuple[int, int, int] = (20, 80, 2), max_bytes: int | None = None,
    multiscale: bool = False, progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> SoftMapResult:
    r"""Soft map ``source -> target`` by Wasserstein propagation with compatibility (§3.7).

    Landmarks are fixed nodes :math:`\mu_{x_l} = \delta_{y_l}`; the other source samples
    solve (eq. 3.17-3.18)

    .. math::  \min_{\{\mu_u\}} \sum_{e=(u,u')} \omega_e\, W^2_{2,H_t}(\mu_u, \mu_{u'})
               \;+\; \tau \sum_u \int_M c(u, y)\, d\mu_u(y),

    one Wasserstein propagation (Alg. 4) with per-edge rescaled kernels (eq. 3.18); a point
    map is then extracted (§4.5.1) and refined.

    Parameters
    ----------
    source, target : TriangleMesh
        Connected surfaces of unit area.
    landmarks : (L, 2) int array, optional
        Pairs ``(source vertex, target vertex)``: fixed nodes :math:`\mu = \delta_y` and
        landmark descriptors (geodesic distances).
    samples : int
        Number of farthest-point source samples ``N`` (``>= n_source``: all vertices).
    target_points : "auto", int or None
        ``"auto"``: eq. 3.18 solved over a coarse target of about ``N`` points (the target
        decimated, :mod:`solvers.softmaps.coarse_target`) when that is at most 2/3 of its
        vertices (:func:`solved_points`); an integer: that many coarse points; ``None``:
        every target vertex.  The compatibility cost is evaluated at the coarse points,
        landmark deltas are their barycentric weights there, and the rows are prolonged to
        every target vertex for the extraction (a block of rows at a time, or through
        :math:`P^\top`: no samples × n_target matrix); ``result.target_points`` says which
        ran.
    tau : float
        Compatibility weight :math:`\tau` (the cost has mean 1).
    gamma : float, optional
        Entropic regularization of the heat kernel on the target solved over
        (``t = gamma/4``; default :func:`default_gamma`).
    substeps : int
        Implicit Euler steps of the heat kernel.
    k, n_energies, wks_weight, landmark_weight, landmark_method : int, int, float, float, str
        Descriptors (:func:`descriptors_for_pair`).
    norm : {"l1", "l2"}
        Cost (:func:`compatibility_cost`).
    descriptors : tuple, optional
        ``(f0, f)``: descriptors per source and target vertex, instead of computing them.
    tol, max_iter : float, int
        Stopping of the propagation (largest L1 marginal violation).
    acceleration : {"over-relaxation", "none"}
        Adaptive over-relaxation of the sweeps (same fixed point), or plain Alg. 4 sweeps;
        see :func:`~solvers.convolutional.wasserstein_propagation`.
    top_k : int, optional
        Keep only the ``k`` largest masses per row over the target vertices
        (``dropped_mass`` reports the rest).
    extraction : {"mode", "barycentric", "path"}
        Point-map extraction; ``"path"`` is eq. 4.7, seeded with the first landmark.
    refine : {"symmetric-zoomout", "zoomout", "sinkhorn", "sinkhorn+zoomout", "none"}
        ``"symmetric-zoomout"``: spectral upsampling started from the soft map's own
        functional map, the reverse map tied in; ``"zoomout"``: the same one way;
        ``"sinkhorn"``: doubly-stochastic projection of the rows before extraction
        (:func:`~solvers.softmaps.extraction.extract_correspondence`).
    zoomout_range : tuple of int
        ``(k_start, k_end, step)`` of ZoomOut.
    max_bytes : int, optional
        Refuse (``InputError`` on ``samples``) a problem whose estimated peak memory
        exceeds this.
    multiscale : bool
        Start the propagation from a solve with :data:`MULTISCALE_SAMPLES` samples over as
        many coarse target points, prolonged (same fixed point; off by default:
        bench/results/softmaps.md measures it).
    progress : callable, optional
        ``progress(iteration, residual)``, called once per iteration.
    should_cancel : callable, optional
        ``should_cancel() -> bool``; True stops with :class:`~solvers.errors.CancelledError`.

    Returns
    -------
    SoftMapResult
        ``iterations``, ``residual``, ``converged`` from the propagation; the soft map, the
        point map and the energies.
    """
    pairs, n_samples, points, tau, top_k = _checked_request(
        source, target, landmarks, samples=samples, target_points=target_points, k=k,
        n_energies=n_energies, extraction=extraction, refine=refine, max_bytes=max_bytes,
        tau=tau, norm=norm, top_k=top_k)
    timings = {}
    map_large_blocks()  # the (samples x target) temporaries go back to the OS when freed
    with _timed(timings, "sampling"):
        graph, cells, coarse = _sampled(source, target, pairs, n_samples, points)
    solved = target if coarse is None else coarse.mesh
    gamma = check_positive(default_gamma(n_samples, solved, coarse=coarse is not None)
                           if gamma is None else gamma, "gamma")
    cost, start = _cost_and_start(
        source, target, pairs, graph, coarse, descriptors, timings, n_samples, multiscale,
        norm=norm, tau=tau, tol=tol, max_iter=max_iter, k=k, n_energies=n_energies,
        wks_weight=wks_weight, landmark_weight=landmark_weight, landmark_method=landmark_method)
    del descriptors  # not needed any more: out before the largest arrays come
    with _timed(timings, "propagation"):  # float32 node logs replace the float64 cost
        log_d = _node_logs(cost, graph, tau=tau, gamma=gamma, coarse=coarse is not None)
        del cost
        prop, rows, descriptor = _propagate(
            solved, coarse, graph, cells, pairs, log_d, tau=tau, gamma=gamma,
            substeps=substeps, tol=tol, start_masses=start, max_iter=max_iter,
            acceleration=acceleration, progress=progress, should_cancel=should_cancel)
    with _timed(timings, "extraction"):
        extracted = _extracted(source, target, rows, graph, cells, pairs, coarse,
                               extraction=extraction, refine=refine,
                               zoomout_range=zoomout_range)
    return _soft_map_result(prop, graph, cells, rows, extracted, coarse, top_k,
                            descriptor=descriptor, gamma=gamma, tau=tau, timings=timings,
                            n_target=target.n)


@contextlib.contextmanager
def _timed(timings: dict, stage: str):
    """Record the wall time of the ``with`` block as ``timings[stage]``."""
    t0 = time.perf_counter()
    yield
    timings[stage] = time.perf_counter() - t0


def _sampled(source, target, pairs, n_samples, points):
    """The farthest-point sample graph on ``source`` (seeded with the landmarks), the areas
    of its cells, and the coarse target of ``points`` points (None: the target itself)."""
    graph = farthest_point_samples(source, n_samples, pairs[:, 0])
    cells = np.bincount(graph.labels, weights=source.areas, minlength=graph.n)
    coarse = None if points is None else coarse_target(target, points)
    return graph, cells, coarse


def _checked_request(source, target, landmarks, *, samples, target_points, k, n_energies,
                     extraction, refine, max_bytes, tau, norm, top_k):
    """:func:`soft_map`'s inputs checked, before any work: ``(landmark pairs, samples,
    solved target points (None: all), tau, top_k)``; a problem whose estimated memory
    exceeds ``max_bytes`` is refused."""
    check_mesh_for_soft_map(source, "source")
    check_mesh_for_soft_map(target, "target")
    pairs = check_landmark_pairs(landmarks, source.n, target.n)
    if len(pairs) == 0:
        raise InputError("a soft map by propagation needs at least one landmark pair (a "
                         "fixed node)", field="landmarks")
    samples = check_int(samples, "samples", low=max(2, len(pairs)))
    n_samples = min(samples, source.n)
    points = solved_points(target_points, n_samples, target.n)
    need = estimated_bytes(n_samples, target.n, target_points=points, n_source=source.n,
                           k=k, n_energies=n_energies, landmarks=len(pairs),
                           whole_rows=wholly_prolonged(extraction, refine))
    if max_bytes is not None and need > max_bytes:
        raise InputError(f"{n_samples} samples over {points or target.n} target points need "
                         f"about {need / 2**20:.0f} MiB, more than the "
                         f"{max_bytes / 2**20:.0f} MiB allowed", field="samples")
    tau = check_positive(tau, "tau")
    check_choice(norm, NORMS, "norm")
    check_choice(extraction, EXTRACTIONS, "extraction")
    check_choice(refine, REFINEMENTS, "refine")
    if top_k is not None:
        top_k = check_int(top_k, "top_k", low=1, high=target.n)
    return pairs, n_samples, points, tau, top_k


def _cost_and_start(source, target, pairs, graph, coarse, descriptors, timings, n_samples,
                    multiscale, *, norm, tau, tol, max_iter, **descriptor_options):
    """The compatibility cost ``(N, solved points)`` of the samples of ``graph`` (from
    ``descriptors``, or :func:`descriptors_for_pair` with ``descriptor_options``) and the
    propagation's start (:func:`_multiscale_start` with ``multiscale``, else None); the
    descriptors are freed before returning."""
    with _timed(timings, "descriptors"):
        if descriptors is None:
            f0, f1 = descriptors_for_pair(source, target, pairs, **descriptor_options)
        else:
            f0, f1 = descriptors
        cost = compatibility_cost(f0, f1, areas0=source.areas, areas1=target.areas,
                                  rows=graph.indices, norm=norm,
                                  columns=None if coarse is None else coarse.restrict(f1))
    with _timed(timings, "multiscale"):
        start = None
        if multiscale and coarse is not None and n_samples > MULTISCALE_SAMPLES:
            start = _multiscale_start(source, target, pairs, graph, coarse, f0, f1, norm=norm,
                                      tau=tau, tol=tol, max_iter=max_iter)
    del f0, f1, descriptors  # not needed any more: out before the largest arrays come
    release_free_heap()  # the descriptors' temporaries too
    return cost, start


def _extracted(source, target, rows, graph, cells, pairs, coarse, *, extraction, refine,
               zoomout_range):
    """The correspondence extracted from the soft map's ``rows`` (prolonged from the coarse
    target, if any), its projected Sinkhorn rows not kept."""
    extracted = extract_correspondence(source, target, rows, labels=graph.labels,
                                       samples=graph.indices, cell_areas=cells,
                                       edges=graph.edges, fixed=np.arange(len(pairs)),
                                       seed_target=int(pairs[0, 1]),
                                       extraction=extraction, refine=refine,
                                       zoomout_range=zoomout_range,
                                       zoomout_queries=_zoomout_queries(source, target, pairs),
                                       prolongation=None if coarse is None else
                                       coarse.prolongation)
    if extracted.sinkhorn is not None:
        extracted.sinkhorn.rows = None  # the projected copy is not kept
    return extracted


def _soft_map_result(prop, graph, cells, rows, extracted, coarse, top_k, *, descriptor, gamma,
                     tau, timings, n_target) -> SoftMapResult:
    """The :class:`SoftMapResult`: the rows kept whole, or their ``top_k`` largest masses."""
    prolongation = None if coarse is None else coarse.prolongation
    dirichlet = dirichlet_from_edge_values(prop.edge_values, graph.edges, graph.weights,
                                           graph.n, cells)
    top_idx = top_m = dropped = None
    if top_k is not None:
        top_idx, top_m, dropped = _top_k(rows, prolongation, top_k)
        rows = prolongation = None
    release_free_heap()
    return SoftMapResult(
        iterations=prop.iterations, residual=prop.residual, converged=prop.converged,
        samples=graph.indices, labels=graph.labels, cell_areas=cells, edges=graph.edges,
        edge_weights=graph.weights, soft_map=rows, top_indices=top_idx, top_masses=top_m,
        dropped_mass=dropped, correspondence=extracted.correspondence,
        sample_correspondence=extracted.sample_correspondence,
        dirichlet=dirichlet, descriptor_energy=descriptor, gamma=gamma, tau=tau,
        timings=timings, n_target=n_target, sinkhorn=extracted.sinkhorn,
        target_points=None if coarse is None else coarse.n, prolongation=prolongation)


def _top_k(rows, prolongation, k: int):
    """The ``k`` largest masses of every row on the target (prolonged a block of rows at a
    time): ``(indices (N, k), masses (N, k), dropped mass (N,))``."""
    idx = np.empty((len(rows), k), np.int64)
    masses = np.empty((len(rows), k), rows.dtype)
    blocks = ([(0, rows)] if prolongation is None else prolongation.blocks(rows))
    for r0, block in blocks:
        part = np.argpartition(-block, k - 1, axis=1)[:, :k]
        idx[r0:r0 + len(block)] = part
        masses[r0:r0 + len(block)] = np.take_along_axis(block, part, axis=1)
    dropped = np.maximum(1.0 - masses.sum(axis=1, dtype=np.float64), 0.0)
    return idx, masses, dropped


def _multiscale_start(source, target, pairs, graph, coarse, f0, f1, *, norm, tau, tol,
                      max_iter):
    """``(coarse.n, N)`` guesses for the nodes of ``graph``: eq. 3.18 solved with
    :data:`MULTISCALE_SAMPLES` samples over as many coarse points (default gamma there),
    each row prolonged to the target, read at ``coarse``'s points, and given to the nodes
    of its cell."""
    small = farthest_point_samples(source, MULTISCALE_SAMPLES, pairs[:, 0])
    cells = np.bincount(small.labels, weights=source.areas, minlength=small.n)
    below = coarse_target(target, MULTISCALE_SAMPLES)
    cost = compatibility_cost(f0, f1, areas0=source.areas, areas1=target.areas,
                              rows=small.indices, norm=norm, columns=below.restrict(f1))
    gamma = default_gamma(small.n, below.mesh, coarse=True)
    _, rows, _ = _propagate(below.mesh, below, small, cells, pairs,
                            _node_logs(cost, small, tau=tau, gamma=gamma, coarse=True), tau=tau,
                            gamma=gamma, tol=tol,
                            max_iter=max_iter, acceleration="over-relaxation")
    density = below.prolongation.apply(rows.astype(np.float64)) / target.areas  # (n_s, n)
    guess = coarse.restrict(density.T) * coarse.mesh.areas[:, None]  # (coarse.n, n_s)
    guess /= guess.sum(axis=0, keepdims=True)
    return guess[:, small.labels[graph.indices]]


def _zoomout_queries(source, target, pairs):
    """ZoomOut's intermediate vertices and their cell areas on the source and the target
    (``None``: all), farthest-point samples seeded with the landmarks."""
    def on(mesh, seeds):
        if ZOOMOUT_QUERIES is None or ZOOMOUT_QUERIES >= mesh.n:
            return None
        g = farthest_point_samples(mesh, max(ZOOMOUT_QUERIES, len(seeds)), seeds)
        return g.indices, np.bincount(g.labels, weights=mesh.areas, minlength=g.n)

    return on(source, pairs[:, 0]), on(target, np.unique(pairs[:, 1]))


def _node_weights(graph) -> np.ndarray:
    """:math:`W_u = \\sum_{e \\ni u} \\omega_e` per node of ``graph``."""
    return np.bincount(graph.edges.ravel(), weights=np.repeat(graph.weights, 2),
                       minlength=graph.n)


def scalings_dtype(coarse: bool):
    """Storage of the propagation's log-scalings: :data:`SCALINGS_DTYPE` over a coarse
    target, float64 at full resolution (its memory model was measured in float64)."""
    return SCALINGS_DTYPE if coarse else np.float64


def _node_logs(cost, graph, *, tau, gamma, coarse: bool) -> np.ndarray:
    """The node log-rescalings :math:`\\log d_u = -\\tau c(u, \\cdot) / (\\gamma W_u)` of eq.
    3.18, stored as the propagation's log-scalings (:func:`scalings_dtype`); ``cost`` is
    overwritten (scaled in place)."""
    cost *= -tau / gamma / _node_weights(graph)[:, None]
    return cost.astype(scalings_dtype(coarse), copy=False)


def _propagate(solved, coarse, graph, cells, pairs, log_d, *, tau, gamma, start_masses=None,
               **options):
    """eq. 3.18 over ``solved`` (the target, or ``coarse.mesh``) with the node
    log-rescalings ``log_d`` (:func:`_node_logs`): the propagation result, the ``(N,
    solved.n)`` float32 rows and the descriptor energy (eq. 4.6)."""
    w = graph.weights
    wu = _node_weights(graph)
    fixed = {}
    for j, (_, y) in enumerate(pairs):  # landmark j is sample j (seeds first)
        if coarse is None:
            fixed[j] = np.zeros(solved.n)
            fixed[j][y] = 1.0
        else:
            fixed[j] = coarse.landmark_masses(int(y))
    if start_masses is not None:
        for j, m in fixed.items():
            start_masses[:, j] = m
    prop = wasserstein_propagation(solved, graph.n, graph.edges, fixed, edge_weights=w,
                                   node_scalings=log_d, gamma=gamma,
                                   start_masses=start_masses,
                                   scalings_dtype=log_d.dtype, method="convolutional",
                                   **options)
    # Descriptor energy (eq. 4.6) with the normalized cost c = -log_d * gamma * W_u / tau.
    descriptor = -(gamma / tau) * float((cells * wu) @ np.einsum("ij,ji->i", log_d,
                                                                  prop.masses,
                                                                  dtype=np.float64))
    del log_d
    rows = np.ascontiguousarray(prop.masses.T, dtype=np.float32)
    prop.masses = None
    return prop, rows, descriptor
