"""otgeo numerical library: optimal transport on meshes, grids, graphs and point clouds.

Plain functions over numpy arrays and domain objects; no web imports. The packages follow
J. Solomon's thesis *Transportation Techniques for Geometric Data Processing* (2015):

========================  =====================================================
``solvers.domains``       §2.2, §3.4: meshes, grids, graphs, point clouds; their operators,
                          kept in one store per domain (``domain.operators``)
``solvers.kernels``,      §3.5: heat kernels applied to n×k blocks; sparse Cholesky
``solvers.linalg``
``solvers.validation``    the one set of input validators (library and service)
``solvers.monitor``       progress, cancellation, stagnation; the result base
``solvers.emd``           ch. 2: earth mover's distances (Beckmann W1, d_W^k, features,
                          volumetric distances, exact SOCP, W1 barycenters and paths)
``solvers.convolutional`` ch. 3: convolutional Wasserstein distances, barycenters,
                          interpolation, propagation (Alg. 1–4), shape interpolation
``solvers.transport``     the exact W2 LP between sparse supports and the default
                          decision between it and the convolutional method
``solvers.softmaps``      ch. 4 and §3.7: soft maps between surfaces
``solvers.histograms``    ch. 5: Wasserstein propagation of histograms on graphs
``solvers.color``         §3.7: color transfer over chrominance histograms
``solvers.regularization`` the default choice of gamma, t and substeps
``solvers.geodesics``     exact polyhedral geodesics (ground truth for tests, exact routes)
========================  =====================================================
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
