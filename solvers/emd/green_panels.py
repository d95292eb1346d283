"""The storage of the dense Green's matrix ``L⁺``: float32 column panels of :data:`PANEL`.

Shared by the builder (:mod:`solvers.emd.green`) and its numba kernels
(:mod:`solvers.emd._green_kernels`), which both lay columns out in panels; kept apart from
the kernels so that the builder can name the layout without loading numba.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Targets per panel: one contiguous run per vertex row in the face pass.
PANEL = 32


@dataclass
class GreenMatrix:
    """``L⁺`` of one mesh (component-wise mean-free) as float32 column panels.

    ``panels[b, :, t]`` is column ``b·PANEL + t`` (zero padding past ``n``);
    ``tri``/``metric`` are the per-face vertex indices and the area-weighted 2×2
    gradient metrics ``(M00, 2 M01, M11)`` of the face pass.
    """

    panels: np.ndarray
    n: int
    tri: np.ndarray
    metric: np.ndarray
    build_seconds: float

    @property
    def nbytes(self) -> int:
        return int(self.panels.nbytes)

    def column(self, v: int) -> np.ndarray:
        """``L⁺[:, v]`` (float32, (V,))."""
        return self.panels[v // PANEL, :, v % PANEL]

    def target_panels(self, targets: np.ndarray) -> np.ndarray:
        """Panels holding the columns ``targets`` in order (a copy, zero padded)."""
        n_t = len(targets)
        out = np.zeros((-(-n_t // PANEL) * PANEL, self.n), dtype=np.float32)
        out[:n_t] = self.panels[targets // PANEL, :, targets % PANEL]
        return np.ascontiguousarray(out.reshape(-1, PANEL, self.n).transpose(0, 2, 1))
