"""Curves as feature sets (Fig. 2.14): edge paths through waypoints; distances to them."""

from __future__ import annotations

import numpy as np
import pytest

from solvers import InputError
from solvers.emd import distance_to_features
from solvers.emd.feature_curves import curve_vertices, feature_set


def test_curve_follows_mesh_edges_through_its_waypoints(shared_mesh):
    mesh = shared_mesh("cow.obj")
    waypoints = [10, 900, 2000]
    path = curve_vertices(mesh, waypoints, closed=True)
    assert path[0] == path[-1] == 10
    assert {10, 900, 2000} <= set(path.tolist())
    edges = {tuple(sorted(e)) for e in mesh.edges.tolist()}
    steps = list(zip(path[:-1].tolist(), path[1:].tolist(), strict=True))
    assert all(tuple(sorted(s)) in edges for s in steps)
    s = feature_set(mesh, vertices=[5], curves=[(waypoints, False)])
    assert 5 in s and 900 in s and len(s) == len(np.unique(s))


def test_distance_to_a_curve_matches_exact_geodesics(shared_mesh):
    """Distances to the curve's vertices against exact polyhedral geodesics (tvb-gdist)."""
    import gdist

    mesh = shared_mesh("cow.obj")
    feats = feature_set(mesh, curves=[([10, 900, 2000], True)])
    exact = gdist.compute_gdist(mesh.vertices.astype(np.float64),
                                mesh.faces.astype(np.int32),
                                source_indices=feats.astype(np.int32))
    res = distance_to_features(mesh, feats, method="auto", basis="auto")
    err = np.abs(res.distances - exact)
    # measured: 2.7 % mean error, 4.3 % of the largest distance at most
    assert err.mean() < 0.04 * exact.mean()
    assert err.max() < 0.06 * exact.max()


def test_bad_curves_are_refused(shared_mesh):
    mesh = shared_mesh("suzanne.obj")  # several components
    labels = mesh.component_labels
    a = int(np.flatnonzero(labels == 0)[0])
    b = int(np.flatnonzero(labels == 1)[0])
    with pytest.raises(InputError) as err:
        curve_vertices(mesh, [a, b], field="curves[0]")
    assert err.value.field == "curves[0]"
    with pytest.raises(InputError) as err:
        curve_vertices(mesh, [a], field="curves[1]")
    assert err.value.field == "curves[1]"
    with pytest.raises(InputError):
        feature_set(mesh)
