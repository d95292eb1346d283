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

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from solvers.convolutional import wasserstein_propagation
from solvers.errors import InputError, UnsupportedDomainError
from solvers.monitor import SolverResult
from solvers.softmaps.compatibility import NORMS, compatibility_cost
from solvers.softmaps.descriptors import (
    LANDMARK_ROUTES,
    check_landmarks,
    eigenpairs,
    landmark_descriptors,
    wave_kernel_signature,
    wks_energies,
)
from solvers.softmaps.energies import dirichlet_from_edge_values
from solvers.softmaps.extraction import EXTRACTIONS, REFINEMENTS, extract_correspondence
from solvers.softmaps.sampling import farthest_point_samples
from solvers.validation import check_int, check_positive


def check_mesh_for_soft_map(mesh, field: str) -> None:
    """A soft map needs a triangle mesh with one connected component."""
    if getattr(mesh, "kind", None) != "mesh":
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


def estimated_bytes(n_samples: int, n_target: int, edges_per_sample: float = 3.0) -> int:
    """Peak bytes of :func:`soft_map` for ``n_samples`` over ``n_target`` target vertices.

    Per (sample, target vertex): the edge-end log-scalings (2 per edge, float64), the node
    log-rescalings, barycenters and masses with two temporaries of the final normalization
    (float64), and the float32 soft map; the propagation's chunk temporaries are small.
    Measured peaks are in bench/results/softmaps.md.
    """
    return int(n_samples * n_target * (2 * edges_per_sample * 8 + 6 * 8 + 4))


def default_gamma(n_samples: int, target) -> float:
    r"""Twice the squared spacing of ``n_samples`` uniform samples of a unit-area surface
    (:math:`2 \cdot 2/(\sqrt3 N)`), and at least :math:`4h^2` (``h``: target edge length)."""
    return max(4.0 / (np.sqrt(3.0) * n_samples), 4.0 * target.mean_edge_length**2)


@dataclass(kw_only=True)
class SoftMapResult(SolverResult):
    r"""A soft map :math:`\mu: M_0 \to \mathrm{Prob}(M)` on source samples.

    ``samples`` ``(N,)`` source vertices; ``labels`` ``(n_source,)`` sample of each source
    vertex's cell; ``cell_areas`` ``(N,)``; ``edges``/``edge_weights`` the source graph.
    ``soft_map`` ``(N, n_target)`` float32 target masses per sample (rows sum to 1), or with
    ``top_k`` ``None`` and ``top_indices``/``top_masses`` ``(N, k)`` plus ``dropped_mass``
    ``(N,)`` (mass outside the kept entries).  ``correspondence`` ``(n_source,)`` the target
    vertex of every source vertex (extracted, then refined if asked);
    ``sample_correspondence`` ``(N,)`` the extraction before refinement; ``dirichlet`` the
    Dirichlet energy from the final edge plans (convolutional :math:`W^2`, not debiased);
    ``descriptor_energy`` eq. 4.6 with the normalized cost; ``sinkhorn`` the projection of
    ``refine="sinkhorn"`` (:class:`~solvers.softmaps.extraction.SinkhornProjection` without
    its rows; ``soft_map`` stays the unprojected map), else ``None``.
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

    def row(self, i: int) -> np.ndarray:
        """Dense ``(n_target,)`` masses of sample ``i`` (zeros outside the top-k)."""
        if self.soft_map is not None:
            return np.asarray(self.soft_map[i], dtype=np.float64)
        out = np.zeros(self.n_target)
        out[self.top_indices[i]] = self.top_masses[i]
        return out

    n_target: int = 0


def descriptors_for_pair(source, target, landmarks, *, k: int = 100, n_energies: int = 100,
                         wks_weight: float = 1.0, landmark_weight: float = 1.0,
                         landmark_route: str = "geodesic"):
    """Stacked descriptors ``(f0 (n0, d), f (n1, d))``: WKS on shared energies + landmarks.

    Each block is divided by its width so ``wks_weight``/``landmark_weight`` weigh blocks.
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
        if landmark_route not in LANDMARK_ROUTES:
            raise InputError(f"landmark_route must be one of {LANDMARK_ROUTES}",
                             field="landmark_route")
        scale = landmark_weight / len(landmarks)
        blocks0.append(scale * landmark_descriptors(source, landmarks[:, 0],
                                                    route=landmark_route))
        blocks1.append(scale * landmark_descriptors(target, landmarks[:, 1],
                                                    route=landmark_route))
    if not blocks0:
        raise InputError("no descriptor: give wks_weight > 0 or landmarks", field="descriptors")
    return np.concatenate(blocks0, axis=1), np.concatenate(blocks1, axis=1)


def soft_map(
    source,
    target,
    landmarks=None,
    *,
    samples: int = 1024,
    tau: float = 0.05,
    gamma: float | None = None,
    substeps: int = 1,
    k: int = 100,
    n_energies: int = 100,
    wks_weight: float = 1.0,
    landmark_weight: float = 1.0,
    landmark_route: str = "geodesic",
    norm: str = "l1",
    descriptors: tuple | None = None,
    tol: float = 1e-4,
    max_iter: int = 1000,
    acceleration: str = "over-relaxation",
    top_k: int | None = None,
    extraction: str = "mode",
    refine: str = "zoomout",
    zoomout_range: tuple[int, int, int] = (20, 50, 1),
    max_bytes: int | None = None,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> SoftMapResult:
    r"""Soft map ``source -> target`` by Wasserstein propagation with compatibility (§3.7).

    Parameters
    ----------
    source, target : connected :class:`~solvers.TriangleMesh` (unit area).
    landmarks : ``(L, 2)`` pairs ``(source vertex, target vertex)``: fixed nodes
        :math:`\mu = \delta_y` and landmark descriptors (geodesic distances).
    samples : number of farthest-point source samples ``N`` (``>= n_source``: all vertices).
    tau : compatibility weight :math:`\tau` (cost of mean 1); gamma : entropic
        regularization of the target's heat kernel (``t = gamma/4``; default
        :func:`default_gamma`).
    k, n_energies, wks_weight, landmark_weight, landmark_route, norm : descriptors
        (:func:`descriptors_for_pair`) and cost (:func:`compatibility_cost`); or pass
        ``descriptors=(f0, f)`` directly.
    tol, max_iter : stopping of the propagation (largest L1 marginal violation).
    acceleration : ``"over-relaxation"`` (default: adaptive over-relaxation of the sweeps,
        same fixed point) or ``"none"`` (plain Alg. 4 sweeps); see
        :func:`~solvers.convolutional.wasserstein_propagation`.
    top_k : keep only the ``k`` largest masses per row (``dropped_mass`` reports the rest).
    extraction : ``"mode"``, ``"barycentric"`` or ``"path"`` (eq. 4.7, seeded with the first
        landmark); refine : ``"zoomout"`` (spectral upsampling over ``zoomout_range =
        (k_start, k_end, step)``, started from the soft map's own functional map),
        ``"sinkhorn"`` (doubly-stochastic projection of the rows before extraction),
        ``"sinkhorn+zoomout"`` or ``"none"``
        (:func:`~solvers.softmaps.extraction.extract_correspondence`).
    max_bytes : refuse (``InputError`` on ``samples``) a problem whose estimated peak memory
        exceeds this.

    Returns
    -------
    SoftMapResult (iterations, residual, converged from the propagation).
    """
    import time

    check_mesh_for_soft_map(source, "source")
    check_mesh_for_soft_map(target, "target")
    pairs = check_landmark_pairs(landmarks, source.n, target.n)
    if len(pairs) == 0:
        raise InputError("a soft map by propagation needs at least one landmark pair (a "
                         "fixed node)", field="landmarks")
    samples = check_int(samples, "samples", low=max(2, len(pairs)))
    n_samples = min(samples, source.n)
    if max_bytes is not None and estimated_bytes(n_samples, target.n) > max_bytes:
        raise InputError(f"{n_samples} samples over {target.n} target vertices need about "
                         f"{estimated_bytes(n_samples, target.n) / 2**20:.0f} MiB, more than "
                         f"the {max_bytes / 2**20:.0f} MiB allowed", field="samples")
    tau = check_positive(tau, "tau")
    if gamma is None:
        gamma = default_gamma(n_samples, target)
    gamma = check_positive(gamma, "gamma")
    if norm not in NORMS:
        raise InputError(f"norm must be one of {NORMS}", field="norm")
    if extraction not in EXTRACTIONS:
        raise InputError(f"extraction must be one of {EXTRACTIONS}", field="extraction")
    if refine not in REFINEMENTS:
        raise InputError(f"refine must be one of {REFINEMENTS}", field="refine")
    if top_k is not None:
        top_k = check_int(top_k, "top_k", low=1, high=target.n)
    timings = {}
    t0 = time.perf_counter()
    graph = farthest_point_samples(source, n_samples, pairs[:, 0])
    cells = np.bincount(graph.labels, weights=source.areas, minlength=graph.n)
    timings["sampling"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    if descriptors is None:
        f0, f1 = descriptors_for_pair(source, target, pairs, k=k, n_energies=n_energies,
                                      wks_weight=wks_weight, landmark_weight=landmark_weight,
                                      landmark_route=landmark_route)
    else:
        f0, f1 = descriptors
    cost = compatibility_cost(f0, f1, areas0=source.areas, areas1=target.areas,
                              rows=graph.indices, norm=norm)
    timings["descriptors"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    w = graph.weights
    wu = np.bincount(graph.edges.ravel(), weights=np.repeat(w, 2), minlength=graph.n)
    log_d = cost
    log_d *= -tau / gamma / wu[:, None]  # in place: the cost is not needed any more
    fixed = {}
    for j, (_, y) in enumerate(pairs):
        m = np.zeros(target.n)
        m[y] = 1.0
        fixed[j] = m  # landmark j is sample j (seeds first)
    prop = wasserstein_propagation(target, graph.n, graph.edges, fixed, edge_weights=w,
                                   node_scalings=log_d, gamma=gamma,
                                   substeps=substeps, acceleration=acceleration,
                                   tol=tol, max_iter=max_iter, progress=progress,
                                   should_cancel=should_cancel)
    # Descriptor energy (eq. 4.6) with the normalized cost c = -log_d * gamma * W_u / tau.
    descriptor = -(gamma / tau) * float((cells * wu) @ np.einsum("ij,ji->i", log_d,
                                                                  prop.masses))
    del log_d, cost
    rows = np.ascontiguousarray(prop.masses.T, dtype=np.float32)
    del prop.masses
    timings["propagation"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    extracted = extract_correspondence(source, target, rows, labels=graph.labels,
                                       samples=graph.indices, cell_areas=cells,
                                       edges=graph.edges, fixed=np.arange(len(pairs)),
                                       seed_target=int(pairs[0, 1]),
                                       extraction=extraction, refine=refine,
                                       zoomout_range=zoomout_range)
    sample_corr, corr = extracted.sample_correspondence, extracted.correspondence
    if extracted.sinkhorn is not None:
        extracted.sinkhorn.rows = None  # the projected copy is not kept
    timings["extraction"] = time.perf_counter() - t0
    dirichlet = dirichlet_from_edge_values(prop.edge_values, graph.edges, w, graph.n, cells)

    top_idx = top_m = dropped = None
    dense = rows
    if top_k is not None:
        top_idx = np.argpartition(-rows, top_k - 1, axis=1)[:, :top_k]
        top_m = np.take_along_axis(rows, top_idx, axis=1)
        dropped = np.maximum(1.0 - top_m.sum(axis=1, dtype=np.float64), 0.0)
        dense = None
    return SoftMapResult(
        iterations=prop.iterations, residual=prop.residual, converged=prop.converged,
        samples=graph.indices, labels=graph.labels, cell_areas=cells, edges=graph.edges,
        edge_weights=w, soft_map=dense, top_indices=top_idx, top_masses=top_m,
        dropped_mass=dropped, correspondence=corr, sample_correspondence=sample_corr,
        dirichlet=dirichlet, descriptor_energy=descriptor, gamma=gamma, tau=tau,
        timings=timings, n_target=target.n, sinkhorn=extracted.sinkhorn)
