"""Domains own their geometry, area weights, Laplacians and prefactored heat kernels.

* :class:`TriangleMesh` (§2.2: cotangent / intrinsic-Delaunay Laplacian, lumped areas,
  per-face gradient and divergence), :class:`Grid` (§3.4: separable Gaussian kernels),
  :class:`Graph`, :class:`PointCloud` — each in its own module;
* ``maze`` — :func:`maze_mesh`, planar maze meshes for path planning (Fig. 2.12);
* ``operators`` — :class:`~solvers.domains.operators.OperatorStore`, the one explicit
  store of every prefactored operator a domain owns (built once under a lock, sized).
"""

from __future__ import annotations

import numpy as np

from solvers.domains.base import Domain
from solvers.domains.graph import Graph
from solvers.domains.grid import Grid
from solvers.domains.maze import Maze, maze_mesh
from solvers.domains.mesh import MESH_FORMATS, MeshDiagnostics, TriangleMesh
from solvers.domains.pointcloud import PointCloud
from solvers.errors import DomainError

DOMAIN_CLASSES: dict[str, type[Domain]] = {"mesh": TriangleMesh, "grid": Grid, "graph": Graph,
                                           "pointcloud": PointCloud}
DOMAIN_KINDS = tuple(DOMAIN_CLASSES)


def load_mesh(source, file_type: str | None = None, **kwargs) -> TriangleMesh:
    """Load a triangle mesh file (OBJ, PLY, STL, OFF, GLB/glTF).

    See :meth:`TriangleMesh.from_file`.

    Parameters
    ----------
    source : str, path, bytes or binary file
        The mesh file.
    file_type : str, optional
        One of ``MESH_FORMATS`` (default: the path's extension; needed for bytes).
    **kwargs
        Keywords of :meth:`TriangleMesh.from_file`.

    Returns
    -------
    TriangleMesh
    """
    return TriangleMesh.from_file(source, file_type=file_type, **kwargs)


def domain_from_arrays(kind: str, arrays: dict[str, np.ndarray], parameters: dict | None = None
                       ) -> Domain:
    """Rebuild a domain from ``Domain.to_arrays()`` and ``Domain.parameters()``.

    Parameters
    ----------
    kind : {"mesh", "grid", "graph", "pointcloud"}
        The domain's kind.
    arrays : dict of str to array
        ``Domain.to_arrays()``.
    parameters : dict, optional
        ``Domain.parameters()``.

    Returns
    -------
    Domain
    """
    parameters = parameters or {}
    if kind == "mesh":
        return TriangleMesh(arrays["vertices"], arrays["faces"], **parameters)
    if kind == "grid":
        return Grid(arrays["shape"].tolist(), arrays["bounds"], arrays["periodic"].tolist())
    if kind == "graph":
        return Graph(int(arrays["n_nodes"][0]), arrays["edges"], arrays["weights"],
                     arrays.get("positions"))
    if kind == "pointcloud":
        return PointCloud(arrays["points"], **parameters)
    raise DomainError(f"unknown domain kind {kind!r}; expected one of {DOMAIN_KINDS}",
                      field="kind")


__all__ = [
    "DOMAIN_CLASSES",
    "DOMAIN_KINDS",
    "MESH_FORMATS",
    "Domain",
    "Graph",
    "Grid",
    "Maze",
    "MeshDiagnostics",
    "PointCloud",
    "TriangleMesh",
    "domain_from_arrays",
    "load_mesh",
    "maze_mesh",
]
