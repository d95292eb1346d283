"""solvers.color split transfer: exact histograms, coherence, flat and smooth images."""

from __future__ import annotations

import numpy as np
import pytest
from skimage import data

from solvers.color import color_transfer, transfer
from solvers.color.chrominance import AbGrid
from solvers.color.lab import lab_to_rgb_reference, rgb_to_lab_reference
from solvers.color.split import exact_plan, integer_split
from solvers.errors import InputError

BINS = 65  # node spacing 4 ab units; multiples of 4 are nodes


def flat(lab, shape):
    """A float32 image of one Lab colour (in gamut)."""
    rgb = lab_to_rgb_reference(np.broadcast_to(np.asarray(lab, float), shape + (3,)))
    return rgb.astype(np.float32)


def node_counts(img, bins=BINS):
    grid = AbGrid(bins)
    ab = rgb_to_lab_reference(img)[..., 1:].reshape(-1, 2)
    idx = np.rint((ab + 128.0) / grid.spacing).astype(int)
    return np.bincount(idx[:, 0] * bins + idx[:, 1], minlength=bins * bins)


def test_two_colour_source_split_reproduces_the_target_histogram():
    # source: left half colour P, right half colour Q (equal areas); target: P' on half,
    # Q1 and Q2 on a quarter each: the plan splits Q between Q1 and Q2.
    src = np.concatenate([flat((55, 20, -8), (40, 30)), flat((55, -24, 32), (40, 30))], 1)
    tgt = np.concatenate([flat((55, 24, -12), (40, 60)), flat((55, -36, 28), (20, 60)),
                          flat((55, -12, 40), (20, 60))], 0)
    r = color_transfer([src, tgt], [0, 1], recolor=[0], luminance=False, regularization=0)
    assert r.converged and r.residual < 1e-9
    out = r.images[0][0]
    got, want = node_counts(out), node_counts(tgt)
    # to the bin: every target node gets its share of the source's pixels exactly
    assert np.array_equal(got * tgt.shape[0] * tgt.shape[1],
                          want * src.shape[0] * src.shape[1])
    # coherent: the split half is two solid blocks, not salt and pepper
    q1 = rgb_to_lab_reference(out[:, 30:])[..., 1] < -30  # the Q1 pixels of the right half
    assert q1.sum() == 600
    changes = np.count_nonzero(np.diff(q1, axis=0)) + np.count_nonzero(np.diff(q1, axis=1))
    # a random split would change label between ~half of all 2 x 1200 neighbour pairs
    # (~1200); two solid blocks: one boundary, at most ~2 region sides long
    assert changes <= 2 * 40


def test_constant_image_stays_constant_towards_a_constant_target():
    src = flat((40, 12, 8), (30, 40))
    tgt = flat((70, -20, 30), (25, 25))
    for reg in (0.0, None):
        kw = {} if reg is None else {"regularization": reg}
        out = rgb_to_lab_reference(color_transfer([src, tgt], [0, 1], recolor=[0],
                                                  **kw).images[0][0]).reshape(-1, 3)
        assert out.std(axis=0).max() < 1e-3
        assert np.abs(out[0] - [70, -20, 30]).max() < 0.1


def test_within_node_remap_reproduces_the_targets_colours_inside_a_node(monkeypatch):
    # source: a* and b* vary smoothly by +-1.4 around the node (20, -8); target: two
    # colours inside the single node (4, 28).  The split moves every pixel by the same
    # node-to-node step; the remap then gives each axis the target's values inside the node
    y, x = np.mgrid[0:40, 0:60]
    lab = np.stack([55 + 0 * x, 20 + 2.8 * (x / 59 - 0.5), -8 + 2.8 * (y / 39 - 0.5)], -1)
    src = lab_to_rgb_reference(lab).astype(np.float32)
    tgt = np.concatenate([flat((55, 4.9, 27.3), (20, 50)), flat((55, 3.2, 28.6), (20, 50))])
    targets = {1: (4.9, 3.2), 2: (27.3, 28.6)}

    def spread(subbins):
        monkeypatch.setattr(transfer, "WITHIN_NODE_SUBBINS", subbins)
        out = color_transfer([src, tgt], [0, 1], recolor=[0], luminance=False).images[0][0]
        o = rgb_to_lab_reference(out).reshape(-1, 3)
        far, share = [], []
        for ax, (v1, v2) in targets.items():
            d1, d2 = np.abs(o[:, ax] - v1), np.abs(o[:, ax] - v2)
            far.append(np.minimum(d1, d2).max())
            share.append(np.mean(d1 < d2))
        return max(far), share

    far, share = spread(16)
    # every value within one sub-bin (h / 16 = 0.25 ab units) of one of the target's, and
    # the two values in the target's proportions (half each) on each axis
    assert far < 0.26
    assert np.allclose(share, 0.5, atol=0.02)
    far_off, _ = spread(0)  # without the remap the source's spread is kept
    assert far_off > 0.5


def test_no_new_edges_on_a_smooth_gradient():
    y, x = np.mgrid[0:120, 0:160] / 160.0
    lab = np.stack([35 + 30 * x + 10 * y, -20 + 30 * x, -10 + 25 * y], -1)
    yt, xt = np.mgrid[0:90, 0:100] / 100.0
    labt = np.stack([50 + 20 * yt, 10 + 20 * np.sin(2 * xt), 20 - 30 * yt * xt], -1)
    src, tgt = lab_to_rgb_reference(lab), lab_to_rgb_reference(labt)

    def largest_step(img):
        o = rgb_to_lab_reference(img)
        return max(np.abs(np.diff(o, axis=0)).max(), np.abs(np.diff(o, axis=1)).max())

    assert largest_step(src) < 0.2
    raw = color_transfer([src, tgt], [0, 1], recolor=[0], regularization=0).images[0][0]
    out = color_transfer([src, tgt], [0, 1], recolor=[0]).images[0][0]
    # the unregularized split steps by several ab units between neighbours; the default
    # (guided filter) keeps every step between neighbours below 3 ab units (~1.3 JND)
    assert largest_step(raw) > 4.0
    assert largest_step(out) < 3.0


def test_weight_one_returns_the_input():
    imgs = [data.coffee()[::2, ::2], data.chelsea()[::2, ::2]]
    r = color_transfer(imgs, [[1.0, 0.0], [0.0, 1.0]])
    assert np.array_equal(r.images[0][0], imgs[0])
    assert np.array_equal(r.images[1][1], imgs[1])


def test_interpolation_moves_the_fraction_s_of_the_way():
    src = np.concatenate([flat((50, 20, 0), (20, 20)), flat((50, -20, 20), (20, 20))], 1)
    tgt = np.concatenate([flat((50, 0, 40), (20, 40)), flat((50, 16, -16), (20, 40))], 0)
    s = [0.25, 0.5, 0.75]
    r = color_transfer([src, tgt], [[1 - x, x] for x in s], recolor=[0], luminance=False,
                       regularization=0)
    m_src = rgb_to_lab_reference(src)[..., 1:].reshape(-1, 2).mean(0)
    m_tgt = rgb_to_lab_reference(tgt)[..., 1:].reshape(-1, 2).mean(0)
    for b, x in enumerate(s):
        m = rgb_to_lab_reference(r.images[b][0])[..., 1:].reshape(-1, 2).mean(0)
        assert np.abs(m - ((1 - x) * m_src + x * m_tgt)).max() < 0.05
        assert abs(r.barycenters[b].sum() - 1) < 1e-9


def test_three_images_go_to_their_barycenter():
    imgs = [data.coffee()[::4, ::4], data.chelsea()[::4, ::4], data.astronaut()[::4, ::4]]
    r = color_transfer(imgs, [0.2, 0.3, 0.5], luminance=False, regularization=0)
    assert r.converged and r.iterations > 0
    assert set(r.plans) == {(0, "b0"), (1, "b0"), (2, "b0")}
    for p in r.plans.values():
        assert p.converged and p.residual < 1e-9
    # every output's histogram sits closer to the barycenter than its input's did
    grid_bins = r.bins
    for i, out in enumerate(r.images[0]):
        h = node_counts(out, grid_bins).reshape(grid_bins, grid_bins)
        h = h / h.sum()
        assert np.abs(h - r.barycenters[0]).sum() < np.abs(r.histograms[i]
                                                          - r.barycenters[0]).sum()


def test_exact_plan_matches_the_lp_and_integer_split_keeps_rows():
    grid = AbGrid(9)
    rng = np.random.default_rng(0)
    mu, nu = rng.random((9, 9)) * (rng.random((9, 9)) < 0.4), rng.random((9, 9))
    mu, nu = mu / mu.sum(), nu / nu.sum()
    p = exact_plan(mu, nu, grid)
    import ot

    M = ot.dist(p.sources, p.targets)
    assert np.isclose(p.cost, ot.emd2(mu.ravel()[p.rows], nu.ravel()[p.cols], M))
    counts = rng.integers(1, 1000, len(p.rows))
    n = integer_split(p.plan, counts)
    assert np.array_equal(n.sum(1), counts) and n.min() >= 0
    share = p.plan / p.plan.sum(1, keepdims=True) * counts[:, None]
    assert np.abs(n - share).max() < 1.0


def test_split_input_errors():
    img = data.coffee()[::8, ::8]
    with pytest.raises(InputError) as e:
        color_transfer([img, img], mode="nearest")
    assert e.value.field == "mode"
    with pytest.raises(InputError) as e:
        color_transfer([img, img], regularization=-1)
    assert e.value.field == "regularization"


def test_contrast_limited_luminance_map():
    from solvers.color.luminance import limit_slope, luminance_maps

    rng = np.random.default_rng(0)
    centres = (np.arange(400) + 0.5) * 0.25
    src = np.bincount((np.clip(rng.normal(40, 8, 20000), 0, 99.9) / 0.25).astype(int),
                      minlength=400)
    tgt = np.bincount((np.clip(rng.gamma(30.0, 1.7, 20000), 0, 99.9) / 0.25).astype(int),
                      minlength=400)
    exact = luminance_maps(np.stack([src, tgt]), np.array([[0.0, 1.0]]))[0, 0]
    assert limit_slope(exact, src, float("inf")) is exact  # the exact map stays available
    w = src / src.sum()
    occ = np.flatnonzero(src)
    slope_exact = np.diff(exact[occ]) / np.diff(centres[occ])
    g = np.sqrt(w @ (exact - w @ exact) ** 2 / (w @ (centres - w @ centres) ** 2))
    for c in (1.0, 1.25, 2.0):
        out = limit_slope(exact, src, c)
        assert 0 < out[occ].min() and out[occ].max() < 100  # no clipping on this pair
        slope = np.diff(out[occ]) / np.diff(centres[occ])
        assert np.all(slope >= g / c - 1e-9) and np.all(slope <= g * c + 1e-9)
        assert abs(w @ out - w @ exact) < 1e-9  # the mean L* goes where the exact map sends it
        free = (slope_exact > g / c) & (slope_exact < g * c)  # within the limits: unchanged
        assert np.allclose(slope[free], slope_exact[free])
    affine = np.diff(limit_slope(exact, src, 1.0)[occ]) / np.diff(centres[occ])
    assert np.ptp(affine) < 1e-9  # c = 1: affine


def test_luminance_slope_input_error_and_exact_option():
    img, tgt = data.coffee()[::8, ::8], data.chelsea()[::8, ::8]
    with pytest.raises(InputError) as e:
        color_transfer([img, tgt], luminance_slope=0.5)
    assert e.value.field == "luminance_slope"
    r = color_transfer([img, tgt], [0, 1], recolor=[0], luminance_slope=float("inf"))
    exact = rgb_to_lab_reference(r.images[0][0])[..., 0]
    limited = rgb_to_lab_reference(color_transfer([img, tgt], [0, 1], recolor=[0]
                                                  ).images[0][0])[..., 0]
    assert np.abs(exact - limited).max() > 1.0  # the option changes the L* map


def test_guided_gain_limit_bounds_the_slope_and_keeps_the_window_mean():
    """``max_gain`` clips each window's gain a of D ~ a I + b and refits b on the window's
    means: the filtered field's slope along I is bounded, its mean at the mean I kept."""
    from scipy import ndimage

    from solvers.color import _split_kernels as SK
    from solvers.color.regularize import guided_solve_moments

    rng = np.random.default_rng(0)
    h, w = 12, 16
    I = rng.uniform(0.2, 0.8, (h, w))
    D = 30.0 * I + rng.normal(0, 0.1, (h, w))  # gain 30 per unit of I
    mom = np.zeros((SK.n_moments(1), h, w))
    mom[0], mom[1], mom[2], mom[4], mom[6] = I, I * I, D, I * D, 1.0
    free = guided_solve_moments(mom.copy(), 1, 1e-6, 2)
    capped = guided_solve_moments(mom.copy(), 1, 1e-6, 2, max_gain=5.0)
    assert np.allclose(free[0], 30.0, atol=1.0)  # the limit is what changes the gain
    assert np.allclose(capped[0], 5.0)  # every window's gain was above the limit

    def mean(x):  # the 5 x 5 window mean (radius 2) the filter uses
        return ndimage.uniform_filter(x, 5, mode="nearest")

    # b = window mean of D - 5 * window mean of I, then averaged over the windows
    assert np.allclose(capped[2], mean(mean(D) - 5.0 * mean(I)))
    with pytest.raises(ValueError):
        guided_solve_moments(np.zeros((SK.n_moments(2), h, w)), 2, 1e-6, 2, max_gain=1.0)
