"""numba kernels of :mod:`solvers.color` (fused per-pixel passes; imported on first use).

Every kernel works on flat ``(N, C)`` pixel blocks (``C`` = 3 or 4; a fourth channel is
alpha and is copied through untouched) and runs in parallel over contiguous chunks.  The
arithmetic is float64 (scalar code: no slower than float32); Lab values are stored as
float32 and agree with scikit-image's float64 to ~3e-5 units (tests check 1e-4).
Compiled with ``cache=True`` where a cache directory is writable.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types
from numba.extending import overload

# sRGB (IEC 61966-2-1) primaries, D65 white, 2-degree observer: the constants of
# skimage.color.rgb2lab / lab2rgb, so both paths agree.
XYZ_FROM_RGB = np.array([[0.412453, 0.357580, 0.180423],
                         [0.212671, 0.715160, 0.072169],
                         [0.019334, 0.119193, 0.950227]])
RGB_FROM_XYZ = np.linalg.inv(XYZ_FROM_RGB)
WHITE = np.array([0.95047, 1.0, 1.08883])
# Rows of the matrices divided/multiplied by the white point (fold the normalization in).
_M_FWD = XYZ_FROM_RGB / WHITE[:, None]
_M_INV = RGB_FROM_XYZ * WHITE[None, :]


# Tables of the two costly scalar functions, linearly interpolated (65536 cells): the Lab
# nonlinearity f(t) (C1 at its knee) on [0, _T_MAX] and the sRGB encoding on [0, 1].
# Interpolation errors: f below 2e-8 (2e-6 Lab units), encoding below 1e-7.
_TABLE = 65536
_T_MAX = 1.0001
_KNEE_END = 0.008856 + 2 * _T_MAX / _TABLE


def _f_exact(t):
    return np.where(t > 0.008856, np.cbrt(t), 7.787 * t + 16.0 / 116.0)


def _encode_exact(v):
    return np.where(v > 0.0031308, 1.055 * np.power(v, 1 / 2.4) - 0.055, 12.92 * v)


F_TABLE = _f_exact(np.linspace(0.0, _T_MAX, _TABLE + 1)).astype(np.float32)
ENCODE_TABLE = np.clip(_encode_exact(np.linspace(0.0, 1.0, _TABLE + 1)), 0, 1).astype(np.float32)


def _jit(**options):
    def wrap(fn):
        try:
            return numba.njit(cache=True, **options)(fn)
        except RuntimeError:  # pragma: no cover - no writable cache location
            return numba.njit(**options)(fn)

    return wrap


@_jit(inline="always")
def _decode(v):
    """sRGB transfer function, float32 in [0, 1] -> linear."""
    if v > 0.04045:
        return ((v + 0.055) / 1.055) ** 2.4
    return v / 12.92


def _linear(v, lut):  # pragma: no cover - replaced by the overload in compiled code
    raise NotImplementedError


@overload(_linear)
def _linear_impl(v, lut):
    """Integer codes: lookup table; floats in [0, 1]: the transfer function."""
    if isinstance(v, types.Integer):
        return lambda v, lut: np.float64(lut[v])
    return lambda v, lut: _decode(np.float64(v))


@_jit(inline="always")
def _lerp(table, u):
    """``table`` at fractional index ``u`` (float64: float32 would keep only 8 bits of the
    fraction at u ~ 65536) in ``[0, len - 1]``, linearly interpolated."""
    k = int(u)
    if k > table.shape[0] - 2:
        k = table.shape[0] - 2
    f = u - k
    return table[k] + f * (table[k + 1] - table[k])


@_jit(inline="always")
def _f(t):
    if t <= 0.008856:
        return 7.787 * t + 16.0 / 116.0
    if t >= _T_MAX or t < _KNEE_END:  # the cell across the knee: f jumps by 4e-6 there
        return np.cbrt(t)
    return _lerp(F_TABLE, np.float64(t) * (_TABLE / _T_MAX))


@_jit(inline="always")
def _finv(t):
    if t > 0.2068966:
        return t * t * t
    return (t - 16.0 / 116.0) / 7.787


@_jit(inline="always")
def _encode(v):
    """Linear -> sRGB, clipped to [0, 1]."""
    if v <= 0:
        return 0.0
    if v >= 1:
        return 1.0
    return _lerp(ENCODE_TABLE, np.float64(v) * _TABLE)


@_jit(inline="always")
def _lab_of(r, g, b, m):
    x = _f(m[0, 0] * r + m[0, 1] * g + m[0, 2] * b)
    y = _f(m[1, 0] * r + m[1, 1] * g + m[1, 2] * b)
    z = _f(m[2, 0] * r + m[2, 1] * g + m[2, 2] * b)
    return (116.0 * y - 16.0, 500.0 * (x - y),
            200.0 * (y - z))


@_jit(inline="always")
def _linear_rgb(L, a, b, m):
    """Lab -> linear RGB (not clipped; ``m`` = ``_M_INV``)."""
    y = (L + 16.0) / 116.0
    x = a / 500.0 + y
    z = y - b / 200.0
    if z < 0:
        z = 0.0  # as skimage: negative Z clipped to zero
    x = _finv(x)
    y = _finv(y)
    z = _finv(z)
    return (m[0, 0] * x + m[0, 1] * y + m[0, 2] * z,
            m[1, 0] * x + m[1, 1] * y + m[1, 2] * z,
            m[2, 0] * x + m[2, 1] * y + m[2, 2] * z)


@_jit(inline="always")
def _lookup_l(L, lut_l, inv_l):
    """``lut_l`` at the bin (width ``1 / inv_l``) of ``L``, clamped to the table."""
    u = L * inv_l
    if u < 0.0:
        u = 0.0
    k = int(u)
    if k > lut_l.shape[0] - 1:
        k = lut_l.shape[0] - 1
    return np.float64(lut_l[k])


@_jit(inline="always")
def _store(out, src, p, L, a, b, m, scale, offset, alpha):
    """Write Lab ``(L, a, b)`` as ``sRGB * scale + offset`` into ``out[p]``; copy alpha."""
    r, g, bb = _linear_rgb(L, a, b, m)
    _store_linear(out, src, p, r, g, bb, scale, offset, alpha)


@_jit(inline="always")
def _store_linear(out, src, p, r, g, bb, scale, offset, alpha):
    """:func:`_store` of a colour given in linear RGB."""
    r = _encode(r)
    g = _encode(g)
    bb = _encode(bb)
    out[p, 0] = r * scale + offset
    out[p, 1] = g * scale + offset
    out[p, 2] = bb * scale + offset
    if alpha:
        out[p, 3] = src[p, 3]


@_jit(inline="always")
def _cell(u, v, n1, n2):
    """The ab grid cell ``(i, j)`` holding grid coordinates ``(u, v)`` and the bilinear
    fractions ``(fu, fv)`` inside it, clamped to the ``n1 x n2`` nodes: the same weights
    for the histogram splat and the map lookup."""
    if u < 0.0:
        u = 0.0
    if v < 0.0:
        v = 0.0
    i = int(u)
    j = int(v)
    if i > n1 - 2:
        i = n1 - 2
    if j > n2 - 2:
        j = n2 - 2
    fu = u - i
    fv = v - j
    if fu > 1.0:
        fu = 1.0
    if fv > 1.0:
        fv = 1.0
    return i, j, fu, fv


@_jit(inline="always")
def _nearest_node(v, lo, inv_h, n):
    """Index of the node ``lo + h*k`` (``k < n``) nearest to ``v``."""
    u = (v - lo) * inv_h + 0.5
    if u < 0.0:
        return 0
    k = int(u)
    return n - 1 if k > n - 1 else k


@_jit(inline="always")
def sub_bin(v, lo, h, k, nsub):
    """Sub-bin (of ``nsub`` over ``[-h/2, h/2]`` around node ``k``) holding ``v``."""
    t = int(((v - lo) / h - k + 0.5) * nsub)
    return min(max(t, 0), nsub - 1)


@_jit(inline="always")
def count_at_node(hist, sums, sub, c, ia, ib, a, b, sa, sb, lo, h, nbins):
    """Count a colour ``(a, b)`` at its nearest node ``(ia, ib)`` in chunk ``c``: one in
    ``hist``, ``(sa, sb)`` added to the node's ``sums``, and (``K = sub.shape[3] > 0``)
    its offsets from the node counted in ``K`` sub-bins."""
    nsub = sub.shape[3]
    q = ia * nbins + ib
    hist[c, q] += 1.0
    sums[c, 0, q] += sa
    sums[c, 1, q] += sb
    if nsub > 0:
        sub[c, 0, q, sub_bin(a, lo, h, ia, nsub)] += 1.0
        sub[c, 1, q, sub_bin(b, lo, h, ib, nsub)] += 1.0


def _chunks(n: int) -> int:
    return max(1, min(4 * numba.get_num_threads(), n // 4096 + 1))


@_jit(parallel=True, fastmath=False)
def _analyze(px, lut, m, lab, nbins, lo, h, lbins, lmax, hist, lhist, nearest, sums, sub):
    """Lab of every pixel (into ``lab``) and the ab / L histograms of the block.

    ``px`` (N, C) uint8/uint16 (``lut``: the linear value of each code) or float in
    [0, 1] (``lut`` unused).  ``hist`` (chunks, nbins*nbins) receives each pixel's unit
    mass split bilinearly over the 4 ab nodes ``lo + h*k`` around it (the weights
    :func:`_apply` looks the map up with), or with ``nearest`` all of it to the nearest
    node, and ``sums`` (chunks, 2, nbins*nbins) the a*, b* of the pixels at each node,
    and ``sub`` (chunks, 2, nbins*nbins, K) (if ``K > 0``) the counts of their a*, b*
    offsets from the node in ``K`` equal sub-bins of ``[-h/2, h/2]``;
    ``lhist`` (chunks, lbins) counts L over [0, lmax].
    """
    n = px.shape[0]
    chunks = hist.shape[0]
    step = (n + chunks - 1) // chunks
    keep = lab.shape[0] == n
    inv_h = 1.0 / h
    for c in numba.prange(chunks):
        for p in range(c * step, min(n, (c + 1) * step)):
            r = _linear(px[p, 0], lut)
            g = _linear(px[p, 1], lut)
            b = _linear(px[p, 2], lut)
            L, A, B = _lab_of(r, g, b, m)
            if keep:
                lab[p, 0] = L
                lab[p, 1] = A
                lab[p, 2] = B
            if nbins > 0 and nearest:
                # bin the stored (float32) values, as every later pass reads them
                a32 = np.float64(np.float32(A))
                b32 = np.float64(np.float32(B))
                ia = _nearest_node(a32, lo, inv_h, nbins)
                ib = _nearest_node(b32, lo, inv_h, nbins)
                count_at_node(hist, sums, sub, c, ia, ib, a32, b32, A, B, lo, h, nbins)
            elif nbins > 0:  # bilinear ("cloud in cell") splat onto the 4 nearest nodes
                i, j, fu, fv = _cell((A - lo) * inv_h, (B - lo) * inv_h, nbins, nbins)
                q = i * nbins + j
                hist[c, q] += (1.0 - fu) * (1.0 - fv)
                hist[c, q + 1] += (1.0 - fu) * fv
                hist[c, q + nbins] += fu * (1.0 - fv)
                hist[c, q + nbins + 1] += fu * fv
            if lbins > 0:
                k = int(L / lmax * lbins)
                k = min(max(k, 0), lbins - 1)
                lhist[c, k] += 1


def analyze(px: np.ndarray, lut: np.ndarray, scale: float, nbins: int, lo: float, h: float,
            lbins: int, lmax: float, keep_lab: bool = True, nearest: bool = False,
            subbins: int = 0):
    """Run :func:`_analyze`; returns ``(lab (N, 3) float32, ab counts, L counts)`` (``lab``
    empty unless ``keep_lab``: images that only contribute histograms need no Lab copy;
    ``nearest``: each pixel counted at its nearest ab node instead of split bilinearly, and
    then a fourth item, the mean ``(2, nbins²)`` a*, b* of the pixels at each node, and
    with ``subbins > 0`` a fifth, the counts ``(2, nbins², subbins)`` of their a*, b*
    offsets from the node in ``subbins`` sub-bins of the node's cell)."""
    n = px.shape[0]
    chunks = _chunks(n)
    lab = np.empty((n if keep_lab else 0, 3), dtype=np.float32)
    hist = np.zeros((chunks, max(nbins, 1) ** 2), dtype=np.float64)
    lhist = np.zeros((chunks, max(lbins, 1)), dtype=np.int64)
    sums = np.zeros((chunks, 2, max(nbins, 1) ** 2) if nearest else (1, 2, 1))
    nsub = subbins if nearest else 0
    sub = np.zeros((chunks, 2, nbins**2, nsub) if nsub else (1, 1, 1, 0))
    _analyze(px, lut, _M_FWD, lab, nbins, np.float32(lo), np.float32(h),
             lbins, np.float32(lmax), hist, lhist, bool(nearest), sums, sub)
    counts = hist.sum(axis=0)
    if not nearest:
        return lab, counts, lhist.sum(axis=0)
    means = sums.sum(axis=0) / np.maximum(counts, 1.0)
    if nsub:
        return lab, counts, lhist.sum(axis=0), means, sub.sum(axis=0)
    return lab, counts, lhist.sum(axis=0), means


@_jit(parallel=True, fastmath=False)
def _apply(lab, src, out, lut_l, lstep, ta, tb, a0, b0, h, m, scale, offset, chunks):
    """Recolor every pixel: ``L -> lut_l[bin of L]`` (bins of width ``lstep``; ``lut_l``
    empty: keep),
    ``ab -> (ta, tb)(ab)`` (bilinear on the nodes ``(a0 + h i, b0 + h j)``; ``ta`` empty:
    keep), Lab -> sRGB, ``out = v * scale + offset`` (rounding into integer dtypes); a
    fourth channel of ``src`` is copied."""
    n = lab.shape[0]
    step = (n + chunks - 1) // chunks
    use_l = lut_l.shape[0] > 0
    use_ab = ta.shape[0] > 0
    m1 = max(ta.shape[0], 2)
    m2 = max(ta.shape[1], 2)
    inv_l = 1.0 / lstep
    inv_h = 1.0 / h
    alpha = src.shape[1] > 3 and out.shape[1] > 3
    # Scalar float64 code with explicit clamps: min/max over mixed int/float types made
    # this loop ~4x slower.
    for c in numba.prange(chunks):
        for p in range(c * step, min(n, (c + 1) * step)):
            L = np.float64(lab[p, 0])
            A = np.float64(lab[p, 1])
            B = np.float64(lab[p, 2])
            if use_l:
                L = _lookup_l(L, lut_l, inv_l)
            if use_ab:
                i, j, fu, fv = _cell((A - a0) * inv_h, (B - b0) * inv_h, m1, m2)
                t00 = ta[i, j]
                t01 = ta[i, j + 1]
                t10 = ta[i + 1, j]
                t11 = ta[i + 1, j + 1]
                A = t00 + fu * (t10 - t00) + fv * (t01 - t00) + fu * fv * (t11 - t10 - t01 + t00)
                t00 = tb[i, j]
                t01 = tb[i, j + 1]
                t10 = tb[i + 1, j]
                t11 = tb[i + 1, j + 1]
                B = t00 + fu * (t10 - t00) + fv * (t01 - t00) + fu * fv * (t11 - t10 - t01 + t00)
            _store(out, src, p, L, A, B, m, scale, offset, alpha)


def apply(lab, src, out, lut_l, lstep, ta, tb, a0, b0, h, scale, offset):
    _apply(lab, src, out, lut_l, float(lstep), ta, tb, float(a0), float(b0), float(h), _M_INV,
           float(scale), float(offset), _chunks(lab.shape[0]))
    return out
