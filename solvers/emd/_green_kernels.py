"""numba kernels of :mod:`solvers.emd.green` (imported on first use: numba loads in ~0.5 s).

Compiled with ``cache=True`` (the first call in a fresh environment compiles for a few
seconds; later processes load the cache).  Where no cache directory is writable numba
refuses ``cache=True``; the kernels are then compiled once per process.
"""

from __future__ import annotations

import numba
import numpy as np

from solvers.emd.green_panels import PANEL
from solvers.jit import cached_njit

_FLUSH = 64  # faces summed in float32 before adding to the float64 accumulator




@cached_njit(parallel=True, fastmath=True)
def face_pass(panels, s1, s2, tri, metric, out):  # pragma: no cover - compiled
    n_panels = panels.shape[0]
    n_faces = tri.shape[0]
    for b in numba.prange(n_panels):
        p = panels[b]
        acc = np.zeros(PANEL, np.float64)
        part = np.zeros(PANEL, np.float32)
        for f in range(n_faces):
            i = tri[f, 0]
            j = tri[f, 1]
            k = tri[f, 2]
            a1 = s1[f]
            a2 = s2[f]
            m0 = metric[f, 0]
            m1 = metric[f, 1]
            m2 = metric[f, 2]
            for t in range(PANEL):
                gi = p[i, t]
                d1 = a1 - (p[j, t] - gi)
                d2 = a2 - (p[k, t] - gi)
                part[t] += np.sqrt(max(m0 * d1 * d1 + m1 * d1 * d2 + m2 * d2 * d2,
                                       np.float32(0.0)))
            if (f % _FLUSH) == _FLUSH - 1 or f == n_faces - 1:
                for t in range(PANEL):
                    acc[t] += part[t]
                    part[t] = 0.0
        for t in range(PANEL):
            out[b * PANEL + t] = acc[t]


@cached_njit(parallel=True)
def store_block(sol, keep, pins, c, mu_row, first, panels):  # pragma: no cover - compiled
    """``panels[:, :, col] = G_pin[:, col] - c - c[col] + μ`` for the solved columns
    ``first + t`` (``sol`` (len(keep), w·PANEL) holds the rows ``keep``, the pinned rows of
    ``G_pin`` are 0; ``c`` is padded with zeros to the panel width)."""
    n_sub = sol.shape[1] // PANEL
    b0 = first // PANEL
    for r in numba.prange(keep.shape[0]):
        v = keep[r]
        base = mu_row[v] - c[v]
        for pb in range(n_sub):
            dst = panels[b0 + pb, v]
            for t in range(PANEL):
                dst[t] = sol[r, pb * PANEL + t] + base - c[first + pb * PANEL + t]
    for r in range(pins.shape[0]):
        v = pins[r]
        base = mu_row[v] - c[v]
        for pb in range(n_sub):
            dst = panels[b0 + pb, v]
            for t in range(PANEL):
                dst[t] = base - c[first + pb * PANEL + t]
