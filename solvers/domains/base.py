"""What every domain (mesh, grid, graph, point cloud) provides."""

from __future__ import annotations

import hashlib
import json
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from solvers.domains.operators import OperatorStore, nbytes_of
from solvers.errors import UnsupportedDomainError
from solvers.kernels import HeatKernel
from solvers.linalg import Backend


class Domain:
    """A discretized space carrying distributions.

    Subclasses define ``kind``, ``n`` (number of points carrying mass),
    ``areas`` (positive weights summing to 1), ``laplacian`` (sparse PSD weak
    Laplacian, ``L·1 = 0``), ``_build_heat_kernel`` and ``to_arrays``.
    Prefactored operators (heat kernels per ``(t, substeps, backend)``, and whatever the
    solvers derive from the domain) live in one explicit store, ``domain.operators``
    (:class:`~solvers.domains.operators.OperatorStore`): built once under a lock, sized.
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
        """The heat kernel at time ``t`` (built and factored once, then cached)."""
        key = ("heat_kernel", float(t), int(substeps), backend)
        return self.operators.get(
            key, lambda: self._build_heat_kernel(float(t), int(substeps), backend))

    def _build_heat_kernel(self, t: float, substeps: int, backend: Backend) -> HeatKernel:
        raise NotImplementedError  # pragma: no cover

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

    def component_masses(self, masses: np.ndarray) -> np.ndarray:
        """Total mass per connected component of an (n,) mass vector."""
        return np.bincount(self.component_labels, weights=masses, minlength=self.n_components)

    def require_matching_component_masses(self, masses: np.ndarray, tol: float,
                                          field: str) -> None:
        """Refuse ``(n, k)`` masses whose columns put different mass on some component.

        Transport never moves mass between connected components, so every
        distribution of one problem must give each component the same total
        (L1 gap over components at most ``tol``, mass units).
        """
        if self.n_components <= 1 or masses.shape[1] < 2:
            return
        per = np.stack([self.component_masses(masses[:, j]) for j in range(masses.shape[1])],
                       axis=1)
        gap = np.abs(per - per[:, :1]).sum(axis=0)
        if np.any(gap > tol):
            j = int(np.argmax(gap))
            raise UnsupportedDomainError(
                f"the domain has {self.n_components} connected components and mass cannot "
                f"move between them, but the distributions put different mass on them "
                f"(component masses {np.round(per[:, 0], 6).tolist()} vs "
                f"{np.round(per[:, j], 6).tolist()}); give each component the same mass in "
                "every distribution",
                field=field,
            )

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
