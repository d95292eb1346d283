"""Earth mover's distances on surfaces (thesis ch. 2).

* :func:`earth_movers_distance` — W1 between distributions (Beckmann problem, ADMM /
  Weiszfeld over the curl, spectral or unrestricted flow space), with flows, dual
  potentials and anisotropic costs.
* :func:`pointwise_distances` — ``d_W^k`` from one source to every vertex (§2.5).
* :func:`distance_to_features` — geodesic-like distance to points/curves (§2.7).
* :func:`beckmann_w1_exact` — the Beckmann problem (eq. 2.1) solved exactly as an SOCP;
  on the same program :func:`w1_barycenter` (eq. 2.7, squared W1), :func:`w1_median`
  (unsquared) and :func:`w1_path_planning` (a multi-step chain with capacities).
* :mod:`solvers.emd.volumetric` — mean value coordinates, volumetric distances and descent
  paths (§2.6).

Thesis section → module: §2.2–2.4 ``operators``, ``bases``, ``harmonic``, ``beckmann``;
§2.5 ``pointwise``, ``green``; §2.6 ``volumetric``, ``exact`` (barycenters); §2.7
``features``, ``exact`` (paths).
"""

from solvers.emd.beckmann import EMDResult, earth_movers_distance
from solvers.emd.exact import (
    BeckmannResult,
    W1BarycenterResult,
    W1PathResult,
    beckmann_w1_exact,
    kantorovich_rubinstein_norm,
    w1_barycenter,
    w1_median,
    w1_path_planning,
)
from solvers.emd.features import FeatureDistanceResult, distance_to_features
from solvers.emd.operators import EMDOperators, mesh_operators
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
    "EMDOperators",
    "EMDResult",
    "FeatureDistanceResult",
    "PointwiseDistanceResult",
    "VolumetricDistanceResult",
    "VolumetricFieldResult",
    "VolumetricPathResult",
    "W1BarycenterResult",
    "W1PathResult",
    "beckmann_w1_exact",
    "distance_to_features",
    "earth_movers_distance",
    "kantorovich_rubinstein_norm",
    "mean_value_coordinates",
    "mesh_operators",
    "pointwise_distances",
    "volumetric_distance",
    "volumetric_distances",
    "volumetric_path",
    "w1_barycenter",
    "w1_median",
    "w1_path_planning",
    "winding_number",
]
