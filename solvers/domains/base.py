"""What every domain (mesh, grid, graph, point cloud) provides."""

from __future__ import annotations

import contextlib
import hashlib
import json
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from solvers.domains.operators import OperatorStore, nbytes_of
from solvers.errors import DomainError, InputError
from solvers.kernels import HeatKernel
from solvers.linalg import Backend
from solvers.validation import check_component_masses


def check_laplacian_name(laplacian: str) -> None:
    """Refuse a ``laplacian`` that is not one of :data:`LAPLACIAN_NAMES`."""
    if laplacian not in LAPLACIAN_NAMES:
        raise InputError(f"laplacian must be 'auto', 'robust' or 'cotan', got {laplacian!r}",
                         field="laplacian")


@contextlib.contextmanager
def domain_input():
    """Re-raise the shared validators' ``InputError`` as ``DomainError`` (same message and
    field) while a domain checks its construction arguments."""
    try:
        yield
    except DomainError:
        raise
    except InputError as exc:
        raise DomainError(exc.message, field=exc.field) from exc


def points_extent(points) -> float:
    """Bounding-box diagonal of ``(n, d)`` points (1.0 without points or for one point)."""
    if points is None or len(points) == 0:
        return 1.0
    pts = np.asarray(points, dtype=np.float64)
    diag = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
    return diag if np.isfinite(diag) and diag > 0 else 1.0


def squared_straight_distances(points, src, dst, periods=None) -> np.ndarray:
    """``(len(src), len(dst))`` squared Euclidean distances between ``points[src]`` and
    ``points[dst]``; an axis with a period (``periods[axis] > 0``) wraps (nearest image)."""
    pts = np.asarray(points, dtype=np.float64)
    diff = pts[src][:, None, :] - pts[dst][None, :, :]
    for ax, width in enumerate(() if periods is None else periods):
        if width > 0:
            diff[..., ax] -= width * np.round(diff[..., ax] / width)
    return np.einsum("ijk,ijk->ij", diff, diff)


def squared_straight_distance_bytes(n: int, entries: int, dim: int) -> int:
    """Bytes of :func:`squared_straight_distances` giving ``entries`` distances between
    points of an ``n``-point, ``dim``-dimensional domain, at most: the squares, the
    ``(rows, columns, dim)`` coordinate differences they are summed from, and the gathered
    coordinates and indices (``2 dim + 2`` numbers a point)."""
    return 8 * (dim + 1) * entries + 8 * (2 * dim + 2) * n


# What an operation may need of a domain (``Domain.supports``); each domain class lists the
# ones it has in ``capabilities``.
CAPABILITIES = {
    "faces": "triangle faces: per-face fields and flows, Beckmann W1, soft maps, shape "
             "interpolation, boundaries",
    "exact_transport": "the exact W2 route: ground distances between any two points",
    "geodesic_solves": "the exact route's ground distances are geodesics solved per source "
                       "(MMP), planned and estimated per solve",
    "edge_lengths": "the length scale h is a mean edge length (raised to a floor for values)",
    "exact_heat_kernel": "the heat kernel is an exact (separable) Gaussian: substeps unused, "
                         "no solve time modelled",
    "hop_metric": "distances count edge hops (bumps, extent): no coordinates needed",
    "histogram_propagation": "histogram propagation along the domain's Laplacian (service)",
}
LAPLACIAN_NAMES = ("auto", "robust", "cotan")


@dataclass(frozen=True)
class ExportGeometry:
    """What a glTF export draws of a domain: ``positions`` ``(n, 3)`` (or ``(n, d)``), and
    either triangle ``faces`` or ``edges`` (index pairs), or neither (points).

    Attributes
    ----------
    positions : (n, 3) or (n, d) array
        Point positions.
    faces : (F, 3) int array or None
        Triangles.
    edges : (m, 2) int array or None
        Index pairs.
    """

    positions: np.ndarray
    faces: np.ndarray | None = None
    edges: np.ndarray | None = None


class Domain:
    """A discretized space carrying distributions.

    Subclasses define ``kind``, ``n`` (number of points carrying mass),
    ``areas`` (positive weights summing to 1), ``laplacian`` (sparse PSD weak
    Laplacian, ``L·1 = 0``), ``_build_heat_kernel`` and ``to_arrays``.
    Prefactored operators (heat kernels per ``(t, substeps, backend)``, and whatever the
    solvers derive from the domain) live in one explicit store, ``domain.operators``
    (:class:`~solvers.domains.operators.OperatorStore`): built once under a lock, sized.

    Attributes
    ----------
    kind : str
        ``"mesh"``, ``"grid"``, ``"graph"`` or ``"pointcloud"``.
    n : int
        Points carrying mass.
    areas : (n,) array
        Positive weights summing to 1.
    laplacian : (n, n) sparse matrix
        Weak Laplacian, PSD with ``L·1 = 0``.
    operators : OperatorStore
        The store of prefactored operators.
    artifacts : ArtifactStore or None
        The persistent backing of costly derived arrays (all-pairs geodesics), supplied by
        whoever stores the domain (the service); None: computed and kept per process.
    """

    kind: str = "domain"
    n: int
    areas: np.ndarray
    # what the domain offers (keys of CAPABILITIES); see :meth:`supports`
    capabilities: frozenset[str] = frozenset()
    # graph edges (meshes, graphs) and face count (meshes); None on the others
    edges: np.ndarray | None = None
    n_faces: int | None = None
    # persistent backing of costly derived arrays (operators.ArtifactStore), or None
    artifacts = None

    def __init__(self):
        self.operators = OperatorStore()

    @classmethod
    def supports(cls, capability: str) -> bool:
        """Whether this kind of domain has ``capability`` (a key of :data:`CAPABILITIES`).

        Parameters
        ----------
        capability : str
            What an operation needs, e.g. ``"faces"``.

        Returns
        -------
        bool
        """
        return capability in cls.capabilities

    @property
    def coordinates(self) -> np.ndarray | None:
        """``(n, d)`` coordinates of the mass-carrying points (mesh vertices and point
        clouds at unit area, grid nodes, graph positions), or None (a graph without
        positions)."""
        return None

    @property
    def heat_mass(self) -> np.ndarray:
        """Diagonal of the mass matrix ``M`` of the heat equation ``M du/dt = -L u``: the
        area weights (ones on graphs, whose mass counts nodes)."""
        return np.asarray(self.areas, dtype=np.float64)

    def laplacian_variant(self, laplacian: str = "auto") -> sp.csr_matrix:
        """The Laplacian named ``laplacian`` (``"auto"``: :attr:`laplacian`; ``"robust"`` and
        ``"cotan"`` choose between a triangle mesh's two Laplacians).

        Parameters
        ----------
        laplacian : {"auto", "robust", "cotan"}
            The Laplacian's name.

        Returns
        -------
        (n, n) scipy.sparse.csr_matrix

        Raises
        ------
        InputError
            An unknown name, or a mesh Laplacian asked of another domain.
        """
        check_laplacian_name(laplacian)
        if laplacian != "auto":
            raise InputError(f"laplacian={laplacian!r} applies to triangle meshes only",
                             field="laplacian")
        return sp.csr_matrix(self.laplacian)

    def export_geometry(self) -> ExportGeometry:
        """What a glTF export draws: the points at :attr:`coordinates`.

        Raises
        ------
        UnsupportedDomainError
            The domain has no geometry to draw.
        """
        return ExportGeometry(np.asarray(self.coordinates))

    @classmethod
    def stored_geometry(cls, arrays: dict, summary: dict, points) -> dict:
        """What a viewer draws of a stored domain of this kind, from its stored ``arrays``
        (``to_arrays()``), ``summary`` and unit-area ``points`` (None without): a dict with
        ``points`` and, by kind, ``faces``, ``edges`` or ``shape`` and ``bounds``.

        Parameters
        ----------
        arrays : dict of str to array
            The stored ``to_arrays()``.
        summary : dict
            The stored summary.
        points : (n, d) array or None
            Unit-area positions.

        Returns
        -------
        dict
        """
        return {"points": points}

    @property
    def laplacian(self) -> sp.csr_matrix:  # pragma: no cover - abstract
        raise NotImplementedError

    def heat_kernel(self, t: float, substeps: int = 1, backend: Backend = "auto") -> HeatKernel:
        """The heat kernel at time ``t`` (built and factored once, then cached).

        Parameters
        ----------
        t : float
            Heat time.
        substeps : int
            Implicit Euler steps.
        backend : {"auto", "pardiso", "cholespy", "splu"}
            Sparse factorization backend.
        """
        key = ("heat_kernel", float(t), int(substeps), backend)
        return self.operators.get(
            key, lambda: self._build_heat_kernel(float(t), int(substeps), backend))

    def _build_heat_kernel(self, t: float, substeps: int, backend: Backend) -> HeatKernel:
        raise NotImplementedError  # pragma: no cover

    @property
    def geodesic_kernel_available(self) -> bool:
        """Whether :meth:`geodesic_kernel` is offered (method ``"geodesic"``): the kind's
        rule (:meth:`offers_geodesic_kernel`) on this domain's size and components."""
        return self.offers_geodesic_kernel(self.n, self.n_components)

    @classmethod
    def offers_geodesic_kernel(cls, n: int, n_components: int) -> bool:
        """Whether a domain of this kind with ``n`` points in ``n_components`` connected
        components offers :meth:`geodesic_kernel` (none but triangle meshes do).

        Parameters
        ----------
        n : int
            Number of points (vertices).
        n_components : int
            Number of connected components.

        Returns
        -------
        bool
        """
        return False

    @classmethod
    def geodesic_kernel_bytes(cls, n: int) -> int:
        """Memory of :meth:`geodesic_kernel` on ``n`` points (0 where not offered).

        Parameters
        ----------
        n : int
            Points of the domain.
        """
        return 0

    def geodesic_kernel(self, t: float) -> HeatKernel:
        """The exact Gibbs kernel of squared geodesic distances (triangle meshes).

        Parameters
        ----------
        t : float
            Heat time (the kernel is :math:`e^{-d^2/4t}`).
        """
        raise InputError(f"method 'geodesic' is not available on a {self.kind} domain",
                         field="method")

    def ground_distances(self, src, dst, *, should_cancel=None) -> tuple[np.ndarray, bool]:
        """``(d, squared)``: the ``(len(src), len(dst))`` ground distances between the points
        ``src`` and ``dst`` (indices), the metric whose squares are the costs of the exact
        transport route (thesis eq. 1.1); ``squared``: the entries are already the squares
        (where the squares are what is computed).  ``should_cancel()`` is checked between
        the solves of domains that solve for them.

        Parameters
        ----------
        src, dst : array of int
            Point indices.
        should_cancel : callable, optional
            ``should_cancel() -> bool``, checked between solves.
        """
        raise NotImplementedError(f"no ground distances on a {self.kind} domain")

    def stored_ground_distances(self, should_cancel=None) -> tuple[np.ndarray, bool] | None:
        """``(d, squared)`` of :meth:`ground_distances` between all points, ``(n, n)``, kept
        in the operator store, on domains where they are costly to compute and small enough
        to keep; None elsewhere (compute what is asked).

        Parameters
        ----------
        should_cancel : callable, optional
            ``should_cancel() -> bool``, checked between solves.
        """
        return None

    @classmethod
    def stored_ground_distance_seconds(cls, n: int) -> float:
        """Modelled seconds (one core) of computing :meth:`stored_ground_distances` on an
        ``n``-point domain of this kind: what a domain pays once, where it keeps them and
        has not stored them yet (0 where it keeps none).

        Parameters
        ----------
        n : int
            Points of the domain.
        """
        return 0.0

    def has_stored_geodesics(self) -> bool:
        """Whether :meth:`stored_ground_distances` are stored data (the domain's
        ``artifacts``) rather than computed on first use (False where none are kept)."""
        return False

    @classmethod
    def ground_distance_bytes(cls, n: int, entries: int, dim: int) -> int:
        """Bytes of :meth:`ground_distances` (or :meth:`stored_ground_distances`) giving
        ``entries`` distances on an ``n``-point domain whose points have ``dim``
        coordinates, at most: a memory estimate taken before the domain is built.

        Parameters
        ----------
        n : int
            Points of the domain.
        entries : int
            Distances asked for.
        dim : int
            Coordinates per point.
        """
        raise NotImplementedError(f"no ground distances on a {cls.kind} domain")

    def _adjacency(self) -> sp.spmatrix:
        """Sparsity graph used for connected components."""
        return self.laplacian

    @cached_property
    def _components(self) -> tuple[int, np.ndarray]:
        count, labels = connected_components(self._adjacency(), directed=False)
        return int(count), labels

    @property
    def n_components(self) -> int:
        return self._components[0]

    @property
    def component_labels(self) -> np.ndarray:
        """(n,) component index of every point."""
        return self._components[1]

    @cached_property
    def extent(self) -> float:
        """Size of the domain in its own units (the scale that bounds ``gamma``): the
        bounding-box diagonal of its points (unit area for meshes and point clouds).

        Computed once per domain: a domain's points are set when it is built and never
        change (a solver's gamma check reads it on every call)."""
        return points_extent(self.coordinates)

    def component_masses(self, masses: np.ndarray) -> np.ndarray:
        """Total mass per connected component of an (n,) mass vector.

        Parameters
        ----------
        masses : (n,) array
            Masses.
        """
        return np.bincount(self.component_labels, weights=masses, minlength=self.n_components)

    def require_matching_component_masses(self, masses: np.ndarray, tol: float,
                                          field: str) -> None:
        """Refuse ``(n, k)`` masses whose columns put different mass on some component.

        Transport never moves mass between connected components, so every
        distribution of one problem must give each component the same total
        (L1 gap over components at most ``tol``, mass units).

        Parameters
        ----------
        masses : (n, k) array
            One distribution per column.
        tol : float
            Largest L1 gap over components (mass units).
        field : str
            Input name given to the :class:`~solvers.errors.InputError` raised.
        """
        if self.n_components <= 1 or masses.shape[1] < 2:
            return
        check_component_masses(self.component_labels, masses, field, tol)

    # -- content addressing -------------------------------------------------
    def to_arrays(self) -> dict[str, np.ndarray]:
        """Canonical arrays from which ``domain_from_arrays`` rebuilds this domain."""
        raise NotImplementedError  # pragma: no cover

    def parameters(self) -> dict:
        """Scalar construction parameters (part of the content hash)."""
        return {}

    def content_hash(self) -> str:
        """SHA-256 of the canonical arrays and parameters: equal inputs, equal id."""
        digest = hashlib.sha256()
        digest.update(self.kind.encode())
        digest.update(json.dumps(self.parameters(), sort_keys=True).encode())
        for name, array in sorted(self.to_arrays().items()):
            arr = np.ascontiguousarray(array)
            digest.update(name.encode())
            digest.update(str(arr.dtype).encode())
            digest.update(str(arr.shape).encode())
            digest.update(arr.tobytes())
        return digest.hexdigest()

    @property
    def nbytes(self) -> int:
        """Bytes held: the domain's own arrays and cached geometry plus its operator store."""
        own = {k: v for k, v in vars(self).items() if k != "operators"}
        return nbytes_of(own) + self.operators.nbytes

    def summary(self) -> dict:
        """Sizes and diagnostics, JSON-serializable."""
        return {"kind": self.kind, "n": int(self.n), "components": self.n_components}
