r"""Soft maps of user-given point maps and their analysis (thesis ch. 4, §4.6).

A point map :math:`T: M_0 \to M` (a target vertex per source vertex) becomes a soft map by
blurring: on the source graph of ``N`` farthest-point samples (all vertices when ``N`` is at
least their number; :mod:`solvers.softmaps.sampling`) the node ``u`` carries the heat
diffusion of a unit mass at :math:`T(x_u)`,

.. math:: \mu_u = a \odot H_t\,(\delta_{T(x_u)} / a_{T(x_u)}), \qquad t = \gamma / 4,

(:func:`solvers.kernels.heat_time`: the Gibbs kernel :math:`e^{-d^2/\gamma}`), the soft
map whose plans the entropic solvers at :math:`\gamma` would see.  Its energies are those of
:mod:`solvers.softmaps.energies` (Dirichlet eq. 4.2, bijectivity eq. 4.5, descriptor
eq. 4.6 with WKS descriptors) and its bases those of :mod:`solvers.softmaps.analysis`
(§4.6.1 SVD, §4.6.2 collections).

For the identity map of a mesh onto itself with every vertex a sample, the weighted kernel
is :math:`(I + \tau D_a^{-1/2} L D_a^{-1/2})^{-s}` (``s`` implicit Euler substeps of
:math:`\tau = t/s`): the singular values are :math:`(1 + \tau\lambda_i)^{-s}` with
:math:`\lambda_i` the Laplace–Beltrami eigenvalues and the bases its eigenfunctions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.errors import InputError
from solvers.kernels import heat_time
from solvers.softmaps.analysis import SoftMapBasis, collection_basis, soft_map_svd
from solvers.softmaps.compatibility import compatibility_cost
from solvers.softmaps.energies import (
    DIRICHLET_METHODS,
    DirichletEnergy,
    bijectivity_density,
    descriptor_energy,
    dirichlet_energy,
)
from solvers.softmaps.propagation_map import (
    check_mesh_for_soft_map,
    default_gamma,
    descriptors_for_pair,
)
from solvers.softmaps.sampling import SourceSamples, farthest_point_samples
from solvers.validation import check_indices, check_int, check_positive


@dataclass
class PointSoftMap:
    """``rows`` ``(N, n_target)`` target masses per sample (rows sum to 1); ``samples`` the
    source graph; ``cell_areas`` ``(N,)`` source area per sample (sum 1); ``targets``
    ``(N,)`` the target vertex each sample's mass is centred on; ``gamma``, ``substeps``."""

    rows: np.ndarray
    samples: SourceSamples
    cell_areas: np.ndarray
    targets: np.ndarray
    gamma: float
    substeps: int


def check_point_map(correspondence, n_source: int, n_target: int,
                    field: str = "correspondence") -> np.ndarray:
    """``(n_source,)`` int64 target vertices, one per source vertex."""
    T = check_indices(correspondence, n_target, field=field)
    if len(T) != n_source:
        raise InputError(f"{field} has {len(T)} entries; the source has {n_source} vertices "
                         "(one target vertex per source vertex)", field=field)
    return T


def point_map_soft_map(source, target, correspondence, *, samples: int = 256,
                       gamma: float | None = None, substeps: int = 1) -> PointSoftMap:
    """The blurred soft map of a point map (module docstring).

    ``samples``: source graph nodes (farthest-point samples; at least the number of source
    vertices: every vertex with the mesh edges); ``gamma``: blur (default
    :func:`~solvers.softmaps.propagation_map.default_gamma`, twice the squared sample
    spacing and at least ``4 h^2``); ``substeps``: implicit Euler steps of the heat kernel.
    """
    check_mesh_for_soft_map(source, "source")
    check_mesh_for_soft_map(target, "target")
    T = check_point_map(correspondence, source.n, target.n)
    graph = farthest_point_samples(source, samples)
    gamma = default_gamma(graph.n, target) if gamma is None else check_positive(gamma, "gamma")
    substeps = check_int(substeps, "substeps", low=1)
    y = T[graph.indices]
    deltas = np.zeros((target.n, graph.n))
    deltas[y, np.arange(graph.n)] = 1.0 / target.areas[y]
    density = target.heat_kernel(heat_time(gamma), substeps).apply(deltas)
    rows = np.maximum(density * target.areas[:, None], 0.0).T
    rows /= rows.sum(axis=1, keepdims=True)
    cells = np.bincount(graph.labels, weights=source.areas, minlength=graph.n)
    return PointSoftMap(rows=rows, samples=graph, cell_areas=cells / cells.sum(), targets=y,
                        gamma=float(gamma), substeps=substeps)


@dataclass
class PointMapAnalysis:
    """Energies and bases of one point map's soft map.

    ``dirichlet`` (eq. 4.2, per edge and per sample; ``None`` when not asked),
    ``bijectivity`` :math:`E_B` and ``bijectivity_density`` :math:`b` per target vertex
    (eq. 4.5), ``descriptor`` (eq. 4.6, WKS cost of mean 1; ``None`` when not asked),
    ``basis`` the §4.6.1 SVD bases of rank ``rank`` (source side per sample),
    ``singular_values`` all of them (the constant pair's 1 first) and ``low_rank_error``
    the relative weighted Frobenius error of the rank-``rank`` map."""

    soft_map: PointSoftMap
    dirichlet: DirichletEnergy | None
    bijectivity: float
    bijectivity_density: np.ndarray
    descriptor: float | None
    basis: SoftMapBasis
    singular_values: np.ndarray
    low_rank_error: float


def _descriptor_energy(source, target, sm: PointSoftMap, k: int, n_energies: int,
                       norm: str) -> float:
    f0, f1 = descriptors_for_pair(source, target, np.zeros((0, 2), np.int64), k=k,
                                  n_energies=n_energies, landmark_weight=0.0)
    cost = compatibility_cost(f0, f1, areas0=source.areas, areas1=target.areas,
                              rows=sm.samples.indices, norm=norm)
    return descriptor_energy(sm.rows, cost, sm.cell_areas)


def analyze_point_map(source, target, correspondence, *, samples: int = 256,
                      gamma: float | None = None, substeps: int = 1, rank: int = 10,
                      dirichlet_method: str = "w2", descriptor_k: int | None = 50,
                      n_energies: int = 100, norm: str = "l1") -> PointMapAnalysis:
    """Soft map of a point map (:func:`point_map_soft_map`), its energies and SVD bases.

    ``dirichlet_method``: ``"w2"`` (convolutional :math:`W_2^2` per source edge at
    ``gamma``, debiased), ``"potential"`` (eq. 4.3) or ``None`` (not computed);
    ``descriptor_k``: eigenpairs of the WKS descriptors (``None``: no descriptor energy);
    ``rank``: basis functions kept (the constant first).
    """
    if dirichlet_method is not None and dirichlet_method not in DIRICHLET_METHODS:
        raise InputError(f"dirichlet_method must be one of {DIRICHLET_METHODS}",
                         field="dirichlet_method")
    sm = point_map_soft_map(source, target, correspondence, samples=samples, gamma=gamma,
                            substeps=substeps)
    full = soft_map_svd(sm.rows, sm.cell_areas, target.areas)
    rank = check_int(rank, "rank", low=1, high=len(full.singular_values))
    s = full.singular_values
    error = float(np.sqrt(np.sum(s[rank:] ** 2) / np.sum(s**2)))
    basis = SoftMapBasis(full.source_basis[:, :rank], s[:rank], full.target_basis[:, :rank],
                         full.source_areas, full.target_areas)
    g = sm.samples
    dirichlet = None if dirichlet_method is None else dirichlet_energy(
        target, sm.rows, g.edges, g.weights, cell_areas=sm.cell_areas, method=dirichlet_method,
        gamma=sm.gamma, substeps=sm.substeps)
    b = bijectivity_density(target, sm.rows, sm.cell_areas)
    descriptor = None if descriptor_k is None else _descriptor_energy(
        source, target, sm, descriptor_k, n_energies, norm)
    return PointMapAnalysis(soft_map=sm, dirichlet=dirichlet,
                            bijectivity=float(target.areas @ b**2), bijectivity_density=b,
                            descriptor=descriptor, basis=basis, singular_values=s,
                            low_rank_error=error)


def point_maps_collection_basis(target, analyses, rank: int) -> np.ndarray:
    """§4.6.2: one ``(n_target, rank)`` basis (area-orthonormal, constant first) shared by
    the soft maps of several point maps into ``target``
    (:func:`solvers.softmaps.analysis.collection_basis`)."""
    return collection_basis([a.soft_map.rows for a in analyses],
                            [a.soft_map.cell_areas for a in analyses], target.areas, rank)


def captured_energy(soft_map: PointSoftMap, target_areas, basis: np.ndarray) -> float:
    r"""Fraction of a soft map's de-meaned weighted kernel (§4.6:
    :math:`\tilde P - \sqrt{a_0}\sqrt{a}^\top`, Frobenius norm) in the span of the non-constant
    columns of a target ``basis`` ``(n, r)`` (constant first): 1 when the basis holds the whole
    map, and by Eckart–Young at most the map's own rank-``r`` SVD basis's share."""
    a = np.asarray(target_areas, np.float64) / np.sum(target_areas)
    a0 = soft_map.cell_areas
    K = np.sqrt(a0)[:, None] * (soft_map.rows / a[None, :]) * np.sqrt(a)[None, :] \
        - np.outer(np.sqrt(a0), np.sqrt(a))
    total = float(np.linalg.norm(K) ** 2)
    if basis.shape[1] < 2 or total <= 0:
        return 0.0 if total > 0 else 1.0
    q = np.linalg.qr(np.sqrt(a)[:, None] * np.asarray(basis, np.float64)[:, 1:])[0]
    return float(np.linalg.norm(K @ q) ** 2 / total)
