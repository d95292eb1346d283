"""Point clouds sampled from surfaces."""

from __future__ import annotations

import numpy as np
import robust_laplacian
import scipy.sparse as sp

from solvers.domains.base import Domain
from solvers.errors import DomainError
from solvers.kernels import ImplicitEulerHeatKernel
from solvers.linalg import Backend


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

    def __init__(self, points, n_neighbors: int = 30):
        super().__init__()
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3:
            raise DomainError(f"points must have shape (n, 3), got {p.shape}", field="points")
        if len(p) < 4:
            raise DomainError(f"a point cloud needs at least 4 points, got {len(p)}",
                              field="points")
        if not np.all(np.isfinite(p)):
            bad = int(np.argwhere(~np.isfinite(p))[0, 0])
            raise DomainError(f"point {bad} has a NaN or infinite coordinate", field="points")
        n_neighbors = int(n_neighbors)
        if not 3 <= n_neighbors < len(p):
            raise DomainError(f"n_neighbors must lie in [3, {len(p) - 1}]",
                              field="n_neighbors")
        self._input_points = p
        self.n_neighbors = n_neighbors
        lap, mass = robust_laplacian.point_cloud_laplacian(p, n_neighbors=n_neighbors)
        mass = np.asarray(mass.diagonal(), dtype=np.float64)
        if not np.all(mass > 0):
            raise DomainError("some points received no area (duplicates?)", field="points")
        total = float(mass.sum())
        self.length_scale = float(np.sqrt(total))
        self.points = p / self.length_scale
        self.areas = mass / total
        # The weak Laplacian is scale invariant on surfaces; only masses rescale.
        self._laplacian = sp.csr_matrix(lap)

    @property
    def n(self) -> int:
        return len(self.points)

    @property
    def laplacian(self) -> sp.csr_matrix:
        return self._laplacian

    def _build_heat_kernel(self, t: float, substeps: int, backend: Backend):
        return ImplicitEulerHeatKernel(self.areas, self.laplacian, t, substeps, backend)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"points": self._input_points}

    def parameters(self) -> dict:
        return {"n_neighbors": self.n_neighbors}

    def summary(self) -> dict:
        return {"kind": self.kind, "n": self.n, "points": self.n,
                "components": self.n_components, "length_scale": self.length_scale}
