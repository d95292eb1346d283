"""Earth mover's distances on surfaces (thesis ch. 2).

* :func:`earth_movers_distance` — W1 between distributions (Beckmann problem, ADMM /
  Weiszfeld over the curl, spectral or unrestricted flow space), with flows, dual
  potentials and anisotropic costs.
* :func:`pointwise_distances` — ``d_W^k`` from one source to every vertex (§2.5).
* :func:`distance_to_features` — geodesic-like distance to points/curves (§2.7).
"""

from solvers.emd.beckmann import EMDResult, earth_movers_distance
from solvers.emd.features import FeatureDistanceResult, distance_to_features
from solvers.emd.operators import EMDOperators, mesh_operators
from solvers.emd.pointwise import PointwiseDistanceResult, pointwise_distances

__all__ = [
    "EMDOperators",
    "EMDResult",
    "FeatureDistanceResult",
    "PointwiseDistanceResult",
    "distance_to_features",
    "earth_movers_distance",
    "mesh_operators",
    "pointwise_distances",
]
