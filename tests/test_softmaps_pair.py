"""The real pair: TOSCA lion -> cat with 5 landmarks (../shared/meshes/pairs, see its README).

Score: mean geodesic error on the cat between the extracted and the ground-truth vertex,
divided by sqrt(cat area) (the cat is loaded at unit area).  Smaller settings than the
benchmark (bench/softmaps.py) so the test stays short.
"""

from __future__ import annotations

import numpy as np
import pytest
from shared_meshes import MESHES_DIR

from solvers import load_mesh
from solvers.softmaps import soft_map
from solvers.softmaps.descriptors import geodesic_distances_from

PAIRS = MESHES_DIR / "pairs"
# Held-out landmarks, geodesic miss on the unit-area cat: measured median 0.020, largest
# 0.077 (128 samples, defaults); the mean error of the whole map is ~0.020.
HELD_OUT_MEDIAN = 0.04
HELD_OUT_MAX = 0.12


@pytest.fixture(scope="module")
def pair():
    # weld=False keeps the files' vertex order, which the ground truth indexes.
    cat = load_mesh(PAIRS / "cat-00.off", weld=False)
    lion = load_mesh(PAIRS / "lion-00.off", weld=False)
    gt = np.loadtxt(PAIRS / "lion-to-cat.txt", dtype=np.int64)
    landmarks = np.loadtxt(PAIRS / "cat-lion-landmarks.txt", dtype=np.int64)
    return cat, lion, gt, landmarks  # the first 5 are given, the other 15 held out


def _error(cat, gt, corr, picks):
    """Mean geodesic error over ``picks`` lion vertices (heat-method distances on the cat)."""
    d = geodesic_distances_from(cat, np.unique(gt[picks]))
    column = {int(g): j for j, g in enumerate(np.unique(gt[picks]))}
    return float(np.mean([d[corr[i], column[int(gt[i])]] for i in picks]))


def test_lion_to_cat_with_five_landmarks(pair):
    cat, lion, gt, landmarks = pair
    res = soft_map(lion, cat, landmarks[:5, ::-1], samples=128)
    assert res.soft_map.shape == (128, res.target_points)  # the coarse target's points
    assert abs(res.target_points - 128) <= 4
    rows = res.target_rows()
    assert rows.shape == (128, cat.n) and np.isfinite(res.residual)
    np.testing.assert_allclose(rows.sum(axis=1), 1.0, atol=1e-4)
    picks = np.arange(0, lion.n, 25)  # 200 lion vertices
    unrefined = _error(cat, gt, res.sample_correspondence[res.labels], picks)
    refined = _error(cat, gt, res.correspondence, picks)
    # The 128-point coarse target's default gamma (4 h^2 there) blurs the rows: measured
    # 0.193 for the extracted modes here (0.094 over all lion vertices with the full-
    # resolution target, ad hoc); ZoomOut is what makes the map accurate.
    assert unrefined < 0.25
    assert refined < 0.03
    assert refined < unrefined
    # Held-out landmarks (lines 6-20 of the file): geodesic distance on the cat between
    # where the map sends each lion landmark and its cat landmark.
    held = landmarks[5:]
    d = geodesic_distances_from(cat, held[:, 0])
    misses = d[res.correspondence[held[:, 1]], np.arange(len(held))]
    assert np.median(misses) < HELD_OUT_MEDIAN and misses.max() < HELD_OUT_MAX
