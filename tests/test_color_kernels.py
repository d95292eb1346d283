"""The fast colour kernels against straightforward references (same answers, any thread
count): the gamut search with skipped steps, the parallel rank assignment."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from solvers.color import _kernels
from solvers.color import _split_kernels as SK

M = _kernels._M_INV


def _in_gamut_ref(L, a, b):
    y = (L + 16.0) / 116.0
    x = a / 500.0 + y
    z = max(y - b / 200.0, 0.0)

    def finv(t):
        return t * t * t if t > 0.2068966 else (t - 16.0 / 116.0) / 7.787

    xyz = (finv(x), finv(y), finv(z))
    t = SK.GAMUT_TOL
    return all(-t <= sum(M[c, k] * xyz[k] for k in range(3)) <= 1 + t for c in range(3))


def _gamut_map_ref(L, a, b, reach):
    """The plain scan: every step of 2 L* below then above, bisection; else chroma."""
    L = min(max(L, 0.0), 100.0)
    if _in_gamut_ref(L, a, b):
        return L, a, b
    for step in range(1, int(reach / SK.GAMUT_STEP) + 1):
        for sign in (-1.0, 1.0):
            Lc = L + sign * step * SK.GAMUT_STEP
            if Lc < 0.0 or Lc > 100.0 or not _in_gamut_ref(Lc, a, b):
                continue
            bad, good = Lc - sign * SK.GAMUT_STEP, Lc
            for _ in range(10):
                mid = 0.5 * (bad + good)
                bad, good = (bad, mid) if _in_gamut_ref(mid, a, b) else (mid, good)
            return good, a, b
    lo, hi = 0.0, 1.0
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _in_gamut_ref(L, a * mid, b * mid) else (lo, mid)
    return L, a * lo, b * lo


def _colours(n, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-5, 105, n), rng.uniform(-140, 140, n),
                     rng.uniform(-140, 140, n)], axis=1)


@pytest.mark.parametrize("reach", [100.0, 10.0])
def test_gamut_map_matches_the_plain_scan(reach):
    lab = _colours(1500)
    out_of_gamut = 0
    for L, a, b in lab:
        got = SK.gamut_map(L, a, b, M, reach)
        want = _gamut_map_ref(L, a, b, reach)
        assert got == pytest.approx(want, abs=1e-9), (L, a, b)
        out_of_gamut += not _in_gamut_ref(min(max(L, 0), 100), a, b)
        assert _in_gamut_ref(*got) or got[1:] == (a, b)  # in gamut, or no L* in reach
    assert out_of_gamut > 500  # the search really ran


def test_apply_field_is_chroma_loss_then_lab_to_rgb():
    """Out-of-gamut colours keep their L* (the smooth shift is the only L* move) and lose
    chroma: the plain reference with no L* reach."""
    rng = np.random.default_rng(1)
    n = 2000
    lab = np.ascontiguousarray(_colours(n, 1).astype(np.float32))
    lab[:, 0] = np.clip(lab[:, 0], 0, 100)
    disp = rng.normal(0, 20, (n, 2)).astype(np.float32)
    src = np.zeros((n, 4), dtype=np.uint8)
    src[:, 3] = rng.integers(0, 256, n)
    src.flags.writeable = False  # as a transfer passes its input image (numba: another type)
    out = np.empty_like(src)
    empty = np.zeros(0, dtype=np.float32)
    SK.apply_field(lab, src, out, empty, 1.0, disp, M, 255.0, 0.5, np.zeros((2, 0, 0)), 1, n)
    moved = [(float(L), float(a) + float(da), float(b) + float(db))
             for (L, a, b), (da, db) in zip(lab, disp, strict=True)]
    assert sum(not _in_gamut_ref(*c) for c in moved) > 500  # the chroma loss really ran
    mapped = np.array([_gamut_map_ref(*c, 0.0) for c in moved])
    want = np.empty((n, 3), dtype=np.uint8)
    # the plain float64 scan's Lab, stored as float32 Lab the way a transfer stores it (the
    # kernel's own types: no test-only compile)
    lab32 = np.ascontiguousarray(mapped, dtype=np.float32)
    rgb = np.zeros((n, 3), dtype=np.uint8)
    rgb.flags.writeable = False
    empty2 = np.zeros((0, 0), dtype=np.float32)
    _kernels._apply(lab32, rgb, want, empty, 1.0, empty2, empty2, 0.0, 0.0, 1.0, M, 255.0,
                    0.5, 1)
    assert np.abs(out[:, :3].astype(int) - want.astype(int)).max() <= 1
    assert np.mean(out[:, :3] != want) < 1e-3  # float32 vs float64 Lab: rare 1-code steps
    assert np.array_equal(out[:, 3], src[:, 3])


def _assign_ref(key, row, lo, hi, offsets, ends, disp, levels):
    """Ranks by a stable sort on (row, key level), then each rank's target."""
    q = np.array([SK._level(k, lo[r], hi[r], levels) for k, r in zip(key, row, strict=True)])
    order = np.lexsort((np.arange(len(key)), q, row))
    out = np.empty((len(key), 2))
    first = np.searchsorted(row[order], np.arange(len(lo)))
    for i, p in enumerate(order):
        r = row[p]
        rank = i - first[r]
        t = offsets[r] + np.searchsorted(ends[offsets[r]:offsets[r + 1]], rank, side="right")
        out[p] = disp[min(t, offsets[r + 1] - 1)]
    return out


def _rank_problem(seed=2, n=20000, nrows=7):
    rng = np.random.default_rng(seed)
    row = rng.choice(nrows, n, p=np.arange(1, nrows + 1) / (nrows * (nrows + 1) / 2))
    key = np.round(rng.normal(size=n), 2).astype(np.float32)  # many ties within a level
    counts = np.bincount(row, minlength=nrows)
    offsets, ends = [0], []
    for r in range(nrows):
        cuts = np.sort(rng.choice(np.arange(1, counts[r]), 2, replace=False))
        ends.extend([cuts[0], cuts[1], counts[r]])
        offsets.append(offsets[-1] + 3)
    disp = rng.normal(size=(3 * nrows, 2))
    # the dtypes a transfer passes (int32 rows and counts): no test-only compile
    return key, row.astype(np.int32), np.array(offsets), np.array(ends, dtype=np.int64), disp


def _run_assign(key, row, offsets, ends, disp, levels):
    nrows = len(offsets) - 1
    lo, hi, missing = SK.key_ranges(key, row, nrows)
    assert not missing
    for r in range(nrows):
        assert (lo[r], hi[r]) == (key[row == r].min(), key[row == r].max())
    counts = np.zeros((nrows, levels), dtype=np.int32)
    SK.level_counts(key, row, lo, hi, counts)
    start = counts.copy()
    SK.exclusive_cumsum(start)
    np.testing.assert_array_equal(start, np.cumsum(counts, axis=1) - counts)
    out = np.empty((len(key), 2), dtype=np.float32)
    SK.assign(key, row, lo, hi, start, offsets, ends, disp, 1.0, out,
              np.ones(len(key), dtype=np.bool_))  # flags scratch: any content
    return out, counts, lo, hi


def test_key_ranges_flags_a_pixel_without_row():
    key = np.arange(6, dtype=np.float32)
    row = np.array([0, 1, 0, -1, 1, 1], dtype=np.int32)
    lo, hi, missing = SK.key_ranges(key, row, 2)
    assert missing and lo.tolist() == [0, 1] and hi.tolist() == [2, 5]
    assert not SK.key_ranges(key, np.abs(row), 2)[2]


def test_parallel_assign_matches_stable_sort_for_any_thread_count():
    key, row, offsets, ends, disp = _rank_problem()
    levels = 64
    before = numba.get_num_threads()
    try:
        results = []
        for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(threads)
            results.append(_run_assign(key, row, offsets, ends, disp, levels))
    finally:
        numba.set_num_threads(before)
    out, counts, lo, hi = results[0]
    assert counts.sum(axis=1).tolist() == np.bincount(row).tolist()
    want = _assign_ref(key, row, lo, hi, offsets, ends, disp, levels)
    np.testing.assert_array_equal(out, want.astype(np.float32))
    for other in results[1:]:
        np.testing.assert_array_equal(other[0], out)
        np.testing.assert_array_equal(other[1], counts)


def _sample_ref(field, y, x, s):
    """Bilinear value of a field reduced by ``s`` at the centre of pixel ``(y, x)``."""
    h, w = field.shape
    fy = min(max((y + 0.5) / s - 0.5, 0.0), h - 1.0)
    fx = min(max((x + 0.5) / s - 0.5, 0.0), w - 1.0)
    i, j = min(int(fy), max(h - 2, 0)), min(int(fx), max(w - 2, 0))
    u, v = fy - i, fx - j
    i1, j1 = min(i + 1, h - 1), min(j + 1, w - 1)
    return (1 - u) * ((1 - v) * field[i, j] + v * field[i, j1]) + u * (
        (1 - v) * field[i1, j] + v * field[i1, j1])


def test_row_wise_sampling_matches_per_pixel_formula():
    rng = np.random.default_rng(3)
    H, W, s = 37, 53, 4
    lab = rng.uniform(-50, 50, (H * W, 3)).astype(np.float32)
    h, w = -(-H // s), -(-W // s)
    sa, sb = rng.normal(size=(h, w)), rng.normal(size=(h, w))
    row_of = np.zeros(65 * 65, dtype=np.int64)
    dirs = np.array([[0.6, 0.8]])
    key = np.empty(H * W, dtype=np.float32)
    row = np.empty(H * W, dtype=np.int32)
    SK.keys(lab, np.zeros((0, 2), dtype=np.float32), W, s, sa, sb, np.float32(-128.0),
            np.float32(4.0), 65, row_of, dirs, key, row)
    coef = rng.normal(size=(4, h, w))
    disp = np.empty((H * W, 2))
    SK.guided_field(lab, coef, 1, s, W, disp)
    for p in range(0, H * W, 7):
        y, x = divmod(p, W)
        i, j = (min(max(int((float(lab[p, c]) + 128.0) / 4.0 + 0.5), 0), 64) for c in (1, 2))
        want = ((_sample_ref(sa, y, x, s) - (-128.0 + 4.0 * i)) * 0.6
                + (_sample_ref(sb, y, x, s) - (-128.0 + 4.0 * j)) * 0.8)
        assert key[p] == pytest.approx(want, rel=1e-6, abs=1e-5)
        g = float(lab[p, 0]) * 0.01
        assert disp[p, 0] == pytest.approx(_sample_ref(coef[2], y, x, s)
                                           + _sample_ref(coef[0], y, x, s) * g, abs=1e-12)
        assert disp[p, 1] == pytest.approx(_sample_ref(coef[3], y, x, s)
                                           + _sample_ref(coef[1], y, x, s) * g, abs=1e-12)


def test_gamut_shift_moments_match_per_pixel_sums_for_any_thread_count():
    """Block sums of the L* moves into the gamut (weighted: 1 out of the gamut, w0 in it)
    against the plain scan, over a sample of every ``stride``-th row and column."""
    rng = np.random.default_rng(5)
    H, W, s, stride, w0 = 13, 11, 4, 2, 0.3
    lab = np.ascontiguousarray(_colours(H * W, 5).astype(np.float32))
    lab[:, 0] = np.clip(lab[:, 0], 0, 100)
    disp = rng.normal(0, 10, (H * W, 2)).astype(np.float32)
    lut = np.linspace(5, 95, 100).astype(np.float32)
    want = np.zeros((SK.n_moments(1), -(-H // s), -(-W // s)))
    for y in range(0, H, stride):
        for x in range(0, W, stride):
            if y % s % stride or x % s % stride:
                continue
            p = y * W + x
            L = min(max(float(lut[min(int(lab[p, 0]), 99)]), 0.0), 100.0)
            a, b = float(lab[p, 1]) + float(disp[p, 0]), float(lab[p, 2]) + float(disp[p, 1])
            inside = _in_gamut_ref(L, a, b)
            d = 0.0 if inside else _gamut_map_ref(L, a, b, 100.0)[0] - L
            w, g = (w0 if inside else 1.0), float(lab[p, 0]) / 100.0
            cell = (slice(None), y // s, min(x // s, want.shape[2] - 1))
            want[cell] += w * np.array([g, g * g, d, 0.0, g * d, 0.0, 1.0])
    before = numba.get_num_threads()
    try:
        for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(threads)
            got = np.zeros_like(want)
            SK.gamut_shift_moments(lab, lut, 1.0, disp, M, 100.0, W, s, stride, w0, got)
            np.testing.assert_allclose(got, want, atol=1e-6)
    finally:
        numba.set_num_threads(before)
    assert want[2].any()  # some pixels really moved


def test_default_transfer_is_the_same_for_any_thread_count():
    from skimage import data

    from solvers.color import color_transfer

    imgs = [data.rocket()[::2, ::2], data.astronaut()[::2, ::2]]  # many out-of-gamut colours
    before = numba.get_num_threads()
    try:
        outs = []
        for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(threads)
            outs.append(color_transfer(imgs, [0, 1], recolor=[0]).images[0][0])
    finally:
        numba.set_num_threads(before)
    for other in outs[1:]:
        np.testing.assert_array_equal(other, outs[0])


def _kernel_signatures() -> set:
    return {(name, sig) for name, fn in (("analyze", _kernels._analyze), ("apply", _kernels._apply),
                                         ("apply_field", SK.apply_field))
            for sig in fn.signatures}


def test_a_library_callers_writable_images_run_the_uploads_kernel_variants():
    """numba compiles per argument type, read-only included: a library caller's (writable)
    uint8 images run the very variants a decoded (read-only) upload runs, so the kernels the
    install's warm-up compiled serve both (solvers.color.lab.pixels)."""
    from solvers.color import color_transfer

    rng = np.random.default_rng(3)
    images = [rng.integers(0, 256, (9, 11, 3), dtype=np.uint8) for _ in range(2)]
    uploads = []
    for img in images:
        frozen = img.copy()
        frozen.flags.writeable = False
        uploads.append(frozen)
    for mode in ("split", "barycentric"):
        color_transfer(uploads, mode=mode, bins=16)
    before = _kernel_signatures()
    for mode in ("split", "barycentric"):
        color_transfer(images, mode=mode, bins=16)
    assert _kernel_signatures() == before
    assert all(img.flags.writeable for img in images)  # the caller's arrays are untouched
