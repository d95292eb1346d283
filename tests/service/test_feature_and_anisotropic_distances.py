"""POST .../feature-distances (Fig. 2.14) and .../anisotropic-distances (Fig. 2.15).

Ground truth: distances to features against exact polyhedral geodesics (tvb-gdist);
anisotropic W1 against closed forms on a flat square (a constant metric M moves a Dirac
from p to q at cost |M (p - q)|; weights depending on x alone integrate along the straight
path) and against the isotropic distance on a sphere, whose curvature weights are constant.
"""

from __future__ import annotations

import gdist
import numpy as np
import pytest
import trimesh
from service_testing import assert_error, job_result, upload_arrays

from service.export import parse_glb
from service.operations.anisotropy import AnisotropicDistanceValues
from service.operations.features import FeatureDistanceValues
from solvers import TriangleMesh
from solvers.emd.feature_curves import feature_set


@pytest.fixture
def ball(client, tmp_path):
    s = trimesh.creation.icosphere(subdivisions=3)
    return upload_arrays(client, tmp_path, s.vertices, s.faces, "ball.obj"), TriangleMesh(
        s.vertices, s.faces)


@pytest.fixture
def square(client, tmp_path):
    n = 21
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = (idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(),
                  idx[1:, :-1].ravel())
    v, f = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)], np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    return upload_arrays(client, tmp_path, v, f, "square.obj"), TriangleMesh(v, f)


def test_feature_distances_match_exact_geodesics(client, ball):
    bid, mesh = ball
    body = {"vertices": [0], "curves": [{"waypoints": [100, 300, 500], "closed": True}]}
    job, res = job_result(client, client.post(f"/v1/domains/{bid}/feature-distances?wait=60",
                                               json=body))
    v, a = res["values"], res["arrays"]
    FeatureDistanceValues.model_validate(v)
    feats = feature_set(mesh, [0], [([100, 300, 500], True)])
    assert v["n_features"] == len(feats) and a["features"] == feats.tolist()
    exact = gdist.compute_gdist(mesh.vertices.astype(np.float64), mesh.faces.astype(np.int32),
                                source_indices=feats.astype(np.int32))
    d = np.asarray(a["distances"])
    assert v["converged"] and v["unreachable"] == 0
    # measured on this 642-vertex sphere: 4.3 % mean error, 9.7 % of the largest at most
    assert np.abs(d - exact).mean() < 0.06 * exact.mean()
    assert np.abs(d - exact).max() < 0.12 * exact.max()
    glb = client.get(f"/v1/jobs/{job}/result.glb")
    assert glb.status_code == 200 and b"_DISTANCES" in glb.content


@pytest.mark.parametrize("body, field", [
    ({}, "vertices"),
    ({"vertices": [10**6]}, "vertices"),
    ({"curves": [{"waypoints": [1]}]}, "curves[0].waypoints"),
    ({"curves": [{"waypoints": [1, 10**6]}]}, "curves[0].waypoints"),
    ({"vertices": [1], "method": "ipm", "basis": "full"}, "basis"),
])
def test_feature_distances_refuse_bad_input(client, ball, body, field):
    assert_error(client.post(f"/v1/domains/{ball[0]}/feature-distances", json=body), 422,
                 field)


def _nearest(mesh, fraction):
    v = mesh.vertices[:, :2]
    target = v.min(0) + np.asarray(fraction) * np.ptp(v, axis=0)
    return int(np.argmin(np.linalg.norm(v - target, axis=1)))


def test_matrix_weights_give_the_closed_form(client, square):
    sid, mesh = square
    p, q = _nearest(mesh, (0.3, 0.2)), _nearest(mesh, (0.6, 0.8))
    M = [[3.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    body = {"mu0": {"indices": [p], "masses": [1.0]}, "mu1": {"indices": [q], "masses": [1.0]},
            "face_weights": [M] * mesh.n_faces}
    job, res = job_result(client, client.post(f"/v1/domains/{sid}/anisotropic-distances?wait=60",
                                               json=body))
    v = res["values"]
    AnisotropicDistanceValues.model_validate(v)
    exact = float(np.linalg.norm(np.asarray(M) @ (mesh.vertices[p] - mesh.vertices[q])))
    assert v["weights"] == "matrix" and v["method"] == "ipm" and v["converged"]
    assert v["value"] == pytest.approx(exact, rel=2e-3)
    assert v["lower_bound"] <= v["value"] and v["weight_range"] == pytest.approx([3.0, 3.0])
    assert np.shape(res["arrays"]["flow"]) == (mesh.n_faces, 3)
    doc, _ = parse_glb(client.get(f"/v1/jobs/{job}/result.glb").content)
    assert any("flow" in n["name"] for n in doc["nodes"])


def test_scalar_weights_integrate_along_the_path(client, square):
    sid, mesh = square
    p, q = _nearest(mesh, (0.2, 0.5)), _nearest(mesh, (0.8, 0.5))
    xs = mesh.vertices[:, 0]
    middle = 0.5 * (xs.min() + xs.max())
    w = np.where(mesh.vertices[mesh.faces].mean(axis=1)[:, 0] > middle, 3.0, 1.0)
    body = {"mu0": {"indices": [p], "masses": [1.0]}, "mu1": {"indices": [q], "masses": [1.0]},
            "face_weights": w.tolist()}
    _, res = job_result(client, client.post(f"/v1/domains/{sid}/anisotropic-distances?wait=60",
                                             json=body))
    exact = (middle - mesh.vertices[p, 0]) + 3.0 * (mesh.vertices[q, 0] - middle)
    assert res["values"]["value"] == pytest.approx(exact, rel=2e-3)
    assert res["values"]["weights"] == "scalar"


def test_curvature_weights_on_a_sphere_scale_the_distance(client, ball):
    bid, _ = ball
    pair = {"mu0": {"indices": [0], "masses": [1.0]}, "mu1": {"indices": [200], "masses": [1]}}
    _, iso = job_result(client, client.post(f"/v1/domains/{bid}/distances?wait=60",
                                             json={**pair, "metric": "w1"}))
    _, res = job_result(client, client.post(f"/v1/domains/{bid}/anisotropic-distances?wait=60",
                                             json={**pair, "curvature": {"strength": 2.0}}))
    v = res["values"]
    assert v["weights"] == "curvature" and min(v["weight_range"]) > 2.9
    assert v["value"] == pytest.approx(3.0 * iso["values"]["value"], rel=0.035)


@pytest.mark.parametrize("change, field", [
    ({}, "face_weights"),
    ({"face_weights": [1.0, 2.0]}, "face_weights"),
    ({"face_weights": "matrices-collapsing"}, "face_weights"),
    ({"curvature": {"strength": -1}}, "curvature.strength"),
    ({"curvature": {"strength": 1}, "basis": "spectral"}, "k"),
    ({"curvature": {"strength": 1}, "method": "ipm", "basis": "full"}, "basis"),
])
def test_anisotropic_distances_refuse_bad_input(client, square, change, field):
    sid, mesh = square
    if change.get("face_weights") == "matrices-collapsing":  # kills y on the plane
        change = {"face_weights": [[[1, 0, 0], [0, 0, 0], [0, 0, 1]]] * mesh.n_faces}
    body = {"mu0": {"vertex": 0, "radius": 0.2}, "mu1": {"vertex": 200, "radius": 0.2},
            **change}
    assert_error(client.post(f"/v1/domains/{sid}/anisotropic-distances", json=body), 422,
                 field)
