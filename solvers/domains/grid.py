"""Regular grids in 1, 2 or 3 dimensions, optionally periodic per axis."""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from solvers.domains.base import (
    Domain,
    ExportGeometry,
    squared_straight_distance_bytes,
    squared_straight_distances,
)
from solvers.errors import DomainError
from solvers.kernels import GaussianGridHeatKernel, ImplicitEulerHeatKernel
from solvers.linalg import Backend

# Nodes of the largest grid built (the service's limit on points is lower); shapes whose
# product exceeds it are refused before anything is allocated.
MAX_GRID_POINTS = 2**31


class Grid(Domain):
    r"""A regular grid of nodes; cells carry equal weight (``areas = 1/N``).

    Axis ``i`` has ``shape[i]`` nodes spanning ``bounds[i] = (lo, hi)``: on a
    non-periodic axis the nodes are ``linspace(lo, hi, n)`` (both ends
    included, as in POT's convolutional solvers); on a periodic axis the
    period is ``hi - lo`` and the nodes are ``lo + k (hi - lo) / n``.
    Flattened index order is C order (last axis fastest), i.e. an image
    ``img`` of shape ``shape`` is the vector ``img.ravel()``.

    The heat kernel is the exact Gaussian :math:`(4\pi t)^{-d/2} e^{-d^2/4t}`
    times the cell volume, applied separably (``kernel="gaussian"``, default)
    or implicit Euler on the finite-difference Laplacian (``kernel="implicit"``).

    Parameters
    ----------
    shape : sequence of int
        Nodes per axis (1 to 3 axes).
    bounds : sequence of (lo, hi), optional
        Extent of each axis (default ``(0, 1)``).
    periodic : bool or sequence of bool
        Periodic axes.
    """

    kind = "grid"
    capabilities = frozenset({"exact_transport", "exact_heat_kernel"})

    def __init__(
        self,
        shape: Sequence[int],
        bounds: Sequence[Sequence[float]] | None = None,
        periodic: bool | Sequence[bool] = False,
    ):
        super().__init__()
        try:
            shape = tuple(int(s) for s in shape)
        except (TypeError, ValueError, OverflowError) as exc:
            raise DomainError("shape must be a list of integers", field="shape") from exc
        if not 1 <= len(shape) <= 3:
            raise DomainError(f"grids have 1 to 3 axes, got {len(shape)}", field="shape")
        if any(s < 2 for s in shape):
            raise DomainError(f"every axis needs at least 2 nodes, got {shape}", field="shape")
        size = math.prod(shape)  # Python ints: no int64 wrap-around
        if size > MAX_GRID_POINTS:
            raise DomainError(f"shape {list(shape)} gives {size} nodes, more than "
                              f"{MAX_GRID_POINTS}", field="shape")
        if bounds is None:
            bounds = [(0.0, 1.0)] * len(shape)
        try:
            bounds = np.asarray(bounds, dtype=np.float64)
        except (TypeError, ValueError, OverflowError) as exc:  # ragged or not numbers
            raise DomainError(f"bounds must be {len(shape)} pairs (lo, hi) of numbers",
                              field="bounds") from exc
        if bounds.shape != (len(shape), 2):
            raise DomainError(f"bounds must have shape ({len(shape)}, 2), got {bounds.shape}",
                              field="bounds")
        if not np.all(np.isfinite(bounds)) or np.any(bounds[:, 1] <= bounds[:, 0]):
            raise DomainError("bounds must be finite with lo < hi on every axis", field="bounds")
        with np.errstate(over="ignore", under="ignore", divide="ignore"):
            width = bounds[:, 1] - bounds[:, 0]
            h = width / np.asarray(shape, dtype=np.float64)
            inv_h2 = 1.0 / (h * h)
        if not (np.all(np.isfinite(width)) and np.all(np.isfinite(inv_h2))
                and np.all(h * h > 0) and np.all(np.isfinite(width**2))):
            raise DomainError("bounds give a grid spacing whose square under- or overflows "
                              "(axis lengths must lie within about 1e-150 and 1e150)",
                              field="bounds")
        if isinstance(periodic, (bool, np.bool_)):
            periodic = (bool(periodic),) * len(shape)
        periodic = tuple(bool(p) for p in periodic)
        if len(periodic) != len(shape):
            raise DomainError(f"periodic needs one flag per axis ({len(shape)})",
                              field="periodic")
        self.shape = shape
        self.bounds = bounds
        self.periodic = periodic

    @property
    def n(self) -> int:
        return math.prod(self.shape)

    @property
    def extent(self) -> float:
        """Diagonal of the bounding box (grid units)."""
        return float(np.linalg.norm(self.bounds[:, 1] - self.bounds[:, 0]))

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @cached_property
    def spacing(self) -> tuple[float, ...]:
        return tuple(
            (hi - lo) / (n if per else n - 1)
            for (lo, hi), n, per in zip(self.bounds, self.shape, self.periodic, strict=True)
        )

    @cached_property
    def axis_coordinates(self) -> list[np.ndarray]:
        return [
            lo + h * np.arange(n)
            for (lo, _), n, h in zip(self.bounds, self.shape, self.spacing, strict=True)
        ]

    @cached_property
    def points(self) -> np.ndarray:
        """(N, d) node coordinates in flattened (C) order."""
        mesh = np.meshgrid(*self.axis_coordinates, indexing="ij")
        return np.stack([m.ravel() for m in mesh], axis=1)

    @property
    def coordinates(self) -> np.ndarray:
        """The node coordinates (:attr:`points`)."""
        return self.points

    @cached_property
    def areas(self) -> np.ndarray:
        return np.full(self.n, 1.0 / self.n)

    def export_geometry(self) -> ExportGeometry:
        """A 2-D grid: its nodes at z = 0 and two triangles per cell; otherwise its nodes."""
        if self.ndim == 2:
            return ExportGeometry(np.pad(self.points, ((0, 0), (0, 1))),
                                  faces=grid_faces(self.shape))
        return ExportGeometry(self.points)

    @classmethod
    def stored_geometry(cls, arrays: dict, summary: dict, points) -> dict:
        """The shape and bounds (no positions: a viewer lays the nodes out itself)."""
        return {"shape": summary["shape"], "bounds": summary["bounds"]}

    @cached_property
    def laplacian(self) -> sp.csr_matrix:
        r"""Weak finite-difference Laplacian :math:`\frac1N(-\Delta_h)`: PSD, ``L·1 = 0``."""
        total = sp.csr_matrix((self.n, self.n))
        for axis, (n, h, per) in enumerate(zip(self.shape, self.spacing, self.periodic,
                                               strict=True)):
            ones = np.ones(n - 1)
            path = sp.diags([-ones, -ones], [-1, 1], shape=(n, n)).tolil()
            if per and n > 2:
                path[0, n - 1] = path[n - 1, 0] = -1.0
            path = path.tocsr()
            path = path - sp.diags(np.asarray(path.sum(axis=1)).ravel())
            factors = [sp.identity(m, format="csr") for m in self.shape]
            factors[axis] = path / h**2
            term = factors[0]
            for fac in factors[1:]:
                term = sp.kron(term, fac, format="csr")
            total = total + term
        return (total / self.n).tocsr()

    def heat_kernel(self, t: float, substeps: int = 1, backend: Backend = "auto",
                    kernel: str = "gaussian"):
        """Exact Gaussian kernel (default) or implicit Euler on the FD Laplacian.

        Parameters
        ----------
        t, substeps, backend
            As in :meth:`Domain.heat_kernel` (``"implicit"`` only: the Gaussian is exact).
        kernel : {"gaussian", "implicit"}
            Exact separable Gaussian, or implicit Euler on the finite-difference Laplacian.
        """
        if kernel not in ("gaussian", "implicit"):
            raise DomainError(f"kernel must be 'gaussian' or 'implicit', got {kernel!r}",
                              field="kernel")
        # The Gaussian kernel has no factorization: one entry whatever the backend.
        key = ("heat_kernel", float(t), int(substeps),
               backend if kernel == "implicit" else None, kernel)

        def build():
            if kernel == "gaussian":
                return GaussianGridHeatKernel(self, float(t))
            return ImplicitEulerHeatKernel(self.areas, self.laplacian, float(t), int(substeps),
                                           backend)

        return self.operators.get(key, build)

    def ground_distances(self, src, dst, *, should_cancel=None) -> tuple[np.ndarray, bool]:
        """Squared straight distances between the nodes, periodic axes wrapped: the metric
        whose Gaussian the grid heat kernel is.
        """
        width = self.bounds[:, 1] - self.bounds[:, 0]
        periods = np.where(self.periodic, width, 0.0)
        return squared_straight_distances(self.points, src, dst, periods), True

    @classmethod
    def ground_distance_bytes(cls, n: int, entries: int, dim: int) -> int:
        """:func:`~solvers.domains.base.squared_straight_distance_bytes`."""
        return squared_straight_distance_bytes(n, entries, dim)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {
            "shape": np.asarray(self.shape, dtype=np.int64),
            "bounds": self.bounds,
            "periodic": np.asarray(self.periodic, dtype=bool),
        }

    def summary(self) -> dict:
        return {
            "kind": self.kind,
            "n": self.n,
            "shape": list(self.shape),
            "bounds": self.bounds.tolist(),
            "periodic": list(self.periodic),
            "spacing": list(self.spacing),
            "components": 1,
        }


def grid_faces(shape) -> np.ndarray:
    """``(2 (nx - 1) (ny - 1), 3)`` triangles of a 2-D grid's cells (nodes in C order)."""
    nx, ny = shape
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
