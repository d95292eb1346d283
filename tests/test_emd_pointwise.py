"""d_W^k pointwise distances (thesis §2.5) and distance to features (§2.7)."""

from __future__ import annotations

import numpy as np
import potpourri3d as pp3d
import pytest

from solvers.emd import distance_to_features, earth_movers_distance, pointwise_distances
from solvers.errors import InputError


@pytest.fixture(scope="module")
def woody(shared_mesh):
    return shared_mesh("woody.obj")


def test_dw0_is_a_metric_and_matches_the_w1_particular_flow(woody):
    rng = np.random.default_rng(0)
    x, y = rng.choice(woody.n, 2, replace=False)
    dx = pointwise_distances(woody, int(x)).distances
    dy = pointwise_distances(woody, int(y)).distances
    assert dx.shape == (woody.n,) and dx[x] < 1e-12 and np.all(dx[np.arange(woody.n) != x] > 0)
    # symmetry and the triangle inequality d(x, z) <= d(x, y) + d(y, z) for every z
    assert abs(dx[y] - dy[x]) < 1e-9 * dx[y]
    assert np.all(dx <= dx[y] + dy + 1e-12)
    assert np.all(dy <= dy[x] + dx + 1e-12)
    # d_W^0 is the cost of the particular (gradient) flow of eq. 2.4 between two Diracs
    res = earth_movers_distance(woody, np.eye(woody.n)[x], np.eye(woody.n)[y], max_iter=1,
                                method="weiszfeld", basis="spectral", k=1)
    assert res.value <= dx[y] * (1 + 1e-12)


def test_dwk_decreases_with_k_and_stays_a_metric(woody):
    rng = np.random.default_rng(1)
    source = int(rng.integers(woody.n))
    targets = rng.choice(woody.n, 20, replace=False)
    d0 = pointwise_distances(woody, source, targets=targets).distances
    d5 = pointwise_distances(woody, source, k=5, targets=targets)
    d30 = pointwise_distances(woody, source, k=20, targets=targets)
    assert d5.converged and d30.converged
    assert np.all(d5.distances <= d0 * (1 + 1e-9))
    assert np.all(d30.distances <= d5.distances * (1 + 1e-5))
    assert np.mean(d30.distances) < np.mean(d0)
    # triangle inequality of the quotient seminorm on a triple
    a, b = int(targets[0]), int(targets[1])
    dab = pointwise_distances(woody, a, k=5, targets=np.array([b, source])).distances
    dsa = d5.distances[0]
    assert dab[1] <= dsa * (1 + 1e-5)  # symmetry
    assert d5.distances[1] <= dsa + dab[0] + 1e-5


def test_dw_tends_to_geodesic_ordering(woody):
    """d_W^k with many eigenfunctions correlates with geodesic distance."""
    source = 17
    targets = np.arange(0, woody.n, 15)
    dk = pointwise_distances(woody, source, k=20, targets=targets).distances
    geo = pp3d.MeshHeatMethodDistanceSolver(woody.vertices, woody.faces).compute_distance(source)
    assert np.corrcoef(dk, geo[targets])[0, 1] > 0.95


def test_pointwise_input_errors(woody):
    with pytest.raises(InputError) as err:
        pointwise_distances(woody, woody.n)
    assert err.value.field == "source"
    with pytest.raises(InputError) as err:
        pointwise_distances(woody, 0, k=-1)
    assert err.value.field == "k"


def test_distance_to_a_point_feature_is_geodesic(woody):
    res = distance_to_features(woody, [7], tol=1e-4)
    geo = pp3d.MeshHeatMethodDistanceSolver(woody.vertices, woody.faces).compute_distance(7)
    assert res.converged and res.distances[7] == 0.0
    # measured: mean relative deviation from the heat-method distance 2.9 %
    assert np.abs(res.distances - geo).mean() / geo.mean() < 0.05
    assert np.corrcoef(res.distances, geo)[0, 1] > 0.99


def test_distance_to_several_features(shared_mesh):
    spot = shared_mesh("spot.obj", weld=True)
    feats = [7, 900, 2000]
    res = distance_to_features(spot, feats, tol=1e-3)
    solver = pp3d.MeshHeatMethodDistanceSolver(spot.vertices, spot.faces)
    geo = solver.compute_distance_multisource(feats)
    assert np.all(res.distances[feats] == 0.0)
    # measured: 1.9 % mean relative deviation from the heat-method distance to the set
    assert np.abs(res.distances - geo).mean() / geo.mean() < 0.05
