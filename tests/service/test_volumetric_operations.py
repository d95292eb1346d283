"""POST /v1/domains/{id}/volumetric-distances and volumetric-paths (thesis §2.6).

Ground truth: the W1 distance between the mean value coordinates of two points is checked
against the transport LP with exact polyhedral geodesic costs (POT, tvb-gdist); the
Euclidean distance is a lower bound (linear functions are feasible potentials)."""

from __future__ import annotations

import io

import gdist
import numpy as np
import ot
import pytest
import trimesh
from PIL import Image
from service_testing import assert_error, job_result, upload_mesh

from service.export import parse_glb
from service.operations.volumetric import VolumetricDistanceValues, VolumetricPathValues
from solvers import TriangleMesh
from solvers.emd import mean_value_coordinates


@pytest.fixture
def capsule(client, tmp_path):
    c = trimesh.creation.capsule(height=1.0, radius=0.5, count=[12, 12])
    path = tmp_path / "capsule.obj"
    path.write_text(trimesh.exchange.obj.export_obj(c))
    mesh = TriangleMesh(c.vertices, c.faces)
    return upload_mesh(client, path).json()["id"], mesh


def test_distances_match_the_exact_lp_and_bound_the_euclidean(client, capsule):
    cid, mesh = capsule
    points = [[0.1, 0.0, 0.0], [0.0, 0.2, 0.5], [0.3, 0.3, 0.9], [0.0, -0.3, -0.6]]
    body = {"source": [0.0, 0.0, 0.0], "points": points, "units": "input"}
    _, res = job_result(client, client.post(f"/v1/domains/{cid}/volumetric-distances?wait=60",
                                             json=body))
    v = res["values"]
    VolumetricDistanceValues.model_validate(v)
    assert v["converged"] and v["solves"] == 4 and v["slice"] is None
    scale = mesh.length_scale
    W = mean_value_coordinates(mesh, np.vstack([[0.0, 0.0, 0.0], points]) / scale)
    D = gdist.local_gdist_matrix(mesh.vertices.astype(np.float64),
                                 mesh.faces.astype(np.int32), max_distance=1e9).toarray()
    for j, d in enumerate(v["distances"]):
        diff = W[0] - W[j + 1]
        pos, neg = np.clip(diff, 0, None), np.clip(-diff, 0, None)
        lp = pos.sum() * ot.emd2(pos / pos.sum(), neg / neg.sum(), D)
        assert d == pytest.approx(lp, rel=0.06)  # measured: Beckmann 1-4 % below the LP
        euclid = np.linalg.norm(points[j]) / scale
        assert v["euclidean"][j] == pytest.approx(euclid, rel=1e-6)
        assert d >= euclid * (1 - 1e-6)
    assert v["min_ratio"] >= 1 - 1e-6


def test_slice_png_and_glb(client, capsule):
    cid, _ = capsule
    body = {"source": [0.0, 0.0, 0.0], "units": "input",
            "slice": {"axis": "x", "offset": 0.5, "resolution": 10}}
    job, res = job_result(client, client.post(f"/v1/domains/{cid}/volumetric-distances?wait=60",
                                              json=body))
    s = res["values"]["slice"]
    assert s["axes"] == ["y", "z"] and s["coordinate"] == pytest.approx(0.0, abs=1e-9)
    rows, cols = s["shape"]
    assert cols == 10 and rows == 5  # the capsule is twice as long along z as wide along y
    sd = np.asarray(res["arrays"]["slice_distances"])
    inside = np.asarray(res["arrays"]["slice_inside"], bool)
    assert sd.shape == (rows, cols) and 0.3 < inside.mean() < 0.9
    # the distance grows away from the source, at the centre of the slice
    assert sd[rows // 2, cols // 2] == pytest.approx(sd.min())
    assert sd[0, 0] > 2 * sd[rows // 2, cols // 2 + 1]
    png = client.get(f"/v1/jobs/{job}/files/slice.png")
    assert png.status_code == 200 and png.headers["content-type"].startswith("image/png")
    assert np.asarray(Image.open(io.BytesIO(png.content))).shape[2] == 3
    doc, _ = parse_glb(client.get(f"/v1/jobs/{job}/result.glb").content)
    assert [n["name"] for n in doc["nodes"]] == ["surface", "slice"]


def test_descent_path_follows_the_axis_to_the_target(client, capsule):
    """Between two points on the capsule's axis the descent stays on the axis (symmetry)."""
    cid, _ = capsule
    body = {"start": [0.0, 0.0, -0.6], "target": [0.0, 0.0, 0.6], "units": "input",
            "step": 0.1, "max_iter": 40}
    job, res = job_result(client, client.post(f"/v1/domains/{cid}/volumetric-paths?wait=60",
                                              json=body))
    v = res["values"]
    VolumetricPathValues.model_validate(v)
    assert v["converged"] and v["decreasing"] and v["final_distance"] == 0.0
    P = np.asarray(res["arrays"]["points"])
    np.testing.assert_allclose(P[0], body["start"]) and np.testing.assert_allclose(
        P[-1], body["target"])
    assert np.abs(P[:, :2]).max() < 0.02
    assert v["length"] == pytest.approx(v["straight"], rel=0.02)
    doc, _ = parse_glb(client.get(f"/v1/jobs/{job}/result.glb").content)
    assert [n["name"] for n in doc["nodes"]] == ["surface", "surface lines"]
    png = np.asarray(Image.open(io.BytesIO(client.get(f"/v1/jobs/{job}/files/path.png")
                                           .content)))
    red = (png[..., 0] > 180) & (png[..., 1] < 80)
    assert red.sum() > 50  # the path is drawn


@pytest.mark.parametrize("route, body, field", [
    ("volumetric-distances", {"source": [0, 0, 0]}, "points"),
    ("volumetric-distances", {"source": [0, 0]}, "source"),
    ("volumetric-distances", {"source": [0, 0, 0], "points": [[0, 0, "x"]]}, "points"),
    ("volumetric-distances", {"source": [0, 0, 0], "slice": {"resolution": 1}},
     "slice.resolution"),
    ("volumetric-paths", {"start": [0, 0, 0], "target": [0, 0, 1], "step": -1}, "step"),
    ("volumetric-paths", {"start": [0, 0, 0], "target": [0, 0, 1], "max_iter": 0},
     "max_iter"),
])
def test_bad_input_is_refused_at_submission(client, capsule, route, body, field):
    cid, _ = capsule
    assert_error(client.post(f"/v1/domains/{cid}/{route}", json=body), 422, field)


def test_open_meshes_are_refused(client, tmp_path):
    grid = trimesh.creation.box().subdivide()
    open_mesh = trimesh.Trimesh(grid.vertices, grid.faces[2:])
    path = tmp_path / "open.obj"
    path.write_text(trimesh.exchange.obj.export_obj(open_mesh))
    mid = upload_mesh(client, path).json()["id"]
    r = client.post(f"/v1/domains/{mid}/volumetric-paths",
                    json={"start": [0, 0, 0], "target": [0, 0, 0.1]})
    assert_error(r, 422, "domain_id", "unsupported_operation")


def test_far_points_are_refused(client, capsule):
    cid, _ = capsule
    r = client.post(f"/v1/domains/{cid}/volumetric-distances",
                    json={"source": [0, 0, 0], "points": [[1e9, 0, 0]], "units": "input"})
    assert_error(r, 422, "points")
    r = client.post(f"/v1/domains/{cid}/volumetric-paths",
                    json={"start": [0, 0, 0], "target": [0, 0, -1e9], "units": "input"})
    assert_error(r, 422, "target")


def test_cost_and_memory_estimates_count_the_points(make_client, tmp_path):
    """One W1 solve per point: the job's cost (its queue) and memory (413) grow with them."""
    c = trimesh.creation.capsule(height=1.0, radius=0.5, count=[12, 12])
    path = tmp_path / "capsule.obj"
    path.write_text(trimesh.exchange.obj.export_obj(c))
    client = make_client(long_job_cost=1e6)
    cid = upload_mesh(client, path).json()["id"]
    one = {"source": [0, 0, 0], "points": [[0.1, 0, 0]], "units": "input"}
    r = client.post(f"/v1/domains/{cid}/volumetric-distances?wait=30", json=one)
    assert r.json()["queue"] == "short", r.text
    many = {**one, "points": [[0.1, 0, 0]] * 20}
    r = client.post(f"/v1/domains/{cid}/volumetric-distances?wait=30", json=many)
    assert r.json()["queue"] == "long", r.text  # 20 x 450 x 146 vertices > 1e6
    small = make_client(job_memory_bytes=2**20, data_dir=tmp_path / "small")
    cid = upload_mesh(small, path).json()["id"]
    assert small.post(f"/v1/domains/{cid}/volumetric-distances", json=one).status_code == 200
    crowd = {**one, "points": [[0.1, 0, 0]] * 200}  # their coordinates' temporaries: ~14 MB
    assert_error(small.post(f"/v1/domains/{cid}/volumetric-distances", json=crowd), 413,
                 "points")
