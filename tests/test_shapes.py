"""Shape interpolation (thesis §3.7): voxelize, barycenter of indicators, iso-surface."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import ndimage

from solvers import Grid, InputError
from solvers.convolutional.shapes import (
    iso_surface,
    shaded_view,
    shape_interpolation,
    shape_interpolations,
    voxelize,
)

GAMMA = 0.002


@pytest.fixture(scope="module")
def ball():
    return trimesh.creation.icosphere(subdivisions=3, radius=1.0)


def shifted(mesh, dx):
    out = mesh.copy()
    out.apply_translation([dx, 0.0, 0.0])
    return out


def disk(shape, center, radius):
    h = 1.0 / (max(shape) - 1)
    yy, xx = np.meshgrid(*(h * np.arange(s) for s in shape), indexing="ij")
    return ((yy - center[0]) ** 2 + (xx - center[1]) ** 2 <= radius**2).astype(float)


def assert_closed_surface(result, genus=0):
    mesh = trimesh.Trimesh(result.vertices, result.faces, process=True)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.euler_number == 2 - 2 * genus
    assert mesh.volume > 0  # outward orientation
    np.testing.assert_allclose(mesh.volume, result.enclosed_volume, rtol=1e-9)
    return mesh


def test_voxelize_fills_the_interior(ball):
    vox = voxelize(ball, resolution=24)
    assert vox.grid.shape == (24, 24, 24)
    ind = vox.indicator
    # filled, not a shell: the center node is inside, and the volume is that of the ball
    assert ind[tuple(s // 2 for s in ind.shape)]
    assert abs(vox.volume - ball.volume) < 0.3 * ball.volume
    centroid = vox.origin + vox.scale * vox.grid.points[ind.ravel()].mean(axis=0)
    np.testing.assert_allclose(centroid, ball.center_mass, atol=0.5 * vox.scale / 23)
    # padding: the border layers are empty
    assert not ind[[0, 1, -2, -1]].any() and not ind[:, [0, 1, -2, -1]].any()


def test_interpolating_a_shape_with_itself_returns_it(ball):
    result = shape_interpolation([ball, ball], [0.3, 0.7], gamma=GAMMA, resolution=24)
    assert result.converged
    mesh = assert_closed_surface(result)
    np.testing.assert_allclose(result.target_volume, ball.volume, rtol=1e-12)
    np.testing.assert_allclose(mesh.volume, ball.volume, rtol=1e-3)
    radii = np.linalg.norm(result.vertices - ball.center_mass, axis=1)
    cell = result.scale * result.grid.spacing[0]
    assert np.all(np.abs(radii - 1.0) < 0.75 * cell)
    assert result.volume.shape == result.grid.shape
    np.testing.assert_allclose(result.volume.sum(), 1.0, rtol=1e-9)


@pytest.mark.parametrize("weights, expected_x", [([0.5, 0.5], 1.5), ([0.25, 0.75], 2.25)])
def test_barycenter_of_displaced_balls_is_a_ball_in_between(ball, weights, expected_x):
    result = shape_interpolation([ball, shifted(ball, 3.0)], weights, gamma=GAMMA,
                                 resolution=32)
    assert result.converged
    mesh = assert_closed_surface(result)
    cell = result.scale * result.grid.spacing[0]
    np.testing.assert_allclose(mesh.center_mass, [expected_x, 0.0, 0.0], atol=0.1 * cell)
    np.testing.assert_allclose(mesh.volume, ball.volume, rtol=1e-3)
    extents = mesh.extents
    assert np.ptp(extents) < cell  # round, not smeared along x
    np.testing.assert_allclose(extents, 2.0, atol=cell)


def test_two_dimensional_volumes_give_closed_contours():
    shape = (48, 64)
    a = disk(shape, (0.35, 0.25), 0.15)
    b = disk(shape, (0.35, 0.75), 0.15)
    result = shape_interpolation([a, b], gamma=GAMMA)
    assert result.converged and result.vertices.shape[1] == 2 and result.faces.shape[1] == 2
    # one closed polyline: every vertex has exactly one incoming and one outgoing segment
    n = len(result.vertices)
    np.testing.assert_array_equal(np.bincount(result.faces[:, 0], minlength=n), 1)
    np.testing.assert_array_equal(np.bincount(result.faces[:, 1], minlength=n), 1)
    h = result.grid.spacing[0]
    np.testing.assert_allclose(result.target_volume, h * h * a.sum(), rtol=1e-12)
    np.testing.assert_allclose(result.enclosed_volume, result.target_volume, rtol=1e-3)
    # polygon centroid at the midpoint of the two disk centers
    p, q = result.vertices[result.faces[:, 0]], result.vertices[result.faces[:, 1]]
    cross = p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]
    centroid = ((p + q) * cross[:, None]).sum(axis=0) / (3.0 * cross.sum())
    np.testing.assert_allclose(centroid, [0.35, 0.5], atol=0.1 * h)


def test_iso_surface_matches_a_requested_volume():
    grid = Grid((30, 30, 30))
    pts = grid.points - 0.5
    volume = np.exp(-(pts**2).sum(axis=1) / 0.02).reshape(grid.shape)
    target = 4.0 / 3.0 * np.pi * 0.2**3
    level, verts, faces, enclosed = iso_surface(volume, grid, target)
    np.testing.assert_allclose(enclosed, target, rtol=1e-4)
    radii = np.linalg.norm(verts - 0.5, axis=1)
    np.testing.assert_allclose(radii, 0.2, atol=0.01)
    np.testing.assert_allclose(level, np.exp(-0.04 / 0.02), rtol=0.05)


def test_invalid_inputs_are_refused(ball):
    with pytest.raises(InputError) as err:
        shape_interpolation([np.ones((8, 8)), np.ones((8, 9))], gamma=GAMMA)
    assert err.value.field == "shapes"
    with pytest.raises(InputError) as err:
        shape_interpolation([np.ones((8, 8))] * 2, [1.0, -1.0], gamma=GAMMA)
    assert err.value.field == "weights"
    with pytest.raises(InputError, match="float range") as err:  # sums to inf
        shape_interpolation([np.ones((8, 8))] * 2, [1e308, 1e308], gamma=GAMMA)
    assert err.value.field == "weights"
    with pytest.raises(InputError) as err:
        shape_interpolation([np.ones((8, 8)), -np.ones((8, 8))], gamma=GAMMA)
    assert err.value.field == "shapes"
    with pytest.raises(InputError) as err:
        shape_interpolation([ball, "not a mesh"], gamma=GAMMA)
    assert err.value.field == "file"
    with pytest.raises(InputError) as err:
        voxelize(ball, resolution=4)
    assert err.value.field == "resolution"


def test_real_mesh_interpolated_with_itself(shared_mesh):
    """spot.obj (welded, closed): the self-barycenter's surface encloses the mesh volume, and
    its super-level set lies inside the voxelized input and covers the input's eroded core."""
    spot = shared_mesh("spot.obj")
    exact = trimesh.Trimesh(spot.vertices * spot.length_scale, spot.faces, process=False)
    assert exact.is_watertight
    result = shape_interpolation([spot, spot], gamma=GAMMA, resolution=32)
    assert result.converged
    mesh = assert_closed_surface(result)
    np.testing.assert_allclose(mesh.volume, exact.volume, rtol=1e-3)
    vox = voxelize(spot, frame=(result.grid, result.origin, result.scale))
    inside = result.volume >= result.level
    core = ndimage.binary_erosion(vox.indicator)  # surface voxels stick out of the mesh
    assert (inside & vox.indicator).sum() >= 0.99 * inside.sum()
    assert (inside & core).sum() >= 0.98 * core.sum()
    np.testing.assert_allclose(mesh.center_mass, exact.center_mass,
                               atol=0.5 * result.scale * result.grid.spacing[0])


def test_frames_of_an_interpolation_share_one_grid(ball):
    """Frames t = 0, 1/4, 1/2 between a ball and its translate: centroids move linearly."""
    frames = [[1.0, 0.0], [0.75, 0.25], [0.5, 0.5]]
    results = shape_interpolations([ball, shifted(ball, 3.0)], frames, gamma=GAMMA,
                                   resolution=32)
    assert len(results) == 3 and all(r.converged for r in results)
    assert len({id(r.grid) for r in results}) == 1  # voxelized once
    cell = results[0].scale * results[0].grid.spacing[0]
    for r, (_, t) in zip(results, frames, strict=True):
        mesh = assert_closed_surface(r)
        np.testing.assert_allclose(mesh.center_mass, [3.0 * t, 0.0, 0.0], atol=0.1 * cell)
    with pytest.raises(InputError) as err:
        shape_interpolations([ball, ball], [[1.0, 0.0], [-1.0, 2.0]], gamma=GAMMA,
                             resolution=16)
    assert err.value.field == "weights[1]"


def test_shaded_view_shows_the_silhouette():
    """A ball of radius 0.3 in the unit cube: a disk of that radius, shaded, on white."""
    grid = Grid((40, 40, 40))
    pts = grid.points - 0.5
    inside = (np.linalg.norm(pts, axis=1) <= 0.3).reshape(grid.shape).astype(float)
    image = shaded_view(inside, 0.5, axis=2, pixels=40)
    assert image.shape == (40, 40)
    disk = image < 1.0
    h = 1.0 / 39
    np.testing.assert_allclose(disk.sum() * h * h, np.pi * 0.3**2, rtol=0.05)
    assert image[20, 20] < 1.0 and image[0, 0] == 1.0
    assert image[disk].std() > 0.02  # shaded, not flat
