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

from solvers.domains.base import CAPABILITIES, Domain, ExportGeometry
from solvers.domains.graph import Graph
from solvers.domains.grid import Grid
from solvers.domains.maze import Maze, maze_mesh
from solvers.domains.mesh import MESH_FORMATS, MeshDiagnostics, TriangleMesh
from solvers.domains.pointcloud import PointCloud
from solvers.errors import DomainError

DOMAIN_CLASSES: dict[str, type[Domain]] = {"mesh": TriangleMesh, "grid": Grid, "graph": Graph,
                                           "pointcloud": PointCloud}
DOMAIN_KINDS = tuple(DOMAIN_CLASSES)


def domain_class(kind: str) -> type[Domain]:
    """The domain class of ``kind`` (one of :data:`DOMAIN_KINDS`).

    Parameters
    ----------
    kind : str
        ``"mesh"``, ``"grid"``, ``"graph"`` or ``"pointcloud"``.

    Returns
    -------
    type
        A subclass of :class:`Domain`.

    Raises
    ------
    DomainError
        An unknown kind.
    """
    try:
        return DOMAIN_CLASSES[kind]
    except KeyError:
        raise DomainError(f"unknown domain kind {kind!r}; expected one of {DOMAIN_KINDS}",
                          field="kind") from None


def supports(domain, capability: str) -> bool:
    """Whether ``domain`` has ``capability`` (a key of :data:`CAPABILITIES`): a domain, a
    light representation of one with a ``supports`` method (a sketch, a service's view), or
    any other object (False: not a domain).

    Parameters
    ----------
    domain : Domain or object
        What to ask.
    capability : str
        What an operation needs, e.g. ``"faces"``.

    Returns
    -------
    bool
    """
    ask = getattr(domain, "supports", None)
    return bool(ask(capability)) if callable(ask) else False


def kind_supports(kind: str, capability: str) -> bool:
    """Whether domains of ``kind`` have ``capability`` (False for an unknown kind): what a
    light representation that holds only the kind answers.

    Parameters
    ----------
    kind : str
        A domain kind.
    capability : str
        A key of :data:`~solvers.domains.base.CAPABILITIES`.

    Returns
    -------
    bool
    """
    cls = DOMAIN_CLASSES.get(kind)
    return cls is not None and cls.supports(capability)


def kinds_supporting(capability: str) -> tuple[str, ...]:
    """The kinds (in :data:`DOMAIN_KINDS` order) whose domains have ``capability``.

    Parameters
    ----------
    capability : str
        A key of :data:`~solvers.domains.base.CAPABILITIES`.

    Returns
    -------
    tuple of str
    """
    return tuple(kind for kind, cls in DOMAIN_CLASSES.items() if cls.supports(capability))


def load_mesh(source, file_type: str | None = None, **kwargs) -> TriangleMesh:
    """Load a triangle mesh file (OBJ, PLY, STL, OFF, GLB/glTF).

    See :meth:`TriangleMesh.from_file`.

    Parameters
    ----------
    source, file_type
        The file and its format, as in :meth:`TriangleMesh.from_file`.
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
    "CAPABILITIES",
    "DOMAIN_CLASSES",
    "DOMAIN_KINDS",
    "MESH_FORMATS",
    "Domain",
    "ExportGeometry",
    "Graph",
    "Grid",
    "Maze",
    "MeshDiagnostics",
    "PointCloud",
    "TriangleMesh",
    "domain_class",
    "domain_from_arrays",
    "kind_supports",
    "kinds_supporting",
    "load_mesh",
    "maze_mesh",
    "supports",
]
