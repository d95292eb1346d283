"""The transport problem itself, outside the entropic chapter: the exact LP and the default
decision between it and the convolutional method (issue 41, item 5).

- :func:`exact_wasserstein_distance` (:mod:`~solvers.transport.exact`) — exact W2² between
  sparse supports (thesis eq. 1.1): exact geodesic costs between the support points, as far
  as the optimal plan needs them, and the network-simplex LP; with its time model
  (:func:`~solvers.transport.exact.exact_route_estimate`);
- :func:`decide_distance` (:mod:`~solvers.transport.decision`) — what
  ``wasserstein_distance(domain, mu0, mu1)`` runs by default (method and regularization),
  a pure function of the masses and the stored domain, taken the same in the library, the
  API process and any worker.

The entropic (convolutional) solvers are in :mod:`solvers.convolutional`, which uses both;
nothing here imports it.
"""

from solvers.transport.decision import DistanceDecision, decide_distance
from solvers.transport.exact import ExactTransportResult, exact_wasserstein_distance

__all__ = [
    "DistanceDecision",
    "ExactTransportResult",
    "decide_distance",
    "exact_wasserstein_distance",
]
