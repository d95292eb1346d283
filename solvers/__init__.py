"""otgeo numerical library: optimal transport on meshes, grids, graphs and point clouds.

Plain functions over numpy arrays and domain objects; no web imports.
"""

from solvers.domains import Graph, Grid, PointCloud, TriangleMesh, load_mesh
from solvers.errors import (
    ConvergenceError,
    DomainError,
    InputError,
    MeshFormatError,
    OTGeoError,
)

__all__ = [
    "ConvergenceError",
    "DomainError",
    "Graph",
    "Grid",
    "InputError",
    "MeshFormatError",
    "OTGeoError",
    "PointCloud",
    "TriangleMesh",
    "load_mesh",
]
