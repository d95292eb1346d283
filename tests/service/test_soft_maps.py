"""POST /v1/soft-maps: a global operation between two uploaded meshes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from service_testing import assert_error, upload_mesh

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
    row = client.get(f"/v1/jobs/{job['id']}/arrays/soft_map/rows/3").json()["values"]
    assert len(row) == 162 and abs(sum(row) - 1.0) < 1e-4
    glb = client.get(f"/v1/jobs/{job['id']}/result.glb")
    assert glb.status_code == 200
    doc, _ = parse_glb(glb.content)
    names = [n["name"] for n in doc["nodes"]]
    targets = [n for n in names if n.startswith("target mu_x") and not n.endswith("lines")]
    assert names[0] == "source" and len(targets) == 2
    assert any(n.endswith("lines") for n in names)  # momentum vectors


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
    small = make_client(data_dir=tmp_path / "small", job_memory_bytes=2**20)
    a2 = upload_mesh(small, _sphere_obj(tmp_path, "c.obj")).json()["id"]
    assert_error(small.post("/v1/soft-maps", json={**body, "source_id": a2, "target_id": a2,
                                                   "samples": 160}), 413, "samples")
