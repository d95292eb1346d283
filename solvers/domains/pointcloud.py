"""Point clouds sampled from surfaces."""

from __future__ import annotations

import numpy as np
import robust_laplacian
import scipy.sparse as sp

from solvers.domains.base import (
    Domain,
    ExportGeometry,
    domain_input,
    squared_straight_distance_bytes,
    squared_straight_distances,
)
from solvers.errors import DomainError
from solvers.kernels import ImplicitEulerHeatKernel
from solvers.linalg import Backend
from solvers.validation import check_int


class PointCloud(Domain):
    r"""Points on a surface with the point-cloud Laplacian of Sharp & Crane (2020).

    The cloud is rescaled so its estimated surface area is 1 (``length_scale``
    returns to input units); ``areas`` are the normalized lumped masses and the
    heat kernel is implicit Euler :math:`(D_a + tL)^{-1} D_a`, as on meshes.

    Parameters
    ----------
    points : (n, 3) coordinates.
    n_neighbors : neighbours of the local triangulations (robust-laplacian).
    """

    kind = "pointcloud"
    capabilities = frozenset({"exact_transport", "histogram_propagation"})

    def __init__(self, points, n_neighbors: int = 30):
        super().__init__()
        try:
            p = np.asarray(points, dtype=np.float64)
        except (TypeError, ValueError, OverflowError) as exc:
            raise DomainError("points must be an (n, 3) array of numbers", field="points") from exc
        if p.ndim != 2 or p.shape[1] != 3:
            raise DomainError(f"points must have shape (n, 3), got {p.shape}", field="points")
        if len(p) < 4:
            raise DomainError(f"a point cloud needs at least 4 points, got {len(p)}",
                              field="points")
        if not np.all(np.isfinite(p)):
            bad = int(np.argwhere(~np.isfinite(p))[0, 0])
            raise DomainError(f"point {bad} has a NaN or infinite coordinate", field="points")
        with domain_input():
            n_neighbors = check_int(n_neighbors, "n_neighbors", low=3, high=len(p) - 1)
        distinct = len(np.unique(p, axis=0))
        if distinct < len(p):
            raise DomainError(f"points holds {len(p) - distinct} repeated points (each point "
                              "must appear once)", field="points")
        # Laplacian and masses are computed on the cloud centered and scaled into the unit
        # box (the weak Laplacian is scale invariant, masses scale with the square), so huge
        # or tiny coordinates cannot overflow.
        center = 0.5 * (p.max(axis=0) + p.min(axis=0))
        with np.errstate(over="ignore"):
            box = float(np.max(np.abs(p - center)))
        if not np.isfinite(box) or box <= 0:
            raise DomainError("point coordinates span a range too large to represent",
                              field="points")
        unit = (p - center) / box
        self._input_points = p
        self.n_neighbors = n_neighbors
        try:
            lap, mass = robust_laplacian.point_cloud_laplacian(unit, n_neighbors=n_neighbors)
        except (RuntimeError, ValueError) as exc:
            raise DomainError("could not build the point-cloud Laplacian (are the points "
                              "degenerate, e.g. all on a line?)", field="points") from exc
        mass = np.asarray(mass.diagonal(), dtype=np.float64)
        lap = sp.csr_matrix(lap)
        if not (np.all(np.isfinite(mass)) and np.all(np.isfinite(lap.data))):
            raise DomainError("the point-cloud Laplacian is not finite (degenerate points)",
                              field="points")
        if not np.all(mass > 0):
            raise DomainError("some points received no area (near-duplicates?)", field="points")
        total = float(mass.sum())  # area of the unit-box cloud
        if not (np.isfinite(total) and total > 0):
            raise DomainError("the estimated surface area of the points is not finite",
                              field="points")
        self.length_scale = float(np.sqrt(total)) * box
        self.points = p / self.length_scale
        self.areas = mass / total
        # The weak Laplacian is scale invariant on surfaces; only masses rescale.
        self._laplacian = lap

    @property
    def n(self) -> int:
        return len(self.points)

    @property
    def laplacian(self) -> sp.csr_matrix:
        return self._laplacian

    def _build_heat_kernel(self, t: float, substeps: int, backend: Backend):
        return ImplicitEulerHeatKernel(self.areas, self.laplacian, t, substeps, backend)

    def ground_distances(self, src, dst, *, should_cancel=None) -> tuple[np.ndarray, bool]:
        """Squared straight distances between the points (unit-area scale)."""
        return squared_straight_distances(self.points, src, dst), True

    @classmethod
    def ground_distance_bytes(cls, n: int, entries: int, dim: int) -> int:
        """:func:`~solvers.domains.base.squared_straight_distance_bytes`."""
        return squared_straight_distance_bytes(n, entries, dim)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"points": self._input_points}

    def export_geometry(self) -> ExportGeometry:
        """The points in input units."""
        return ExportGeometry(self.to_arrays()["points"])

    @property
    def coordinates(self) -> np.ndarray:
        """The points at unit area."""
        return self.points

    def parameters(self) -> dict:
        return {"n_neighbors": self.n_neighbors}

    def summary(self) -> dict:
        return {"kind": self.kind, "n": self.n, "points": self.n,
                "components": self.n_components, "length_scale": self.length_scale}
