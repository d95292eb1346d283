"""numba kernels of the plan-splitting transfer (:mod:`solvers.color.split`).

Pixels are flat ``(N,)`` rows of an ``H × W`` image in C order.  Low-resolution fields
(``(h, w)``, one cell per ``s × s`` block of pixels) are sampled bilinearly at pixel
centres.  The passes that hand out ranks keep a running counter per source bin and key
level, each bin's counters advanced by one thread in raster order, so the assignment is
the same for any number of threads.
"""

from __future__ import annotations

import numba
import numpy as np

from solvers.color._kernels import (
    _jit,
    _linear_rgb,
    _lookup_l,
    _nearest_node,
    _store,
    _store_linear,
    count_at_node,
)


@_jit()
def _axis(n, s, size):
    """For the ``n`` pixel centres along one axis: the two cells of a ``size``-cell axis
    of a field reduced by ``s`` that bilinear sampling mixes, and the fraction of the
    second (clamped at the borders)."""
    first = np.empty(n, dtype=np.int64)
    second = np.empty(n, dtype=np.int64)
    frac = np.empty(n)
    for y in range(n):
        f = (y + 0.5) / s - 0.5
        if f < 0.0:
            f = 0.0
        if f > size - 1:
            f = size - 1.0
        i = int(f)
        if i > size - 2:
            i = max(size - 2, 0)
        first[y] = i
        second[y] = min(i + 1, size - 1)
        frac[y] = f - i
    return first, second, frac


@_jit()
def _axes(npix, width, s, h, w):
    """:func:`_axis` for the rows and the columns of an image of ``npix`` pixels, ``width``
    wide, sampling an ``h × w`` field."""
    ys, ys1, fy = _axis(npix // width, s, h)
    xs, xs1, fx = _axis(width, s, w)
    return ys, ys1, fy, xs, xs1, fx


@_jit(inline="always")
def _bilinear(field, i, i1, u, j, j1, v):
    return ((1 - u) * ((1 - v) * field[i, j] + v * field[i, j1])
            + u * ((1 - v) * field[i1, j] + v * field[i1, j1]))


@_jit(parallel=True)
def keys(lab, base, width, s, smooth_a, smooth_b, lo, h, nbins, row_of, dirs, key, row):
    """Each pixel's source row (``row_of`` its nearest ab node) and its ordering key: the
    smoothed ab around it (bilinear at the pixel centre), relative to its node, projected
    on its row's direction.  The pixel's ab is ``lab[:, 1:] + base`` (``base`` empty:
    ``lab[:, 1:]``)."""
    inv_h = 1.0 / h
    moved = base.shape[0] > 0
    ys, ys1, fy, xs, xs1, fx = _axes(lab.shape[0], width, s, smooth_a.shape[0],
                                      smooth_a.shape[1])
    for y in numba.prange(ys.shape[0]):
        i0, i1, u = ys[y], ys1[y], fy[y]
        for x in range(width):
            p = y * width + x
            a = lab[p, 1]
            b = lab[p, 2]
            if moved:
                a = np.float32(a + base[p, 0])
                b = np.float32(b + base[p, 1])
            i = _nearest_node(np.float64(a), lo, inv_h, nbins)
            j = _nearest_node(np.float64(b), lo, inv_h, nbins)
            r = row_of[i * nbins + j]
            row[p] = r
            j0 = xs[x]
            j1 = xs1[x]
            v = fx[x]
            ma = _bilinear(smooth_a, i0, i1, u, j0, j1, v) - (lo + h * i)
            mb = _bilinear(smooth_b, i0, i1, u, j0, j1, v) - (lo + h * j)
            key[p] = ma * dirs[r, 0] + mb * dirs[r, 1]


@_jit(parallel=True)
def block_sums_ab(lab, base, width, s, sums):
    """Sums of a*, b* (moved by ``base`` unless it is empty) and pixel counts over each
    ``s × s`` block: ``sums`` ``(3, h, w)``."""
    hl = sums.shape[1]
    wl = sums.shape[2]
    height = lab.shape[0] // width
    moved = base.shape[0] > 0
    for by in numba.prange(hl):
        for y in range(by * s, min(height, (by + 1) * s)):
            for x in range(width):
                p = y * width + x
                bx = min(x // s, wl - 1)
                a = np.float64(lab[p, 1])
                b = np.float64(lab[p, 2])
                if moved:
                    a += base[p, 0]
                    b += base[p, 1]
                sums[0, by, bx] += a
                sums[1, by, bx] += b
                sums[2, by, bx] += 1.0


@_jit(parallel=True)
def key_ranges(key, row, nrows):
    """Smallest and largest key of each row ``(nrows,)`` (per-chunk extremes, exact in any
    order), and whether some pixel has no row (``row < 0``)."""
    n = key.shape[0]
    chunks = max(1, min(8, n // 65536 + 1))
    step = (n + chunks - 1) // chunks
    los = np.full((chunks, nrows), np.inf)
    his = np.full((chunks, nrows), -np.inf)
    missing = np.zeros(chunks, dtype=np.bool_)
    for c in numba.prange(chunks):
        for p in range(c * step, min(n, (c + 1) * step)):
            r = row[p]
            if r < 0:
                missing[c] = True
                continue
            k = key[p]
            if k < los[c, r]:
                los[c, r] = k
            if k > his[c, r]:
                his[c, r] = k
    lo = np.full(nrows, np.inf)
    hi = np.full(nrows, -np.inf)
    for c in range(chunks):
        for r in range(nrows):
            if los[c, r] < lo[r]:
                lo[r] = los[c, r]
            if his[c, r] > hi[r]:
                hi[r] = his[c, r]
    return lo, hi, missing.any()


@_jit(inline="always")
def _level(k, lo, hi, levels):
    span = hi - lo
    if span <= 0.0:
        return 0
    q = int((k - lo) / span * (levels - 1) + 0.5)
    return min(max(q, 0), levels - 1)


@_jit(parallel=True)
def _row_counts(row, nrows):
    """Pixels per row (per-chunk integer counts, summed: exact in any order)."""
    n = row.shape[0]
    chunks = max(1, min(8, n // 65536 + 1))
    step = (n + chunks - 1) // chunks
    part = np.zeros((chunks, nrows), dtype=np.int64)
    for c in numba.prange(chunks):
        for p in range(c * step, min(n, (c + 1) * step)):
            part[c, row[p]] += 1
    return part.sum(axis=0)


@_jit()
def _row_groups(weight, ngroups):
    """Rows cut into ``ngroups`` consecutive ranges of about equal ``weight``: the group of
    each row.  Only the work split depends on it, never the result."""
    total = max(weight.sum(), 1)
    group = np.empty(weight.shape[0], dtype=np.int64)
    acc = 0
    for r in range(weight.shape[0]):
        group[r] = min(ngroups - 1, acc * ngroups // total)
        acc += weight[r]
    return group


def level_counts(key, row, lo, hi, counts):
    """Pixels per row and key level, ``counts`` ``(nrows, levels)``.  Parallel over groups
    of rows (each row counted by one thread), so it is exact for any thread count."""
    _level_counts(key, row, lo, hi, counts, numba.get_num_threads())


@_jit(parallel=True)
def _level_counts(key, row, lo, hi, counts, ngroups):
    levels = counts.shape[1]
    group = _row_groups(_row_counts(row, counts.shape[0]), ngroups)
    for g in numba.prange(ngroups):
        for p in range(key.shape[0]):
            r = row[p]
            if group[r] == g:
                counts[r, _level(key[p], lo[r], hi[r], levels)] += 1


def assign(key, row, lo, hi, start, offsets, ends, disp, scale, out, straddle):
    """Rank every pixel within its row (key level, then raster order) and give it the
    displacement of the target its rank falls in: targets ``offsets[r]..offsets[r+1]``
    of row ``r`` hold ``ends`` (cumulative pixel counts) and ``disp`` ``(T, 2)``;
    ``start`` ``(nrows, levels)`` the rank of each level's first pixel (advanced here).

    The pixels of a level whose ranks all fall in one target need no rank: they are
    assigned in parallel; only the levels that straddle a target's end are walked in
    raster order (``straddle`` ``(N,)`` bool scratch marks their pixels).  The result does
    not depend on the number of threads."""
    nrows, levels = start.shape
    target = np.empty((nrows, levels), dtype=np.int32)
    _uniform_levels(start, offsets, ends, target)
    _assign_uniform(key, row, lo, hi, target, disp, float(scale), out, straddle)
    _assign_straddling(key, row, lo, hi, start, offsets, ends, disp, float(scale), out,
                       straddle)


@_jit(parallel=True)
def exclusive_cumsum(counts):
    """Each row of ``counts`` ``(R, L)`` replaced in place by its exclusive prefix sums."""
    for r in numba.prange(counts.shape[0]):
        acc = 0
        for q in range(counts.shape[1]):
            c = counts[r, q]
            counts[r, q] = acc
            acc += c


@_jit(inline="always")
def _target_of(ends, first, last, rank):
    """The first target in ``first..last`` whose cumulative count exceeds ``rank`` (the
    row's last target for any rank past them), by bisection."""
    t = first
    while t < last:
        mid = (t + last) // 2
        if rank >= ends[mid]:
            t = mid + 1
        else:
            last = mid
    return t


@_jit(parallel=True)
def _uniform_levels(start, offsets, ends, target):
    """``target[r, q]``: the target all ranks of level ``q`` of row ``r`` fall in, or -1
    (the level straddles a target's end, or is empty)."""
    nrows, levels = start.shape
    for r in numba.prange(nrows):
        first = offsets[r]
        last = offsets[r + 1] - 1
        for q in range(levels):
            target[r, q] = -1
        if last < first:
            continue
        total = ends[last]
        for q in range(levels):
            lo = start[r, q]
            hi = start[r, q + 1] if q + 1 < levels else total
            if hi > lo:
                t = _target_of(ends, first, last, lo)
                if t == _target_of(ends, first, last, hi - 1):
                    target[r, q] = t


@_jit(parallel=True)
def _assign_uniform(key, row, lo, hi, target, disp, scale, out, straddle):
    levels = target.shape[1]
    for p in numba.prange(key.shape[0]):
        r = row[p]
        t = target[r, _level(key[p], lo[r], hi[r], levels)]
        straddle[p] = t < 0
        if t >= 0:
            out[p, 0] = disp[t, 0] * scale
            out[p, 1] = disp[t, 1] * scale


@_jit()
def _assign_straddling(key, row, lo, hi, start, offsets, ends, disp, scale, out, straddle):
    levels = start.shape[1]
    for p in range(key.shape[0]):
        if not straddle[p]:
            continue
        r = row[p]
        q = _level(key[p], lo[r], hi[r], levels)
        rank = start[r, q]
        start[r, q] = rank + 1
        t = _target_of(ends, offsets[r], offsets[r + 1] - 1, rank)
        out[p, 0] = disp[t, 0] * scale
        out[p, 1] = disp[t, 1] * scale


GUIDE_SCALE = 0.01  # guide channels: Lab / 100


def n_moments(c: int) -> int:
    """Block moments of a ``c``-channel guide: I, I_i I_j (i <= j), Da, Db, I_i D, count."""
    return c + c * (c + 1) // 2 + 2 + 2 * c + 1


@_jit(parallel=True)
def block_moments(lab, disp, width, s, nguide, out):
    """Sums over each ``s × s`` block of the moments :func:`n_moments` lists, guide
    ``I = lab[:, :nguide] / 100``, into ``out`` ``(n_moments, h, w)``."""
    hl = out.shape[1]
    wl = out.shape[2]
    height = lab.shape[0] // width
    c = nguide
    g = np.empty(3)
    for by in numba.prange(hl):
        g = np.empty(3)
        for y in range(by * s, min(height, (by + 1) * s)):
            for x in range(width):
                p = y * width + x
                bx = x // s
                if bx >= wl:
                    bx = wl - 1
                for u in range(c):
                    g[u] = np.float64(lab[p, u]) * GUIDE_SCALE
                da = np.float64(disp[p, 0])
                db = np.float64(disp[p, 1])
                k = 0
                for u in range(c):
                    out[k, by, bx] += g[u]
                    k += 1
                for u in range(c):
                    for v in range(u, c):
                        out[k, by, bx] += g[u] * g[v]
                        k += 1
                out[k, by, bx] += da
                out[k + 1, by, bx] += db
                k += 2
                for u in range(c):
                    out[k, by, bx] += g[u] * da
                    out[k + 1, by, bx] += g[u] * db
                    k += 2
                out[k, by, bx] += 1.0


@_jit(inline="always")
def _solve_small(S, r, c):
    """``S[:c, :c]^{-1} r[:c]`` for ``c`` in (1, 3), symmetric positive definite ``S``
    (closed form: a LAPACK call per cell costs more than the whole filter)."""
    a = np.empty((3, 2))
    if c == 1:
        a[0, 0] = r[0, 0] / S[0, 0]
        a[0, 1] = r[0, 1] / S[0, 0]
        return a
    c00 = S[1, 1] * S[2, 2] - S[1, 2] * S[2, 1]
    c01 = S[1, 2] * S[2, 0] - S[1, 0] * S[2, 2]
    c02 = S[1, 0] * S[2, 1] - S[1, 1] * S[2, 0]
    c11 = S[0, 0] * S[2, 2] - S[0, 2] * S[2, 0]
    c12 = S[0, 2] * S[1, 0] - S[0, 0] * S[1, 2]
    c22 = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
    det = S[0, 0] * c00 + S[0, 1] * c01 + S[0, 2] * c02
    for d in range(2):
        a[0, d] = (c00 * r[0, d] + c01 * r[1, d] + c02 * r[2, d]) / det
        a[1, d] = (c01 * r[0, d] + c11 * r[1, d] + c12 * r[2, d]) / det
        a[2, d] = (c02 * r[0, d] + c12 * r[1, d] + c22 * r[2, d]) / det
    return a


@_jit(parallel=True)
def guided_solve(mom, nguide, eps, coef):
    """Per cell of the box-filtered means ``mom``: ``a_d = (cov(I) + eps)^{-1} cov(I, D_d)``
    and ``b_d = mean D_d - a_d · mean I``; ``coef`` ``(2 nguide + 2, h, w)`` holds
    ``a_a (nguide), a_b (nguide), b_a, b_b``."""
    c = nguide
    hl = mom.shape[1]
    wl = mom.shape[2]
    for y in numba.prange(hl):
        S = np.empty((3, 3))
        r = np.empty((3, 2))
        mi = np.empty(3)
        for x in range(wl):
            for u in range(c):
                mi[u] = mom[u, y, x]
            k = c
            for u in range(c):
                for v in range(u, c):
                    S[u, v] = mom[k, y, x] - mi[u] * mi[v]
                    S[v, u] = S[u, v]
                    k += 1
            for u in range(c):
                S[u, u] += eps
            md0 = mom[k, y, x]
            md1 = mom[k + 1, y, x]
            k += 2
            for u in range(c):
                r[u, 0] = mom[k, y, x] - mi[u] * md0
                r[u, 1] = mom[k + 1, y, x] - mi[u] * md1
                k += 2
            a = _solve_small(S, r, c)
            ba = md0
            bb = md1
            for u in range(c):
                coef[u, y, x] = a[u, 0]
                coef[c + u, y, x] = a[u, 1]
                ba -= a[u, 0] * mi[u]
                bb -= a[u, 1] * mi[u]
            coef[2 * c, y, x] = ba
            coef[2 * c + 1, y, x] = bb


@_jit(inline="always")
def _in_box(r, g, bb):
    t = GAMUT_TOL
    return -t <= r <= 1 + t and -t <= g <= 1 + t and -t <= bb <= 1 + t


@_jit(inline="always")
def _in_gamut(L, a, b, m):
    r, g, bb = _linear_rgb(L, a, b, m)
    return _in_box(r, g, bb)


GAMUT_TOL = 1e-3
GAMUT_STEP = 2.0
# _finv(t) = t^3 above this, linear (slope 1 / 7.787) below
_FINV_KNEE = 0.2068966
_FINV_SLOPE = 1.0 / 7.787


@_jit(inline="always")
def _finv_slope(t):
    """An upper bound of the slope of :func:`~solvers.color._kernels._finv` on
    ``(-inf, t]`` (it is increasing and convex above the knee)."""
    if t > _FINV_KNEE:
        return max(3.0 * t * t, _FINV_SLOPE)
    return _FINV_SLOPE


@_jit(inline="always")
def _excluded_radius(r, g, bb, slope_x, slope_y, slope_z, m):
    """A distance in L* within which no colour of the same ``(a, b)`` is in the gamut,
    from the linear RGB ``(r, g, bb)`` at one L* and bounds ``slope_*`` of ``d X/dL*``
    (and Y, Z) over the L* range searched: channel ``c`` moves at most
    ``sum_k |m_ck| slope_k`` per L* unit, so its violation needs that many units to close."""
    t = GAMUT_TOL
    radius = 0.0
    for c in range(3):
        v = r if c == 0 else (g if c == 1 else bb)
        # less 1e-7: the knee of _finv is continuous only to ~1e-8
        over = max(-t - v, v - (1.0 + t)) - 1e-7
        if over > 0.0:
            rate = (abs(m[c, 0]) * slope_x + abs(m[c, 1]) * slope_y
                    + abs(m[c, 2]) * slope_z)
            radius = max(radius, over / rate)
    # a relative margin well above float rounding keeps every skipped point a sure miss
    return radius * (1.0 - 1e-6)


@_jit(inline="always")
def _skip_steps(L_hi, L, a, b, m, r, g, bb):
    """How many scan steps past ``L`` are sure misses given the RGB ``(r, g, bb)`` at ``L``
    (``L_hi``: the largest L* the steps can reach); at least 1 (the next step)."""
    y = (L_hi + 16.0) / 116.0
    slope_x = _finv_slope(a / 500.0 + y) / 116.0
    slope_y = _finv_slope(y) / 116.0
    slope_z = _finv_slope(y - b / 200.0) / 116.0
    k = int(_excluded_radius(r, g, bb, slope_x, slope_y, slope_z, m) / GAMUT_STEP)
    return max(k, 1)


@_jit()
def gamut_lightness(L, a, b, m, reach):
    """The L* nearest to ``L`` at which ``(L*, a, b)`` is inside the sRGB gamut (scan in
    steps of ``GAMUT_STEP``, below before above at equal distance, then bisection), if one
    lies within ``reach`` of ``L``; ``L`` itself otherwise.

    The scan skips steps that a Lipschitz bound of the RGB channels in L*
    (:func:`_excluded_radius`) proves out of the gamut, so it returns what the plain
    step-by-step scan returns (``tests/test_color_speed.py`` checks it)."""
    if _in_gamut(L, a, b, m):
        return L
    last = int(reach / GAMUT_STEP)
    big = last + 1
    down = 1  # next step below L that may be in the gamut
    up = 1
    while True:
        step = min(down, up)
        if step > last:
            return L
        for sign in (-1.0, 1.0):
            if (down if sign < 0 else up) != step:
                continue
            Lc = L + sign * step * GAMUT_STEP
            if Lc < 0.0 or Lc > 100.0:
                nxt = big  # every further step on this side is outside [0, 100] too
            else:
                r, g, bb = _linear_rgb(Lc, a, b, m)
                if _in_box(r, g, bb):
                    return _bisect_lightness(Lc - sign * GAMUT_STEP, Lc, a, b, m)
                L_hi = Lc if sign < 0 else 100.0
                nxt = step + _skip_steps(L_hi, Lc, a, b, m, r, g, bb)
            if sign < 0:
                down = nxt
            else:
                up = nxt


@_jit(inline="always")
def _bisect_lightness(bad, good, a, b, m):
    for _ in range(10):
        mid = 0.5 * (bad + good)
        if _in_gamut(mid, a, b, m):
            good = mid
        else:
            bad = mid
    return good


@_jit(inline="always")
def _gamut_map_out(L, a, b, m, reach):
    """:func:`gamut_map` of a colour already known to be out of the gamut at ``L``."""
    if reach > 0:
        Lg = gamut_lightness(L, a, b, m, reach)
        if Lg != L:
            return Lg, a, b
    return _chroma_map(L, a, b, m)


@_jit(inline="always")
def _chroma_map(L, a, b, m):
    """The same L* and hue with the largest in-gamut chroma (bisection on the factor of
    ``(a, b)``) of a colour out of the gamut at ``L``."""
    lo = 0.0
    hi = 1.0
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        if _in_gamut(L, a * mid, b * mid, m):
            lo = mid
        else:
            hi = mid
    return L, a * lo, b * lo


@_jit()
def gamut_map(L, a, b, m, reach):
    """An in-gamut colour for ``(L, a, b)``: the nearest in-gamut L* within ``reach``
    (:func:`gamut_lightness`), else the same L* and hue with the largest in-gamut chroma
    (bisection on the factor of ``(a, b)``; grey is in the gamut for L* in [0, 100])."""
    L = min(max(L, 0.0), 100.0)
    if _in_gamut(L, a, b, m):
        return L, a, b
    return _gamut_map_out(L, a, b, m, reach)


@_jit(inline="always")
def _guided_at(lab, coef, c, p, i0, i1, w, j0, j1, v):
    """The guided filter's displacement ``a · I + b`` at pixel ``p`` (coefficients bilinear
    between cells ``i0, i1`` / ``j0, j1`` at fractions ``w`` / ``v``)."""
    da = _bilinear(coef[2 * c], i0, i1, w, j0, j1, v)
    db = _bilinear(coef[2 * c + 1], i0, i1, w, j0, j1, v)
    for u in range(c):
        g = np.float64(lab[p, u]) * GUIDE_SCALE
        da += _bilinear(coef[u], i0, i1, w, j0, j1, v) * g
        db += _bilinear(coef[c + u], i0, i1, w, j0, j1, v) * g
    return da, db


@_jit(parallel=True)
def guided_field(lab, coef, nguide, s, width, disp):
    """The guided filter's displacement ``a · I + b`` at every pixel (``I =
    lab[:, :nguide] / 100``, coefficients from :func:`guided_solve`, box-filtered, bilinear
    at pixel centres), written into ``disp`` ``(N, 2)``."""
    ys, ys1, fy, xs, xs1, fx = _axes(lab.shape[0], width, s, coef.shape[1], coef.shape[2])
    for y in numba.prange(ys.shape[0]):
        i0, i1, w = ys[y], ys1[y], fy[y]
        for x in range(width):
            p = y * width + x
            da, db = _guided_at(lab, coef, nguide, p, i0, i1, w, xs[x], xs1[x], fx[x])
            disp[p, 0] = da
            disp[p, 1] = db


@_jit(inline="always")
def _moved(lab, disp, p, lo, inv_h, nbins):
    """Pixel ``p``'s moved a*, b* (float32, as stored) and their nearest node indices."""
    a = np.float64(np.float32(lab[p, 1] + disp[p, 0]))
    b = np.float64(np.float32(lab[p, 2] + disp[p, 1]))
    return a, b, _nearest_node(a, lo, inv_h, nbins), _nearest_node(b, lo, inv_h, nbins)


@_jit(inline="always")
def _count_moved(lab, disp, p, c, lo, h, inv_h, nbins, counts, sums, sub):
    """Add pixel ``p``'s moved colour to chunk ``c`` of :func:`moved_histogram`'s sums."""
    a, b, ia, ib = _moved(lab, disp, p, lo, inv_h, nbins)
    count_at_node(counts, sums, sub, c, ia, ib, a, b, a, b, lo, h, nbins)


@_jit(parallel=True)
def moved_histogram(lab, disp, lo, h, nbins, counts, sums, sub):
    """Nearest-node histogram of the moved colours ``lab[:, 1:] + disp`` (float32, as
    stored), per chunk: ``counts`` ``(chunks, nbins²)``, ``sums`` ``(chunks, 2, nbins²)``
    their a*, b*, and if ``K = sub.shape[3] > 0`` ``sub`` ``(chunks, 2, nbins², K)`` the
    counts of their offsets from the node in ``K`` sub-bins of ``[-h/2, h/2]`` (as
    :func:`~solvers.color._kernels.analyze` counts an image's)."""
    n = lab.shape[0]
    chunks = counts.shape[0]
    step = (n + chunks - 1) // chunks
    inv_h = 1.0 / h
    for c in numba.prange(chunks):
        for p in range(c * step, min(n, (c + 1) * step)):
            _count_moved(lab, disp, p, c, lo, h, inv_h, nbins, counts, sums, sub)


@_jit(parallel=True)
def guided_moved_histogram(lab, coef, nguide, s, width, disp, add, lo, h, nbins, counts,
                           sums, sub):
    """:func:`guided_field` into ``disp`` (``add``: added to it, in float32 as stored) and
    :func:`moved_histogram` of the result, in one pass over the pixels (the same chunks
    and order as :func:`moved_histogram`, so the same sums)."""
    n = lab.shape[0]
    chunks = counts.shape[0]
    step = (n + chunks - 1) // chunks
    inv_h = 1.0 / h
    ys, ys1, fy, xs, xs1, fx = _axes(n, width, s, coef.shape[1], coef.shape[2])
    for c in numba.prange(chunks):
        p0 = c * step
        p1 = min(n, (c + 1) * step)
        for y in range(p0 // width, (p1 + width - 1) // width):
            i0, i1, w = ys[y], ys1[y], fy[y]
            row = y * width
            x0 = max(p0 - row, 0)
            x1 = min(p1 - row, width)
            # the row's part of the chunk: the field first (a loop the compiler vectorizes),
            # then its colours counted in pixel order
            if add:
                for x in range(x0, x1):
                    da, db = _guided_at(lab, coef, nguide, row + x, i0, i1, w, xs[x],
                                        xs1[x], fx[x])
                    disp[row + x, 0] = disp[row + x, 0] + np.float32(da)
                    disp[row + x, 1] = disp[row + x, 1] + np.float32(db)
            else:
                for x in range(x0, x1):
                    da, db = _guided_at(lab, coef, nguide, row + x, i0, i1, w, xs[x],
                                        xs1[x], fx[x])
                    disp[row + x, 0] = da
                    disp[row + x, 1] = db
            for x in range(x0, x1):
                _count_moved(lab, disp, row + x, c, lo, h, inv_h, nbins, counts, sums, sub)


@_jit(parallel=True)
def remap_in_nodes(lab, disp, lo, h, nbins, cdfs):
    """Move each colour ``lab[:, 1:] + disp`` within its nearest node: per axis, its offset
    from the node goes through the CDF of the moved colours' offsets and the inverse of
    the target's (``cdfs`` ``(nbins², 2, 3, K + 1)``: node, axis, then the moved and the
    target CDFs at the edges of ``K`` sub-bins of ``[-h/2, h/2]``, linear inside one, and
    for each sub-bin ``j`` the target sub-bin holding the moved CDF at its lower edge;
    a node's rows side by side, as a pixel reads them all); ``disp`` updated in place."""
    n = lab.shape[0]
    inv_h = 1.0 / h
    for p in numba.prange(n):
        a, b, ia, ib = _moved(lab, disp, p, lo, inv_h, nbins)
        q = ia * nbins + ib
        ua = (a - lo) * inv_h - ia
        ub = (b - lo) * inv_h - ib
        disp[p, 0] += np.float32((_quantile_map(cdfs, q, 0, ua) - ua) * h)
        disp[p, 1] += np.float32((_quantile_map(cdfs, q, 1, ub) - ub) * h)


@_jit(inline="always")
def _quantile_map(cdfs, q, ax, u):
    """``ft^{-1}(fm(u))`` (``fm, ft = cdfs[q, ax]``) for an offset ``u`` in node units."""
    nsub = cdfs.shape[3] - 1
    t = min(max((u + 0.5) * nsub, 0.0), np.float64(nsub))
    j = min(int(t), nsub - 1)
    y = cdfs[q, ax, 0, j] + (t - j) * (cdfs[q, ax, 0, j + 1] - cdfs[q, ax, 0, j])
    y = min(max(y, 1e-7), 1.0 - 1e-7)
    # the first target sub-bin whose upper CDF reaches y, stepping from the one that
    # holds fm[j] (y >= fm[j]: usually no step; a search's branches would mispredict)
    lo = int(cdfs[q, ax, 2, j])
    while lo < nsub - 1 and cdfs[q, ax, 1, lo + 1] < y:
        lo += 1
    while lo > 0 and cdfs[q, ax, 1, lo] >= y:
        lo -= 1
    f0 = cdfs[q, ax, 1, lo]
    w = cdfs[q, ax, 1, lo + 1] - f0
    f = (y - f0) / w if w > 0 else 0.5
    return (lo + f) / nsub - 0.5


@_jit(parallel=True)
def apply_field(lab, src, out, lut_l, lstep, disp, m, scale, offset, shift, s, width):
    """Recolor every pixel: ``L -> lut_l[bin]`` (empty: keep) plus the L* shift ``a I + b``
    (``shift`` ``(2, h, w)`` the coefficients ``a, b`` of a guided filter on ``s × s``
    blocks, bilinear at pixel centres, ``I = L*/100`` of the input; empty: none), ``ab +=
    disp``; L* clamped to [0, 100], a colour still out of the gamut loses chroma at its L*
    (:func:`_chroma_map`: the smooth shift is the only L* move, no per-pixel one);
    Lab -> sRGB, ``out = v * scale + offset``; a fourth channel of ``src`` is copied."""
    use_l = lut_l.shape[0] > 0
    use_shift = shift.shape[1] > 0
    alpha = src.shape[1] > 3 and out.shape[1] > 3
    inv_l = 1.0 / lstep
    hs = max(shift.shape[1], 1)
    ws = max(shift.shape[2], 1)
    ys, ys1, fy, xs, xs1, fx = _axes(lab.shape[0], width, s, hs, ws)
    for y in numba.prange(ys.shape[0]):
        i0, i1, u = ys[y], ys1[y], fy[y]
        for x in range(width):
            p = y * width + x
            L0 = np.float64(lab[p, 0])
            A = np.float64(lab[p, 1]) + disp[p, 0]
            B = np.float64(lab[p, 2]) + disp[p, 1]
            L = _lookup_l(L0, lut_l, inv_l) if use_l else L0
            if use_shift:
                j0, j1, v = xs[x], xs1[x], fx[x]
                L += (_bilinear(shift[0], i0, i1, u, j0, j1, v) * L0 * GUIDE_SCALE
                      + _bilinear(shift[1], i0, i1, u, j0, j1, v))
            L = min(max(L, 0.0), 100.0)
            r, g, bb = _linear_rgb(L, A, B, m)
            if _in_box(r, g, bb):  # most pixels: linear RGB computed once
                _store_linear(out, src, p, r, g, bb, scale, offset, alpha)
                continue
            L, A, B = _chroma_map(L, A, B, m)
            _store(out, src, p, L, A, B, m, scale, offset, alpha)


@_jit(parallel=True)
def gamut_shift_moments(lab, lut_l, lstep, disp, m, reach, width, s, stride, w0, out):
    """Block moments (:func:`block_moments` layout, one guide channel ``I = L*/100`` of
    the input, field ``(d, 0)``) of ``d``, the L* move :func:`gamut_lightness` gives a
    pixel's recolored colour (``L -> lut_l[bin]``, ``ab += disp``; 0 in the gamut or with
    no in-gamut L* within ``reach``), over the pixels of every ``stride``-th row and
    column (the field is smoothed over many blocks: a sample of each block suffices)."""
    use_l = lut_l.shape[0] > 0
    inv_l = 1.0 / lstep
    hl = out.shape[1]
    wl = out.shape[2]
    height = lab.shape[0] // width
    for by in numba.prange(hl):
        for y in range(by * s, min(height, (by + 1) * s), stride):
            for x in range(0, width, stride):
                p = y * width + x
                bx = min(x // s, wl - 1)
                L0 = np.float64(lab[p, 0])
                A = np.float64(lab[p, 1]) + disp[p, 0]
                B = np.float64(lab[p, 2]) + disp[p, 1]
                L = _lookup_l(L0, lut_l, inv_l) if use_l else L0
                L = min(max(L, 0.0), 100.0)
                d = 0.0
                w = w0
                if not _in_gamut(L, A, B, m):
                    d = gamut_lightness(L, A, B, m, reach) - L
                    w = 1.0
                g = L0 * GUIDE_SCALE
                out[0, by, bx] += w * g
                out[1, by, bx] += w * g * g
                out[2, by, bx] += w * d
                out[4, by, bx] += w * g * d
                out[6, by, bx] += w
