"""numba kernels of the plan-splitting transfer (:mod:`solvers.color.split`).

Pixels are flat ``(N,)`` rows of an ``H × W`` image in C order.  Low-resolution fields
(``(h, w)``, one cell per ``s × s`` block of pixels) are sampled bilinearly at pixel
centres.  The passes that hand out ranks run sequentially (a running counter per source
bin and key level), so the assignment is deterministic.
"""

from __future__ import annotations

import numba
import numpy as np

from solvers.color._kernels import _jit, _nearest_node, _rgb_of


@_jit(inline="always")
def _sample(field, y, x, s):
    """Bilinear value of the low-resolution ``field`` at the centre of pixel ``(y, x)``."""
    fy = (y + 0.5) / s - 0.5
    fx = (x + 0.5) / s - 0.5
    h = field.shape[0]
    w = field.shape[1]
    if fy < 0.0:
        fy = 0.0
    if fx < 0.0:
        fx = 0.0
    if fy > h - 1:
        fy = h - 1.0
    if fx > w - 1:
        fx = w - 1.0
    i = int(fy)
    j = int(fx)
    if i > h - 2:
        i = max(h - 2, 0)
    if j > w - 2:
        j = max(w - 2, 0)
    u = fy - i
    v = fx - j
    i1 = min(i + 1, h - 1)
    j1 = min(j + 1, w - 1)
    return ((1 - u) * ((1 - v) * field[i, j] + v * field[i, j1])
            + u * ((1 - v) * field[i1, j] + v * field[i1, j1]))


@_jit(parallel=True)
def keys(lab, width, s, smooth_a, smooth_b, lo, h, nbins, row_of, dirs, key, row):
    """Each pixel's source row (``row_of`` its nearest ab node) and its ordering key: the
    smoothed ab around it, relative to its node, projected on its row's direction."""
    inv_h = 1.0 / h
    for p in numba.prange(lab.shape[0]):
        y = p // width
        x = p - y * width
        i = _nearest_node(np.float64(lab[p, 1]), lo, inv_h, nbins)
        j = _nearest_node(np.float64(lab[p, 2]), lo, inv_h, nbins)
        r = row_of[i * nbins + j]
        row[p] = r
        ma = _sample(smooth_a, y, x, s) - (lo + h * i)
        mb = _sample(smooth_b, y, x, s) - (lo + h * j)
        key[p] = ma * dirs[r, 0] + mb * dirs[r, 1]


@_jit()
def key_ranges(key, row, nrows):
    lo = np.full(nrows, np.inf)
    hi = np.full(nrows, -np.inf)
    for p in range(key.shape[0]):
        r = row[p]
        k = key[p]
        if k < lo[r]:
            lo[r] = k
        if k > hi[r]:
            hi[r] = k
    return lo, hi


@_jit(inline="always")
def _level(k, lo, hi, levels):
    span = hi - lo
    if span <= 0.0:
        return 0
    q = int((k - lo) / span * (levels - 1) + 0.5)
    return min(max(q, 0), levels - 1)


@_jit()
def level_counts(key, row, lo, hi, counts):
    levels = counts.shape[1]
    for p in range(key.shape[0]):
        r = row[p]
        counts[r, _level(key[p], lo[r], hi[r], levels)] += 1


@_jit()
def assign(key, row, lo, hi, start, offsets, ends, disp, scale, out):
    """Rank every pixel within its row (key level, then raster order) and give it the
    displacement of the target its rank falls in: targets ``offsets[r]..offsets[r+1]``
    of row ``r`` hold ``ends`` (cumulative pixel counts) and ``disp`` ``(T, 2)``."""
    levels = start.shape[1]
    for p in range(key.shape[0]):
        r = row[p]
        q = _level(key[p], lo[r], hi[r], levels)
        rank = start[r, q]
        start[r, q] = rank + 1
        t = offsets[r]
        last = offsets[r + 1] - 1
        while t < last and rank >= ends[t]:
            t += 1
        out[p, 0] = disp[t, 0] * scale
        out[p, 1] = disp[t, 1] * scale


@_jit(parallel=True)
def block_moments(lab, disp, width, s, out):
    """Sums over each ``s × s`` block of: I, I², Da, Db, I·Da, I·Db, count (``I = L/100``),
    into ``out`` ``(7, h, w)``."""
    hl = out.shape[1]
    wl = out.shape[2]
    height = lab.shape[0] // width
    for by in numba.prange(hl):
        for y in range(by * s, min(height, (by + 1) * s)):
            for x in range(width):
                p = y * width + x
                bx = x // s
                if bx >= wl:
                    bx = wl - 1
                g = np.float64(lab[p, 0]) * 0.01
                da = np.float64(disp[p, 0])
                db = np.float64(disp[p, 1])
                out[0, by, bx] += g
                out[1, by, bx] += g * g
                out[2, by, bx] += da
                out[3, by, bx] += db
                out[4, by, bx] += g * da
                out[5, by, bx] += g * db
                out[6, by, bx] += 1.0


@_jit(parallel=True)
def apply_field(lab, src, out, width, lut_l, lstep, disp, coef, s, m, scale, offset):
    """Recolor every pixel: ``L -> lut_l[bin]`` (empty: keep), ``ab += D`` with ``D`` the
    per-pixel ``disp`` or, when ``coef`` ``(4, h, w)`` is given, the guided-filter output
    ``coef[0:2]·I + coef[2:4]`` (``I = L/100`` of the input, coefficients bilinear);
    Lab -> sRGB, ``out = v * scale + offset``; a fourth channel of ``src`` is copied."""
    n = lab.shape[0]
    use_l = lut_l.shape[0] > 0
    nl = max(lut_l.shape[0], 1)
    guided = coef.shape[0] > 0
    alpha = src.shape[1] > 3 and out.shape[1] > 3
    inv_l = 1.0 / lstep
    for p in numba.prange(n):
        L0 = np.float64(lab[p, 0])
        A = np.float64(lab[p, 1])
        B = np.float64(lab[p, 2])
        if guided:
            y = p // width
            x = p - y * width
            g = L0 * 0.01
            A += _sample(coef[0], y, x, s) * g + _sample(coef[2], y, x, s)
            B += _sample(coef[1], y, x, s) * g + _sample(coef[3], y, x, s)
        else:
            A += disp[p, 0]
            B += disp[p, 1]
        L = L0
        if use_l:
            u = L0 * inv_l
            if u < 0.0:
                u = 0.0
            k = int(u)
            if k > nl - 1:
                k = nl - 1
            L = lut_l[k]
        r, g2, b = _rgb_of(L, A, B, m)
        out[p, 0] = r * scale + offset
        out[p, 1] = g2 * scale + offset
        out[p, 2] = b * scale + offset
        if alpha:
            out[p, 3] = src[p, 3]
