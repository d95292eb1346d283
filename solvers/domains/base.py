"""What every domain (mesh, grid, graph, point cloud) provides."""

from __future__ import annotations

import contextlib
import hashlib
import json
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from solvers.domains.operators import OperatorStore, nbytes_of
from solvers.errors import DomainError, InputError
from solvers.kernels import HeatKernel
from solvers.linalg import Backend
from solvers.validation import check_component_masses


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
    """

    kind: str = "domain"
    n: int
    areas: np.ndarray

    def __init__(self):
        self.operators = OperatorStore()

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
        """Whether :meth:`geodesic_kernel` is offered (method ``"geodesic"``)."""
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
        pts = getattr(self, "points", None)
        if pts is None:
            pts = getattr(self, "vertices", None)
        return points_extent(pts)

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
