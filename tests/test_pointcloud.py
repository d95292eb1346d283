"""PointCloud: the robust point-cloud Laplacian on a real mesh's vertices."""

from __future__ import annotations

import numpy as np
import pytest
from shared_meshes import load_shared_mesh

from solvers.domains import PointCloud, domain_from_arrays
from solvers.errors import DomainError


@pytest.fixture(scope="module")
def spot_cloud():
    mesh = load_shared_mesh("spot.obj")
    return mesh, PointCloud(mesh.to_arrays()["vertices"])


def test_areas_approximate_mesh_areas(spot_cloud):
    mesh, cloud = spot_cloud
    assert cloud.n == mesh.n
    assert np.all(cloud.areas > 0) and cloud.areas.sum() == pytest.approx(1.0, abs=1e-12)
    # Loose: per-point Voronoi-like areas vs lumped mesh areas (measured: median relative
    # error 3.6 %, correlation 0.976), and the total surface area within 2 %.
    rel = np.abs(cloud.areas - mesh.areas) / mesh.areas
    assert np.median(rel) < 0.1
    assert np.corrcoef(cloud.areas, mesh.areas)[0, 1] > 0.95
    assert cloud.length_scale == pytest.approx(mesh.length_scale, rel=0.02)
    np.testing.assert_allclose(cloud.points * cloud.length_scale, mesh.to_arrays()["vertices"])


def test_laplacian_and_kernel(spot_cloud):
    mesh, cloud = spot_cloud
    lap = cloud.laplacian
    scale = abs(lap).max()
    assert abs(lap - lap.T).max() <= 1e-12 * scale
    assert np.abs(lap @ np.ones(cloud.n)).max() <= 1e-10 * scale
    assert cloud.n_components == 1
    t = mesh.mean_edge_length**2
    kernel = cloud.heat_kernel(t)
    rng = np.random.default_rng(0)
    idx = rng.choice(cloud.n, 6, replace=False)
    deltas = np.zeros((cloud.n, 6))
    deltas[idx, np.arange(6)] = 1.0 / cloud.areas[idx]
    y = kernel.apply(deltas)
    assert y.min() >= -1e-12 * y.max()
    np.testing.assert_allclose(cloud.areas @ y, 1.0, rtol=1e-10)
    # Diffusion on the cloud resembles diffusion on the mesh (same t, loosely).
    y_mesh = mesh.heat_kernel(t).apply(np.where(deltas > 0, 1.0 / mesh.areas[:, None], 0.0))
    for j in range(6):
        assert np.corrcoef(y[:, j], y_mesh[:, j])[0, 1] > 0.9


def test_round_trip_and_errors(spot_cloud):
    _, cloud = spot_cloud
    small = PointCloud(cloud.points[:200] * 3.0, n_neighbors=12)
    rebuilt = domain_from_arrays("pointcloud", small.to_arrays(), small.parameters())
    assert rebuilt.content_hash() == small.content_hash()
    assert PointCloud(cloud.points[:200] * 3.0).content_hash() != small.content_hash()
    bad = cloud.points[:50].copy()
    bad[7, 1] = np.nan
    cases = [
        (dict(points=bad), "points"),
        (dict(points=np.zeros((3, 3))), "points"),
        (dict(points=np.zeros((10, 2))), "points"),
        (dict(points=cloud.points[:50], n_neighbors=2), "n_neighbors"),
        (dict(points=cloud.points[:50], n_neighbors=50), "n_neighbors"),
    ]
    for kwargs, field in cases:
        with pytest.raises(DomainError) as info:
            PointCloud(**kwargs)
        assert info.value.field == field
