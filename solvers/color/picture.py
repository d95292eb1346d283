"""The picture of an ab histogram (thesis Fig. 3.12, bottom row).

Each node of the ab grid is painted in its own chrominance at a fixed lightness, blended
over white by the histogram's mass (``(m / max m)^power``), with a* to the right and b* up.
"""

from __future__ import annotations

import numpy as np

from solvers.color.chrominance import AbGrid
from solvers.color.lab import lab_to_rgb


def histogram_picture(masses: np.ndarray, lightness: float = 65.0,
                      power: float = 0.5) -> np.ndarray:
    """An ab histogram as a picture (Fig. 3.12, bottom row).

    Each node is painted its own chrominance at lightness ``lightness``, blended with white
    by the node's mass relative to the largest.

    Parameters
    ----------
    masses : (bins, bins) array
        ab masses (axis 0: a*, axis 1: b*).
    lightness : float
        L* of the painted colors.
    power : float
        Exponent on the relative mass (below 1 brightens small masses).

    Returns
    -------
    (bins, bins, 3) uint8 array
        RGB picture, b* upwards and a* to the right.
    """
    m = np.asarray(masses, dtype=np.float64)
    bins = m.shape[0]
    nodes = AbGrid(bins).nodes
    a, b = np.meshgrid(nodes, nodes, indexing="ij")
    lab = np.stack([np.full_like(a, lightness), a, b], axis=-1)
    color = lab_to_rgb(lab, np.float32).astype(np.float64)
    top = m.max()
    w = (m / top) ** power if top > 0 else np.zeros_like(m)
    img = w[..., None] * color + (1.0 - w[..., None])
    # rows = b (up), cols = a (right)
    img = np.transpose(img, (1, 0, 2))[::-1]
    return np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)
