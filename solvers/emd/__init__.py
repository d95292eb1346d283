"""Earth mover's distances on surfaces (thesis ch. 2).

* :func:`earth_movers_distance` — W1 between distributions (Beckmann problem, ADMM /
  Weiszfeld over the curl, spectral or unrestricted flow space), with flows, dual
  potentials and anisotropic costs.
* :func:`pointwise_distances` — ``d_W^k`` from one source to every vertex (§2.5);
  :func:`dwk_matrix` — ``d_W^k`` between every pair of a collection of distributions, each
  embedded once (§2.5, eq. 2.4), with certified gaps.
* :func:`distance_to_features` — geodesic-like distance to points/curves (§2.7).
* :func:`beckmann_w1_exact` — the Beckmann problem (eq. 2.1) solved exactly as an SOCP;
  on the same program :func:`w1_barycenter` (eq. 2.7, squared W1), :func:`w1_median`
  (unsquared) and :func:`w1_multistep_paths` (a multi-step chain with capacities).
* :func:`w1_path_planning` — path planning to a set of exits (eq. 2.6), with the Hodge
  decomposition of its flow (:func:`hodge_decomposition`); :func:`fuzzy_geodesic` —
  ``‖J‖`` of the W1 flow between two bumps (Fig. 2.13).
* :mod:`solvers.emd.volumetric` — mean value coordinates, volumetric distances and descent
  paths (§2.6).

Thesis section → module: §2.2–2.4 ``operators``, ``bases``, ``harmonic``, ``beckmann``;
§2.5 ``pointwise``, ``green``, ``dwk``, ``dwk_matrix``; §2.6 ``volumetric``; §2.7
``features``, ``anisotropy``, ``exact`` (barycenters, eq. 2.7), ``path_planning`` (eq. 2.6),
``hodge``, ``fuzzy``.
"""

from solvers.emd.beckmann import EMDResult, earth_movers_distance
from solvers.emd.dwk_matrix import DwkMatrixResult, dwk_matrix
from solvers.emd.exact import (
    BeckmannResult,
    W1BarycenterResult,
    W1MultistepResult,
    beckmann_w1_exact,
    kantorovich_rubinstein_norm,
    w1_barycenter,
    w1_median,
    w1_multistep_paths,
)
from solvers.emd.features import FeatureDistanceResult, distance_to_features
from solvers.emd.fuzzy import FuzzyGeodesicResult, fuzzy_geodesic
from solvers.emd.hodge import HodgeDecomposition, hodge_decomposition
from solvers.emd.operators import EMDOperators, mesh_operators
from solvers.emd.path_planning import PathPlanningResult, w1_path_planning
from solvers.emd.pointwise import PointwiseDistanceResult, pointwise_distances
from solvers.emd.volumetric import (
    VolumetricDistanceResult,
    VolumetricFieldResult,
    VolumetricPathResult,
    mean_value_coordinates,
    volumetric_distance,
    volumetric_distances,
    volumetric_path,
    winding_number,
)

__all__ = [
    "BeckmannResult",
    "DwkMatrixResult",
    "EMDOperators",
    "EMDResult",
    "FeatureDistanceResult",
    "FuzzyGeodesicResult",
    "PointwiseDistanceResult",
    "VolumetricDistanceResult",
    "VolumetricFieldResult",
    "VolumetricPathResult",
    "W1BarycenterResult",
    "HodgeDecomposition",
    "PathPlanningResult",
    "W1MultistepResult",
    "beckmann_w1_exact",
    "distance_to_features",
    "dwk_matrix",
    "earth_movers_distance",
    "fuzzy_geodesic",
    "hodge_decomposition",
    "kantorovich_rubinstein_norm",
    "mean_value_coordinates",
    "mesh_operators",
    "pointwise_distances",
    "volumetric_distance",
    "volumetric_distances",
    "volumetric_path",
    "w1_barycenter",
    "w1_median",
    "w1_multistep_paths",
    "w1_path_planning",
    "winding_number",
]
