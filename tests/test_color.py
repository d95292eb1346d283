"""solvers.color: Lab conversion, histograms, luminance OT, color transfer ground truths."""

from __future__ import annotations

import numpy as np
import pytest
from skimage import data

from solvers.color import _kernels, ab_histogram, color_transfer, histogram_picture
from solvers.color.chrominance import AbGrid
from solvers.color.lab import (
    lab_to_rgb,
    lab_to_rgb_reference,
    lut_for,
    pixels,
    rgb_to_lab,
    rgb_to_lab_reference,
)
from solvers.color.luminance import cdf_at_edges, luminance_maps, quantiles
from solvers.errors import InputError


@pytest.fixture(scope="module")
def photos():
    return {name: getattr(data, name)() for name in ("astronaut", "coffee", "chelsea",
                                                      "rocket")}


def coarse_w2(h1, h2, size=32):
    """Exact W2^2 (POT emd2, squared ab distance) between two ab histograms pooled to 32²."""
    ot = pytest.importorskip("ot")
    bins = h1.shape[0]
    grid = AbGrid(bins)
    idx = np.minimum(((grid.nodes + 128.0) / 256.0 * size).astype(int), size - 1)

    def pool(h):
        out = np.zeros((size, size))
        np.add.at(out, (idx[:, None], idx[None, :]), h)
        return out.ravel() / out.sum()

    c = -128.0 + (np.arange(size) + 0.5) * 256.0 / size
    pts = np.stack(np.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)
    p, q = pool(h1), pool(h2)
    sp, sq = p > 0, q > 0
    M = ((pts[sp][:, None, :] - pts[sq][None, :, :]) ** 2).sum(-1)
    return float(ot.emd2(p[sp], q[sq], M))


# -- Lab ----------------------------------------------------------------------
def test_lab_fast_path_matches_skimage(photos):
    rng = np.random.default_rng(0)
    cases = [photos["astronaut"], (rng.random((64, 80, 3)) * 65535).astype(np.uint16),
             rng.random((50, 40, 3)), rng.random((30, 30, 4)).astype(np.float32)]
    for img in cases:
        err = np.abs(rgb_to_lab(img) - rgb_to_lab_reference(img)).max()
        assert err < 1e-4, (img.dtype, err)
    lab = np.stack([rng.uniform(0, 100, 20000), rng.uniform(-128, 128, 20000),
                    rng.uniform(-128, 128, 20000)], axis=1)
    assert np.abs(lab_to_rgb(lab, np.float64) - lab_to_rgb_reference(lab)).max() < 1e-4
    # 8-bit round trip is exact
    img = photos["chelsea"]
    assert np.array_equal(lab_to_rgb(rgb_to_lab_reference(img), np.uint8), img)


def test_fused_histogram_equals_bincount(photos):
    img = photos["coffee"]
    bins = 64
    grid = AbGrid(bins)
    px = pixels(img)
    lut, scale = lut_for(px.dtype)
    lab, counts, _ = _kernels.analyze(px, lut, scale, bins, -128.0, grid.spacing, 0, 100.0)
    ref = ab_histogram(rgb_to_lab_reference(img)[..., 1:], bins)
    # Both bin the same ab values (fast vs reference Lab differ by < 1e-4): only pixels
    # within 1e-4 of a bin boundary may land differently.
    assert np.abs(counts.reshape(bins, bins) / px.shape[0] - ref).sum() < 1e-3
    assert np.isclose(counts.sum(), px.shape[0], rtol=1e-12)


# -- luminance ----------------------------------------------------------------
def test_quantile_matching_against_sorting():
    rng = np.random.default_rng(1)
    src = np.clip(rng.normal(40, 10, 20000), 0, 100)
    tgt = np.clip(rng.gamma(4, 8, 30000), 0, 100)
    M = 4096
    counts = np.stack([np.histogram(x, M, (0, 100))[0] for x in (src, tgt)])
    lut = luminance_maps(counts, np.array([[0.0, 1.0]]))[0, 0]
    bin_of = lambda x: np.minimum((x / 100 * M).astype(int), M - 1)  # noqa: E731
    mapped = lut[bin_of(src)]
    # exact 1-D OT: the i-th smallest source value goes to the target quantile of rank i
    order = np.argsort(src)
    exact = np.quantile(tgt, (np.arange(len(src)) + 0.5) / len(src))
    err = np.abs(mapped[order] - exact)
    assert np.median(err) < 0.05 and np.quantile(err, 0.99) < 0.5
    # alpha = (1, 0) is the identity on the support
    ident = luminance_maps(counts, np.array([[1.0, 0.0]]))[0, 0]
    assert np.abs(ident[bin_of(src)] - src).max() <= 0.5 * 100 / M + 1e-9  # bin centers
    # all of a flat image's pixels (one bin) go to the target's mean
    flat = np.zeros(M)
    flat[1000] = 1.0
    to_tgt = luminance_maps(np.stack([flat, counts[1]]), np.array([[0.0, 1.0]]))[0, 0]
    assert abs(to_tgt[1000] - tgt.mean()) < 0.05
    # quantiles cross empty bins (almost) at once
    cdf = cdf_at_edges(np.array([1.0, 0, 0, 1.0]))
    assert np.allclose(quantiles(cdf, np.array([0.25, 0.5 - 1e-6, 0.5 + 1e-6, 0.75]), 4.0),
                       [0.5, 1.0, 3.0, 3.5], atol=1e-3)


# -- ground truths -------------------------------------------------------------
def _shifted_pair(shift):
    """A smooth in-gamut target and the same image with ab shifted by ``shift``."""
    y, x = np.mgrid[0:60, 0:80] / 60.0
    L = 50 + 15 * x
    a = -10 + 20 * np.sin(3 * x + y)
    b = 5 + 15 * np.cos(2 * y - x)
    lab_t = np.stack([L, a, b], -1)
    lab_s = lab_t + np.array([0.0, *shift])
    tgt, src = lab_to_rgb_reference(lab_t), lab_to_rgb_reference(lab_s)
    # in gamut: the round trips reproduce the Lab values
    assert np.abs(rgb_to_lab_reference(tgt) - lab_t).max() < 1e-6
    assert np.abs(rgb_to_lab_reference(src) - lab_s).max() < 1e-6
    return src, tgt, lab_s, lab_t


def test_constant_shift_is_recovered():
    bins = 129  # h = 2 ab units; the shift is a multiple of it
    shift = (12.0, -8.0)
    src, tgt, lab_s, lab_t = _shifted_pair(shift)
    r = color_transfer([src, tgt], [0.0, 1.0], mode="barycentric", bins=bins, gamma=8.0,
                       luminance=False, recolor=[0])
    assert r.converged and r.residual <= 1e-4
    h = AbGrid(bins).spacing
    # T_0 is the shift at every node of the source's support (to the grid resolution)
    nodes = AbGrid(bins).nodes
    A, B = np.meshgrid(nodes, nodes, indexing="ij")
    sup = r.histograms[0] > 0
    Ta, Tb = r.maps[0, 0]
    assert np.abs(Ta[sup] - (A[sup] - shift[0])).max() < 0.5 * h
    assert np.abs(Tb[sup] - (B[sup] - shift[1])).max() < 0.5 * h
    out = r.images[0][0]
    assert out.shape == src.shape and out.dtype == src.dtype
    lab_o = rgb_to_lab_reference(out)
    assert np.abs(lab_o[..., 1:] - lab_t[..., 1:]).max() < h
    # alpha = (0, 1) reproduces the target's histogram
    assert np.abs(ab_histogram(lab_o[..., 1:], bins // 4 + 1)
                  - ab_histogram(lab_t[..., 1:], bins // 4 + 1)).sum() < 0.05
    # only chrominance transferred: L unchanged
    assert np.abs(lab_o[..., 0] - lab_s[..., 0]).max() < 1e-3


def test_identity_weights_barycentric_mode(photos):
    imgs = [photos["coffee"], photos["chelsea"]]
    r = color_transfer(imgs, [1.0, 0.0], mode="barycentric", bins=128, gamma=16.0,
                       recolor=[0])
    out = r.images[0][0]
    assert out.shape == imgs[0].shape and out.dtype == np.uint8
    # Measured: T_0 moves ab by < 0.05 units (entropic blur of a Gaussian kernel has zero
    # mean inside the window) and L* by < 0.025 (luminance bins): 8-bit output differs by
    # at most one code from the input.
    sup = r.histograms[0] > 0
    nodes = AbGrid(128).nodes
    A, B = np.meshgrid(nodes, nodes, indexing="ij")
    assert np.abs(r.maps[0, 0, 0][sup] - A[sup]).max() < 0.05
    assert np.abs(r.maps[0, 0, 1][sup] - B[sup]).max() < 0.05
    assert np.abs(out.astype(int) - imgs[0]).max() <= 1


def test_alpha_size_and_orientation_kept(photos):
    rng = np.random.default_rng(2)
    rgb = photos["chelsea"]  # 300 x 451, not square
    alpha = rng.integers(0, 256, rgb.shape[:2], dtype=np.uint8)
    rgba = np.concatenate([rgb, alpha[..., None]], axis=-1)
    other = photos["rocket"][::2, ::2].astype(np.uint16) * 257  # 16-bit, another size
    r = color_transfer([rgba, other], [0.5, 0.5], bins=64, gamma=32.0)
    a, b = r.images[0]
    assert a.shape == rgba.shape and a.dtype == np.uint8
    assert np.array_equal(a[..., 3], alpha)
    assert b.shape == other.shape and b.dtype == np.uint16
    # orientation: the recolored image correlates with the input in L*, not a flip of it
    L_in, L_out = rgb_to_lab(rgb)[..., 0], rgb_to_lab(a)[..., 0]
    assert np.corrcoef(L_in.ravel(), L_out.ravel())[0, 1] > 0.95
    assert np.corrcoef(L_in[::-1].ravel(), L_out.ravel())[0, 1] < 0.9


@pytest.mark.parametrize("pair", [("astronaut", "coffee"), ("chelsea", "rocket")])
def test_photographs_move_towards_the_target(photos, pair):
    src, tgt = photos[pair[0]], photos[pair[1]]
    r = color_transfer([src, tgt], [0.0, 1.0], bins=128, gamma=16.0, recolor=[0])
    assert r.converged
    out = r.images[0][0]
    h_in = ab_histogram(rgb_to_lab(src)[..., 1:], 128)
    h_tgt = ab_histogram(rgb_to_lab(tgt)[..., 1:], 128)
    h_out = ab_histogram(rgb_to_lab(out)[..., 1:], 128)
    before, after = coarse_w2(h_in, h_tgt), coarse_w2(h_out, h_tgt)
    assert after < 0.25 * before, (before, after)


def test_interpolation_sequence_sharpen_and_debiased(photos):
    imgs = [photos["coffee"][::2, ::2], photos["astronaut"][::2, ::2]]
    s = [0.0, 0.5, 1.0]
    alphas = [[1 - x, x] for x in s]
    plain = color_transfer(imgs, alphas, mode="barycentric", bins=64, gamma=32.0,
                           luminance=False)
    assert plain.barycenters.shape == (3, 64, 64) and len(plain.images) == 3
    # image 0's mean chroma moves monotonically along the sequence
    means = [rgb_to_lab(plain.images[b][0])[..., 1:].reshape(-1, 2).mean(0) for b in range(3)]
    d = [np.linalg.norm(m - means[0]) for m in means]
    assert d[0] < d[1] < d[2]
    sharp = color_transfer(imgs, alphas[1], mode="barycentric", bins=64, gamma=32.0,
                           sharpen=True)
    deb = color_transfer(imgs, alphas[1], mode="barycentric", bins=64, gamma=32.0,
                         debiased=True)
    from solvers.convolutional.common import entropy

    n = 64 * 64
    ent = lambda m: entropy(m.ravel(), np.full(n, 1.0 / n))  # noqa: E731
    assert ent(sharp.barycenters[0]) <= sharp.entropy_bounds[0] + 1e-6
    assert ent(sharp.barycenters[0]) < ent(plain.barycenters[1])
    assert ent(deb.barycenters[0]) < ent(plain.barycenters[1])
    pic = histogram_picture(plain.barycenters[1])
    assert pic.shape == (64, 64, 3) and pic.dtype == np.uint8
    assert pic.min() < 200 and pic.max() == 255  # colored blobs on white


def test_input_errors(photos):
    img = photos["coffee"]
    with pytest.raises(InputError) as e:
        color_transfer([img])
    assert e.value.field == "images"
    with pytest.raises(InputError) as e:
        color_transfer([img, img[..., :2]])
    assert e.value.field == "images[1]"
    with pytest.raises(InputError) as e:
        color_transfer([img, img], [1.0, -1.0])
    assert e.value.field == "alphas"
    with pytest.raises(InputError) as e:
        color_transfer([img, img], bins=3)
    assert e.value.field == "bins"
    with pytest.raises(InputError) as e:
        color_transfer([img, img], gamma=0)
    assert e.value.field == "gamma"


def test_flat_image_goes_to_the_target_means(photos):
    """A one-color image: every plan sends its single color to the target's mean (the
    barycentric projection of a Dirac's plan), in L* and in ab."""
    gray = np.full((40, 50, 3), 128, np.uint8)
    tgt = photos["coffee"][::4, ::4]
    r = color_transfer([gray, tgt], [0.0, 1.0], mode="barycentric", bins=64, gamma=16.0,
                       recolor=[0])
    out = rgb_to_lab_reference(r.images[0][0]).reshape(-1, 3)
    assert out.std(axis=0).max() < 1e-6
    mean = rgb_to_lab_reference(tgt).reshape(-1, 3).mean(axis=0)
    assert np.abs(out[0] - mean).max() < 0.5  # 8-bit output rounding


def test_default_gamma_resolves_coarse_grids(photos):
    """On a coarse ab grid (h = 36.6 at 8 nodes) 16 squared ab units would not resolve the
    kernel; the default is twice the smallest the grid resolves there (below 17 nodes) and
    stays 16 elsewhere."""
    from solvers.color.transfer import DEFAULT_BINS, DEFAULT_GAMMA, default_gamma
    from solvers.validation import GAMMA_RESOLUTION

    coarse = 2 * GAMMA_RESOLUTION * AbGrid(8).spacing ** 2
    assert default_gamma(DEFAULT_BINS["split"]) == DEFAULT_GAMMA
    assert default_gamma(DEFAULT_BINS["barycentric"]) == DEFAULT_GAMMA
    assert default_gamma(17) == DEFAULT_GAMMA < default_gamma(16)
    assert default_gamma(8) == pytest.approx(coarse)
    small = [p[::8, ::8] for p in (photos["coffee"], photos["chelsea"], photos["astronaut"])]
    r = color_transfer(small[:2], [0.5, 0.5], mode="barycentric", bins=8)
    assert r.gamma == pytest.approx(coarse) and r.converged
    moved = r.images[0][0].astype(float)
    assert np.isfinite(moved).all() and np.abs(moved - small[0]).mean() > 1.0
    # an explicit gamma the grid cannot resolve is refused, in either mode
    for mode in ("barycentric", "split"):
        with pytest.raises(InputError, match="smallest regularization") as e:
            color_transfer(small[:2], mode=mode, bins=8, gamma=16.0)
        assert e.value.field == "gamma"
