"""POST /v1/soft-maps: a global operation between two uploaded meshes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from service_testing import assert_error, assert_has_result, upload_mesh
from shared_meshes import MESHES_DIR

from service.export import parse_glb


def _sphere_obj(tmp_path, name, subdivisions=2, scale=(1.0, 1.0, 1.0)):
    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    s.vertices = s.vertices * np.asarray(scale)
    path = tmp_path / name
    path.write_text(trimesh.exchange.obj.export_obj(s))
    return path


@pytest.fixture
def pair(client, tmp_path):
    a = upload_mesh(client, _sphere_obj(tmp_path, "a.obj")).json()["id"]
    b = upload_mesh(client, _sphere_obj(tmp_path, "b.obj", scale=(1.2, 1.0, 0.8))).json()["id"]
    return a, b


BODY = {"landmarks": [{"source": 0, "target": 0}, {"source": 40, "target": 40}],
        "samples": 60, "k": 20, "max_iter": 20, "show_vertices": [5, 100]}


def test_soft_map_job_values_rows_and_glb(client, pair):
    a, b = pair
    r = client.post("/v1/soft-maps?wait=60", json={"source_id": a, "target_id": b, **BODY})
    assert r.status_code in (200, 201, 202), r.text
    job = r.json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    values = result["values"]
    assert len(values["correspondence"]) == 162
    assert values["energies"]["bijectivity"] >= 1.0 - 1e-6  # Cauchy-Schwarz at unit area
    assert values["energies"]["dirichlet"] > 0 and values["samples"] == 60
    assert (values["source_id"], values["target_id"]) == (a, b)  # the viewer reads these
    # Solved over a coarse target ("auto": about 60 points), stored coarse with the
    # prolongation; a row asked for is prolonged to every target vertex.
    assert 50 <= values["target_points"] <= 70
    arrays = result["arrays"]
    assert "soft_map" not in arrays
    assert np.shape(arrays["soft_map_coarse"]) == (60, values["target_points"])
    assert np.shape(arrays["prolongation_indices"])[0] == 162
    row = client.get(f"/v1/jobs/{job['id']}/arrays/soft_map/rows/3").json()["values"]
    assert len(row) == 162 and abs(sum(row) - 1.0) < 1e-4
    weights = np.asarray(arrays["prolongation_weights"])
    coarse = np.asarray(arrays["soft_map_coarse"][3])
    np.testing.assert_allclose(row, (weights * coarse[np.asarray(
        arrays["prolongation_indices"])]).sum(1), rtol=1e-5, atol=1e-9)
    assert_error(client.get(f"/v1/jobs/{job['id']}/arrays/soft_map/rows/60"), 422, "row")
    glb = client.get(f"/v1/jobs/{job['id']}/result.glb")
    assert glb.status_code == 200
    doc, _ = parse_glb(glb.content)
    names = [n["name"] for n in doc["nodes"]]
    targets = [n for n in names if n.startswith("target mu_x") and not n.endswith("lines")]
    assert names[0] == "source" and len(targets) == 2
    assert any(n.endswith("lines") for n in names)  # momentum vectors
    assert not any("density" in n for n in names)  # density copies only on request
    # b(y) (eq. 4.5) and the Dirichlet density per source vertex, as one-row arrays.
    energies = values["energies"]
    b = client.get(f"/v1/jobs/{job['id']}/arrays/bijectivity_density/rows/0").json()["values"]
    assert len(b) == 162 and energies["bijectivity_density"]["array"] == "bijectivity_density"
    assert min(b) == pytest.approx(energies["bijectivity_density"]["min"])
    assert max(b) == pytest.approx(energies["bijectivity_density"]["max"])
    assert energies["bijectivity_density"]["mean"] == pytest.approx(1.0, abs=1e-4)
    e = client.get(f"/v1/jobs/{job['id']}/arrays/dirichlet_vertex_density/rows/0").json()
    assert len(e["values"]) == 162 and min(e["values"]) >= 0
    # The source has unit area: the density integrates (= its mean) to the energy.
    assert energies["dirichlet_density"]["mean"] == pytest.approx(energies["dirichlet"],
                                                                  rel=1e-4)
    assert values["sinkhorn"] is None


def test_soft_map_sinkhorn_refinement_and_density_glb(client, pair):
    a, b = pair
    body = {"source_id": a, "target_id": b, **BODY, "refine": "sinkhorn",
            "glb_densities": ["bijectivity", "dirichlet"], "show_vertices": [5]}
    job = client.post("/v1/soft-maps?wait=60", json=body).json()
    assert job["state"] == "succeeded", job
    values = client.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()["values"]
    sk = values["sinkhorn"]
    assert sk["iterations"] >= 1 and sk["residual"] < sk["initial_residual"]
    doc, _ = parse_glb(client.get(f"/v1/jobs/{job['id']}/result.glb").content)
    names = [n["name"] for n in doc["nodes"]]
    assert "target bijectivity density" in names and "source dirichlet density" in names
    node = doc["nodes"][names.index("target bijectivity density")]
    mesh = doc["meshes"][node["mesh"]]
    attrs = mesh["primitives"][0]["attributes"]
    assert "COLOR_0" in attrs and any("BIJECTIVITY" in k.upper() for k in attrs)
    lo, hi = mesh["extras"]["value_range"]
    assert lo == pytest.approx(values["energies"]["bijectivity_density"]["min"], rel=1e-5)
    assert hi == pytest.approx(values["energies"]["bijectivity_density"]["max"], rel=1e-5)


def test_soft_map_refuses_bad_input_naming_the_field(client, pair, make_client, meshes_dir,
                                                     tmp_path):
    a, b = pair
    body = {"source_id": a, "target_id": b, **BODY}
    bad = {**body, "landmarks": [{"source": 0, "target": 999}]}
    assert_error(client.post("/v1/soft-maps", json=bad), 422, "landmarks[0].target")
    bad = {**body, "landmarks": [{"source": 5000, "target": 0}]}
    assert_error(client.post("/v1/soft-maps", json=bad), 422, "landmarks[0].source")
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4]}).json()["id"]
    assert_error(client.post("/v1/soft-maps", json={**body, "target_id": grid}), 422,
                 "target_id")
    two = trimesh.util.concatenate([trimesh.creation.icosphere(1),
                                    trimesh.creation.icosphere(1).apply_translation([3, 0, 0])])
    path = tmp_path / "two.obj"
    path.write_text(trimesh.exchange.obj.export_obj(two))
    multi = upload_mesh(client, path).json()["id"]
    assert_error(client.post("/v1/soft-maps", json={**body, "source_id": multi}), 422,
                 "source_id")
    assert_error(client.post("/v1/soft-maps", json={**body, "target_id": multi}), 422,
                 "target_id")
    assert_error(client.post("/v1/soft-maps", json={**body, "source_id": grid}), 422,
                 "source_id")
    bad = {**body, "landmarks": [{"source": 0, "target": 0}, {"source": 40, "target": 162}]}
    assert_error(client.post("/v1/soft-maps", json=bad), 422, "landmarks[1].target")
    bad = {**body, "landmarks": [{"source": 0, "target": 0}, {"source": 0, "target": 40}]}
    assert_error(client.post("/v1/soft-maps", json=bad), 422, "landmarks")
    assert_error(client.post("/v1/soft-maps", json={**body, "show_vertices": [162]}), 422,
                 "show_vertices[0]")
    assert_error(client.post("/v1/soft-maps", json={**body, "top_k": 163}), 422, "top_k")
    assert_error(client.post("/v1/soft-maps", json={**body, "target_id": "d" + "0" * 20}),
                 404, "target_id")
    small = make_client(data_dir=tmp_path / "small", job_memory_bytes=2**20)
    a2 = upload_mesh(small, _sphere_obj(tmp_path, "c.obj")).json()["id"]
    assert_error(small.post("/v1/soft-maps", json={**body, "source_id": a2, "target_id": a2,
                                                   "samples": 160}), 413, "samples")


def test_soft_map_full_resolution_on_request(client, pair):
    a, b = pair
    body = {"source_id": a, "target_id": b, **BODY, "target_points": None, "max_iter": 5,
            "refine": "none"}
    job = assert_has_result(client.post("/v1/soft-maps?wait=60", json=body).json())
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    assert result["values"]["target_points"] is None
    assert np.shape(result["arrays"]["soft_map"]) == (60, 162)
    assert "soft_map_coarse" not in result["arrays"]
    row = client.get(f"/v1/jobs/{job['id']}/arrays/soft_map/rows/3").json()["values"]
    assert row == pytest.approx(result["arrays"]["soft_map"][3])
    bad = {**body, "target_points": 3}
    assert_error(client.post("/v1/soft-maps", json=bad), 422, "target_points")


def test_soft_map_of_the_tosca_pair_with_defaults_within_the_wait(client):
    """The cat/lion pair with the defaults (1,024 samples over a coarse target of about as
    many points) inside ``?wait=60``, from cold domains."""
    pairs = MESHES_DIR / "pairs"
    cat = upload_mesh(client, pairs / "cat-00.off", weld="false").json()["id"]
    lion = upload_mesh(client, pairs / "lion-00.off", weld="false").json()["id"]
    landmarks = np.loadtxt(pairs / "cat-lion-landmarks.txt", dtype=np.int64)[:5]
    body = {"source_id": lion, "target_id": cat,
            "landmarks": [{"source": int(lv), "target": int(cv)} for cv, lv in landmarks]}
    job = client.post("/v1/soft-maps?wait=60", json=body).json()
    assert job["state"] == "succeeded", job
    values = client.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()["values"]
    assert values["samples"] == 1024 and values["converged"]
    assert abs(values["target_points"] - 1024) <= 16
    truth = np.loadtxt(pairs / "lion-to-cat.txt", dtype=np.int64)
    # Exact vertex hits of the approximate ground truth (the benchmark scores geodesic
    # error; here a cheap check that the map is the right one, not a flip).
    corr = np.asarray(values["correspondence"])
    cat_mesh = trimesh.load(pairs / "cat-00.off", process=False)
    miss = np.linalg.norm(cat_mesh.vertices[corr] - cat_mesh.vertices[truth], axis=1)
    scale = np.sqrt(cat_mesh.area)
    assert np.median(miss) / scale < 0.03
