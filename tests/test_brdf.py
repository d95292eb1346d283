"""BRDF interpolation on the hemisphere (§3.7): the grid domain, its kernel against the
triangulated hemisphere, moving highlights, the entropy bound, the sphere renderer."""

import numpy as np
import pytest

from solvers.convolutional.brdf import (
    bilinear_weights,
    brdf_slices,
    check_material,
    interpolate_brdfs,
    local_maxima,
    peak_direction,
    png_bytes,
    render_spheres,
)
from solvers.convolutional.hemisphere import HemisphereGrid, kernel_discrepancy
from solvers.errors import InputError

BROAD = {"model": "blinn-phong", "exponent": 6}
SHARP = {"model": "ashikhmin-shirley", "nu": 300, "nv": 300}


@pytest.fixture(scope="module")
def grid():
    return HemisphereGrid(20, 40)


@pytest.mark.parametrize("method", ["separable", "geodesic"])
def test_grid_areas_and_kernel_symmetry(method):
    grid = HemisphereGrid(20, 40, method=method)
    assert np.isclose(grid.areas.sum(), 1.0)
    # sin(theta) weights: a cell at theta has area proportional to sin(theta)
    ratio = grid.areas / np.sin(grid.theta)
    np.testing.assert_allclose(ratio, ratio[0])
    K = grid.heat_kernel(1e-3)
    x, y = np.random.default_rng(0).random((2, grid.n))
    a = grid.areas
    # self-adjoint in the a-weighted product, like every heat kernel
    assert np.isclose(a @ (x * K.apply(y)), a @ (y * K.apply(x)), rtol=1e-12)
    assert grid.heat_kernel(1e-3) is K  # cached in the operator store
    np.testing.assert_allclose(K.apply(np.ones(grid.n)), 1.0, atol=1e-10)  # conserves mass


@pytest.mark.parametrize("method", ["separable", "geodesic"])
def test_grid_kernel_close_to_mesh_kernel(method):
    d = kernel_discrepancy(HemisphereGrid(20, 40, method=method), 5e-3)
    # the two diffusions of a Dirac spread alike (RMS geodesic radius within 20 %) ...
    ratio = d.spread[:, 0] / d.spread[:, 1]
    assert np.all(np.abs(ratio - 1.0) < 0.2), ratio
    # ... and overlap mostly (L1 of normalized masses, 2 = disjoint)
    assert np.all(d.l1 < 0.45), d.l1


def test_highlight_moves_instead_of_cross_fading(grid):
    th = np.radians([65.0])
    s_broad, _ = brdf_slices(grid, BROAD, th)
    s_sharp, _ = brdf_slices(grid, SHARP, th)
    t0, t1 = peak_direction(grid, s_broad[0])[0], peak_direction(grid, s_sharp[0])[0]
    cell = 0.5 * np.pi / grid.shape[0]
    assert t1 - t0 > 4 * cell  # the corners' highlights are far apart
    lam = np.linspace(0.0, 1.0, 11)
    W = np.stack([1 - lam, lam], axis=1)
    r = interpolate_brdfs(grid, [BROAD, SHARP], W, th, gamma=2e-3)
    assert r.converged and r.residual <= 1e-4
    bary = np.array([peak_direction(grid, m)[0] for m in r.masses[0]])
    lin = np.array([peak_direction(grid, m)[0] for m in r.linear[0]])
    # barycenters: the peak walks monotonically from one corner's highlight to the other's
    assert np.all(np.diff(bary) >= 0) and np.isclose(bary[0], t0) and np.isclose(bary[-1], t1)
    assert np.max(np.diff(bary)) <= 1.5 * cell
    assert len(set(np.round(bary, 6))) >= 6  # it visits intermediate directions
    assert all(len(local_maxima(grid, m, rel=0.01)) == 1 for m in r.masses[0])  # one lobe
    # linear mix: the peak jumps in one step, and a mixture holds two separate lobes
    assert np.max(np.diff(lin)) > 4 * cell
    assert max(len(local_maxima(grid, m, rel=0.01)) for m in r.linear[0][1:-1]) >= 2
    # the barycenter at 1/2 is one lobe in between, no copy of either corner
    mid = r.masses[0, 5]
    assert t0 < peak_direction(grid, mid)[0] < t1


def test_entropy_bound_respected(grid):
    th = np.radians([30.0, 65.0])
    W = bilinear_weights(1, 3)[:, :2]
    W = W / W.sum(axis=1, keepdims=True)
    plain = interpolate_brdfs(grid, [BROAD, SHARP], W, th, gamma=1e-2)
    bounded = interpolate_brdfs(grid, [BROAD, SHARP], W, th, gamma=1e-2,
                                entropy_bound="inputs")
    assert bounded.converged
    assert np.all(bounded.entropy <= bounded.entropy_bound + 1e-6)
    assert np.any(plain.entropy > bounded.entropy_bound + 1e-3)  # the bound was active
    fixed = interpolate_brdfs(grid, [BROAD, SHARP], W, th, gamma=1e-2, entropy_bound=-1.5)
    assert np.all(fixed.entropy <= -1.5 + 1e-6)


def test_bilinear_weights_and_render():
    grid = HemisphereGrid(12, 32)
    W = bilinear_weights(2, 3)
    assert W.shape == (6, 4) and np.allclose(W.sum(axis=1), 1.0)
    np.testing.assert_allclose(W[0], [1, 0, 0, 0])
    np.testing.assert_allclose(W[-1], [0, 0, 0, 1])
    th = np.radians([0.0, 40.0, 80.0])
    mats = [BROAD, SHARP, {"model": "blinn-phong", "exponent": 40, "kd": 0.3},
            {"model": "ashikhmin-shirley", "nu": 20, "nv": 200, "rd": 0.4}]
    r = interpolate_brdfs(grid, mats, W, th, gamma=4e-3, max_iter=60)
    img = render_spheres(grid, r.masses, r.scale, th, 2, 3, size=32)
    assert img.shape == (64, 96, 3) and img.dtype == np.uint8
    assert img.max() > 200 and img[0, 0].max() == 0  # lit highlights, black background
    tiles = img[:, :, 0].reshape(2, 32, 3, 32).transpose(0, 2, 1, 3).reshape(6, -1)
    assert len({t.tobytes() for t in tiles}) == 6  # every sphere is shaded differently
    assert png_bytes(img)[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_materials_name_the_field(grid):
    with pytest.raises(InputError) as err:
        check_material({"model": "phong"}, "materials[1]")
    assert err.value.field == "materials[1]"
    with pytest.raises(InputError) as err:
        interpolate_brdfs(grid, [BROAD, {"model": "blinn-phong", "exponent": -1}],
                          [[0.5, 0.5]], [0.3], gamma=1e-2)
    assert err.value.field == "materials[1].exponent"
    with pytest.raises(InputError) as err:
        interpolate_brdfs(grid, [BROAD, SHARP], [[0.5, 0.5]], [2.0], gamma=1e-2)
    assert err.value.field == "incoming_theta"
