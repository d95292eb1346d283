r"""Soft maps between surfaces (thesis ch. 4 and §3.7).

========================================  ===============================================
thesis                                    module
========================================  ===============================================
§4.5.2, §3.7 descriptors (HKS, WKS,        :mod:`~solvers.softmaps.descriptors`
landmark distances)
compatibility cost :math:`c(x, y)`         :mod:`~solvers.softmaps.compatibility`
§4.5.2 descriptor soft map                 :mod:`~solvers.softmaps.descriptor_map`
source graph: samples, weights             :mod:`~solvers.softmaps.sampling`
coarse target and prolongation             :mod:`~solvers.softmaps.coarse_target`
§3.7 eq. 3.17-3.18 soft map by             :mod:`~solvers.softmaps.propagation_map`
Wasserstein propagation
eq. 4.1-4.6 Dirichlet, potential,          :mod:`~solvers.softmaps.energies`
momentum, bijectivity, descriptor energy
§4.5.1 mode, barycentric, path tracing     :mod:`~solvers.softmaps.extraction`
(eq. 4.7); ZoomOut, Sinkhorn refinements
§4.6 SVD bases, low rank, collections      :mod:`~solvers.softmaps.analysis`
pull-back of functions / colors            :mod:`~solvers.softmaps.transfer`
========================================  ===============================================
"""

from solvers.softmaps.analysis import (
    SoftMapBasis,
    collection_basis,
    low_rank_approximation,
    soft_map_svd,
)
from solvers.softmaps.compatibility import compatibility_cost
from solvers.softmaps.descriptor_map import descriptor_soft_map
from solvers.softmaps.descriptors import (
    eigenpairs,
    heat_kernel_signature,
    landmark_descriptors,
    wave_kernel_signature,
)
from solvers.softmaps.energies import (
    bijectivity_density,
    bijectivity_energy,
    descriptor_energy,
    dirichlet_energy,
    momentum,
    soft_map_energies,
    transportation_potential,
)
from solvers.softmaps.extraction import (
    barycentric_projection,
    extract_correspondence,
    mode,
    sinkhorn_projection,
    trace_path,
    zoomout,
)
from solvers.softmaps.propagation_map import SoftMapResult, descriptors_for_pair, soft_map
from solvers.softmaps.sampling import SourceSamples, farthest_point_samples
from solvers.softmaps.transfer import pull_back

__all__ = [
    "SoftMapBasis", "SoftMapResult", "SourceSamples", "barycentric_projection",
    "bijectivity_density", "bijectivity_energy", "collection_basis", "compatibility_cost",
    "descriptor_energy", "descriptor_soft_map", "descriptors_for_pair", "dirichlet_energy",
    "eigenpairs", "extract_correspondence", "farthest_point_samples", "heat_kernel_signature",
    "landmark_descriptors", "low_rank_approximation", "mode", "momentum", "pull_back",
    "sinkhorn_projection", "soft_map", "soft_map_energies", "soft_map_svd", "trace_path",
    "transportation_potential", "wave_kernel_signature", "zoomout",
]
