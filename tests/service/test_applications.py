"""POST /v1/brdf-interpolations and POST /v1/domains/{id}/skeleton-layouts (§3.7)."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh
from PIL import Image
from service_testing import assert_error, upload_mesh

from service.export import parse_glb

BRDF = {"materials": [{"model": "blinn-phong", "exponent": 6},
                      {"model": "ashikhmin-shirley", "nu": 300, "nv": 300}],
        "rows": 1, "cols": 4, "incoming_theta": [30, 65], "n_theta": 12, "n_phi": 32,
        "size": 24, "max_iter": 300}


def test_brdf_interpolation_job_slices_and_png(client):
    r = client.post("/v1/brdf-interpolations?wait=60", json=BRDF)
    assert r.status_code in (200, 201, 202), r.text
    job = r.json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    values = result["values"]
    assert values["converged"] and values["grid"] == [12, 32]
    np.testing.assert_allclose(values["weights"][0], [1, 0])
    peaks = values["peak_theta"][1]  # at 65 degrees: the highlight walks towards the mirror
    assert peaks == sorted(peaks) and peaks[-1] > peaks[0]
    assert np.shape(result["arrays"]["slices"]) == (8, 12 * 32)
    row = client.get(f"/v1/jobs/{job['id']}/arrays/slices/rows/5").json()["values"]
    assert len(row) == 384 and abs(sum(row) - 1.0) < 1e-6
    png = client.get(f"/v1/jobs/{job['id']}/files/spheres.png")
    assert png.status_code == 200 and png.headers["content-type"].startswith("image/png")
    img = np.asarray(Image.open(io.BytesIO(png.content)))
    assert img.shape == (24, 96, 3) and img.max() > 100
    assert client.get(f"/v1/jobs/{job['id']}/files/linear.png").status_code == 200


@pytest.mark.parametrize("change, field", [
    ({"materials": [{"model": "phong"}, {"model": "blinn-phong"}]}, "materials"),
    ({"materials": [{"model": "blinn-phong", "exponent": -1}, {"model": "blinn-phong"}]},
     "materials[0].blinn-phong.exponent"),
    ({"incoming_theta": [60, 30]}, "incoming_theta"),
    ({"weights": [[1, 0]]}, "weights"),
    ({"weights": [[1, -1]] * 4}, "weights[0]"),
    ({"weights": [[1, 0]] * 3 + [[1e308, 1e308]]}, "weights[3]"),  # the sum overflows
    ({"light": [0, 0, 0]}, "light"),
    ({"gamma": 1e3}, "gamma"),
    ({"entropy_bound": -4.8e16}, "entropy_bound"),  # below the spec's bound
    ({"entropy_bound": -12.0}, "entropy_bound"),  # above it, below this grid's point mass
])
def test_brdf_interpolation_refuses_bad_input(client, change, field):
    r = client.post("/v1/brdf-interpolations", json={**BRDF, **change})
    assert_error(r, 422, field)


def test_brdf_interpolation_refuses_oversized_grids(client):
    r = client.post("/v1/brdf-interpolations", json={**BRDF, "n_theta": 64, "n_phi": 128})
    assert_error(r, 413, "n_phi")


def test_the_specs_entropy_bound_is_below_every_allowed_grids_point_mass():
    """The spec's ``minimum`` of ``entropy_bound`` refuses only bounds no grid can reach:
    every grid the service accepts (n_theta * n_phi up to MAX_HEMISPHERE_POINTS, the
    finest for each n_theta, either kernel) has its point-mass entropy above it."""
    from service.operations.applications import ENTROPY_BOUND_MIN, MAX_HEMISPHERE_POINTS
    from solvers.convolutional.hemisphere import HemisphereGrid

    lowest = min(float(np.log(HemisphereGrid(nt, min(256, MAX_HEMISPHERE_POINTS // nt),
                                             method=m).areas.min()))
                 for nt in range(4, 65) for m in ("separable", "geodesic"))
    assert ENTROPY_BOUND_MIN <= lowest < ENTROPY_BOUND_MIN + 0.5


@pytest.fixture
def capsule_id(client, tmp_path):
    c = trimesh.creation.capsule(height=2.0, radius=0.35, count=[16, 16])
    path = tmp_path / "capsule.obj"
    path.write_text(trimesh.exchange.obj.export_obj(c))
    return upload_mesh(client, path).json()["id"]


def test_skeleton_layout_job_positions_and_glb(client, capsule_id):
    body = {"n_nodes": 5, "edges": [[0, 1], [1, 2], [2, 3], [3, 4]], "units": "input",
            "fixed": [{"node": 0, "position": [0, 0, -1.0]},
                      {"node": 4, "position": [0, 0, 1.0]}]}
    r = client.post(f"/v1/domains/{capsule_id}/skeleton-layouts?wait=60", json=body)
    assert r.status_code in (200, 201, 202), r.text
    job = r.json()
    assert job["state"] == "succeeded", job
    values = client.get(f"/v1/jobs/{job['id']}/result").json()["values"]
    P = np.asarray(values["positions"])
    assert P.shape == (5, 3) and all(values["inside"]) and values["converged"]
    assert np.all(np.diff(P[:, 2]) > 0) and np.all(np.abs(P[:, :2]) < 0.02)
    np.testing.assert_allclose(P[[0, 4]], [[0, 0, -1.0], [0, 0, 1.0]], atol=1e-9)
    glb = client.get(f"/v1/jobs/{job['id']}/result.glb")
    assert glb.status_code == 200
    doc, _ = parse_glb(glb.content)
    names = [n["name"] for n in doc["nodes"]]
    assert names == ["mesh", "mesh lines", "linear", "linear lines"]
    lines = doc["meshes"][1]["primitives"][0]
    assert lines["mode"] == 1  # LINES
    assert doc["accessors"][lines["attributes"]["POSITION"]]["count"] == 2 * 4  # 4 bones


@pytest.mark.parametrize("change, field", [
    ({"edges": [[0, 1], [1, 9]]}, "edges"),
    ({"fixed": [{"node": 7, "position": [0, 0, 0]}]}, "fixed"),
    ({"fixed": [{"node": 0, "position": [0, 0]}]}, "fixed[0].position"),
    ({"edges": [[0, 1], [2, 3]]}, "edges"),  # nodes 2, 3 have no fixed node
    ({"gamma": 1e6}, "gamma"),
])
def test_skeleton_layout_refuses_bad_input(client, capsule_id, change, field):
    body = {"n_nodes": 4, "edges": [[0, 1], [1, 2], [2, 3]],
            "fixed": [{"node": 0, "position": [0, 0, 0]}], **change}
    assert_error(client.post(f"/v1/domains/{capsule_id}/skeleton-layouts", json=body), 422,
                 field)


def test_skeleton_layout_outside_point_fails_naming_the_field(client, capsule_id):
    body = {"n_nodes": 3, "edges": [[0, 1], [1, 2]],
            "fixed": [{"node": 0, "position": [0, 0, 9.0]}]}
    r = client.post(f"/v1/domains/{capsule_id}/skeleton-layouts?wait=60", json=body)
    job = r.json()
    assert job["state"] == "failed" and job["error"]["field"] == "fixed", job


def test_skeleton_layout_needs_a_mesh(client):
    gid = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4]}).json()["id"]
    body = {"n_nodes": 2, "edges": [[0, 1]], "fixed": [{"node": 0, "position": [0, 0, 0]}]}
    r = client.post(f"/v1/domains/{gid}/skeleton-layouts", json=body)
    assert r.status_code == 422 and r.json()["error"]["field"] == "domain_id"
