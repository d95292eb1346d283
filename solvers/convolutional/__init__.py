"""Convolutional Wasserstein toolkit (thesis ch. 3) over the heat kernels of any domain.

- :func:`wasserstein_distance` — Alg. 1 / eq. 3.10, optional debiased Sinkhorn divergence;
  ``method="auto"`` solves sparse supports exactly
  (:func:`~solvers.transport.exact_wasserstein_distance`: geodesic costs between the support
  points and the transport LP, decided by :func:`~solvers.transport.decide_distance`);
- :func:`distance_matrix` — every pair of a collection (or against templates), W2 pairs
  sharing a kernel advanced as one multi-column block, exact pairs on one cost matrix;
- :func:`barycenter` — eq. 3.13 / Alg. 2, entropic sharpening (Alg. 3), debiased option;
  :func:`barycenters` — many weight vectors over the same inputs as one block;
- :func:`displacement_interpolation` — eq. 3.16, barycenters of two inputs;
- :func:`wasserstein_propagation` — Alg. 4 / eq. 3.17, per-edge rescaled kernels (eq. 3.18);
- :func:`shape_interpolation` — §3.7, barycenters of voxelized shapes, marching cubes;
- :mod:`~solvers.convolutional.brdf` on the :mod:`~solvers.convolutional.hemisphere` domain —
  §3.7 BRDF interpolation (Fig. 3.11); :mod:`~solvers.convolutional.skeleton` — §3.7
  skeleton layout by Wasserstein propagation (Fig. 3.13).

Thesis section → module: §3.3–3.5 ``distance`` (Alg. 1), ``common`` (log-domain kernel
application, over-relaxation); §3.6 ``barycenter`` (Alg. 2, 3), ``interpolation``;
§3.6.3 ``propagation`` (Alg. 4); §3.7 ``shapes``, ``hemisphere`` + ``brdf``, ``skeleton``;
``matrix`` the distance matrices. The exact LP method for sparse supports (ground truth and
default for few support points) and the default decision are in :mod:`solvers.transport`.

All iterations run on log-scalings (stable at small ``gamma``), stop on a measured
marginal violation, and report ``iterations``, ``residual`` and ``converged``.
"""

from solvers.convolutional.barycenter import (
    BarycenterResult,
    BarycentersResult,
    barycenter,
    barycenters,
)
from solvers.convolutional.distance import SinkhornResult, wasserstein_distance
from solvers.convolutional.interpolation import InterpolationResult, displacement_interpolation
from solvers.convolutional.matrix import DistanceMatrixResult, distance_matrix
from solvers.convolutional.propagation import PropagationResult, wasserstein_propagation
from solvers.convolutional.shapes import ShapeResult, iso_surface, shape_interpolation, voxelize

__all__ = [
    "BarycenterResult",
    "BarycentersResult",
    "DistanceMatrixResult",
    "InterpolationResult",
    "PropagationResult",
    "ShapeResult",
    "SinkhornResult",
    "barycenter",
    "barycenters",
    "displacement_interpolation",
    "distance_matrix",
    "iso_surface",
    "shape_interpolation",
    "voxelize",
    "wasserstein_distance",
    "wasserstein_propagation",
]
