"""Convolutional Wasserstein toolkit (thesis ch. 3) over the heat kernels of any domain.

- :func:`wasserstein_distance` — Alg. 1 / eq. 3.10, optional debiased Sinkhorn divergence;
- :func:`barycenter` — eq. 3.13 / Alg. 2, entropic sharpening (Alg. 3), debiased option;
- :func:`displacement_interpolation` — eq. 3.16, barycenters of two inputs;
- :func:`wasserstein_propagation` — Alg. 4 / eq. 3.17, per-edge rescaled kernels (eq. 3.18);
- :func:`shape_interpolation` — §3.7, barycenters of voxelized shapes, marching cubes.

All iterations run on log-scalings (stable at small ``gamma``), stop on a measured
marginal violation, and report ``iterations``, ``residual`` and ``converged``.
"""

from solvers.convolutional.barycenter import BarycenterResult, barycenter
from solvers.convolutional.distance import SinkhornResult, wasserstein_distance
from solvers.convolutional.interpolation import InterpolationResult, displacement_interpolation
from solvers.convolutional.propagation import PropagationResult, wasserstein_propagation
from solvers.convolutional.shapes import ShapeResult, iso_surface, shape_interpolation, voxelize

__all__ = [
    "BarycenterResult",
    "InterpolationResult",
    "PropagationResult",
    "ShapeResult",
    "SinkhornResult",
    "barycenter",
    "displacement_interpolation",
    "iso_surface",
    "shape_interpolation",
    "voxelize",
    "wasserstein_distance",
    "wasserstein_propagation",
]
