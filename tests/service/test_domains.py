"""Domain uploads: content ids, summaries, limits and clear 4xx errors."""

from __future__ import annotations

import numpy as np
import pytest
from service_testing import assert_error, upload_mesh

from solvers.domains import Grid, load_mesh


def test_mesh_upload_id_is_content_hash_and_stable(client, meshes_dir):
    path = meshes_dir / "woody.obj"
    first = upload_mesh(client, path)
    assert first.status_code == 201, first.text
    body = first.json()
    mesh = load_mesh(path)
    assert body["id"] == mesh.content_hash()
    assert body["kind"] == "mesh"
    assert body["n"] == mesh.n and body["sizes"]["faces"] == mesh.n_faces
    assert body["genus"] == mesh.genus and body["components"] == mesh.n_components
    assert body["boundary"] == {"loops": len(mesh.boundary_loops), "closed": mesh.is_closed}
    assert first.headers["location"] == f"/v1/domains/{body['id']}"

    again = upload_mesh(client, path)
    assert again.status_code == 200 and again.json()["id"] == body["id"]
    assert client.get(f"/v1/domains/{body['id']}").json()["id"] == body["id"]
    listed = client.get("/v1/domains").json()["domains"]
    assert [d["id"] for d in listed] == [body["id"]]


def test_multi_component_mesh_reports_warning(client, meshes_dir):
    body = upload_mesh(client, meshes_dir / "suzanne.obj").json()
    assert body["components"] > 1
    assert any("components" in w for w in body["warnings"])


def test_json_grid_graph_pointcloud(client):
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [8, 6]})
    assert grid.status_code == 201
    assert grid.json()["id"] == Grid((8, 6)).content_hash()
    assert grid.json()["n"] == 48
    graph = client.post("/v1/domains", json={"kind": "graph", "n_nodes": 4,
                                             "edges": [[0, 1], [1, 2], [2, 3]]})
    assert graph.status_code == 201 and graph.json()["components"] == 1
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(60, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    cloud = client.post("/v1/domains", json={"kind": "pointcloud", "points": pts.tolist(),
                                             "n_neighbors": 8})
    assert cloud.status_code == 201 and cloud.json()["n"] == 60


def test_delete_domain(client):
    gid = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4]}).json()["id"]
    assert client.delete(f"/v1/domains/{gid}").status_code == 204
    assert_error(client.get(f"/v1/domains/{gid}"), 404, "domain_id", "not_found")
    assert_error(client.delete(f"/v1/domains/{gid}"), 404, "domain_id")
    assert_error(client.post(f"/v1/domains/{gid}/barycenters",
                             json={"distributions": [[1.0] * 16]}), 404, "domain_id")
    # Re-uploading restores the same id.
    again = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4]})
    assert again.status_code == 201 and again.json()["id"] == gid


@pytest.mark.parametrize("name,content,field,code", [
    ("empty.obj", b"", "file", "invalid_input"),
    ("junk.obj", bytes(range(256)) * 8, "file", "invalid_mesh"),
    ("junk.ply", b"ply\nformat nonsense\n", "file", "invalid_mesh"),
    ("mesh.xyz", b"v 0 0 0\n", "format", "invalid_input"),
    ("noext", b"v 0 0 0\n", "format", "invalid_input"),
])
def test_bad_mesh_uploads(client, name, content, field, code):
    assert_error(client.post("/v1/domains", files={"file": (name, content)}), 422, field, code)


@pytest.mark.parametrize("body,field", [
    (b'{"kind": "grid", "shape": [4, 4], "bounds": [[0, NaN], [0, 1]]}', "bounds"),
    (b'{"kind": "grid", "shape": [4, 1]}', "shape"),
    (b'{"kind": "grid"}', "shape"),
    (b'{"kind": "torus", "shape": [4]}', "kind"),
    (b'{"kind": "pointcloud", "points": [[0, 0, NaN], [1, 0, 0], [0, 1, 0], [1, 1, 0], '
     b'[0, 0, 1]], "n_neighbors": 3}', "points"),
    (b'{"kind": "graph", "n_nodes": 3, "edges": [[0, 5]]}', "edges"),
    (b'{"kind": "mesh", "vertices": [[0, 0, 0], [1, 0, 0]], "faces": [[0, 1, 2]]}', "faces"),
    (b'{"kind": "grid", "shape": [4, 4]', "body"),
    (b"", "body"),
])
def test_bad_json_domains(client, body, field):
    r = client.post("/v1/domains", content=body, headers={"content-type": "application/json"})
    assert_error(r, 422, field)


def test_malformed_multipart(client):
    r = client.post("/v1/domains", content=b"--x\r\nnonsense",
                    headers={"content-type": "multipart/form-data; boundary=x"})
    assert_error(r, 422, "file")
    r = client.post("/v1/domains", data={"format": "obj"},
                    files={"other": ("a.obj", b"v 0 0 0\n")})
    assert_error(r, 422, "file")


def test_unsupported_media_type(client):
    r = client.post("/v1/domains", content=b"abc", headers={"content-type": "text/plain"})
    assert_error(r, 415, "content-type")


def test_upload_and_vertex_limits(make_client, meshes_dir):
    client = make_client(max_upload_bytes=1000)
    assert_error(upload_mesh(client, meshes_dir / "woody.obj"), 413, "file", "payload_too_large")
    client = make_client(max_vertices=100)
    assert_error(upload_mesh(client, meshes_dir / "woody.obj"), 413, "file")
    assert_error(client.post("/v1/domains", json={"kind": "grid", "shape": [20, 20]}), 413,
                 "shape")
    client = make_client(max_upload_bytes=2000)
    gid = client.post("/v1/domains", json={"kind": "grid", "shape": [30, 30]}).json()["id"]
    big = {"distributions": [[1.0] * 900]}
    assert_error(client.post(f"/v1/domains/{gid}/barycenters", json=big), 413, "body")


def test_api_keys(make_client):
    client = make_client(api_keys="alpha, beta")
    assert_error(client.get("/v1/domains"), 401, "X-API-Key", "unauthorized")
    assert_error(client.get("/v1/domains", headers={"X-API-Key": "nope"}), 401, "X-API-Key")
    assert client.get("/v1/domains", headers={"X-API-Key": "beta"}).status_code == 200
    assert client.get("/healthz").status_code == 200


def test_unknown_ids_and_routes(client):
    assert_error(client.get("/v1/domains/" + "0" * 64), 404, "domain_id", "not_found")
    assert_error(client.get("/v1/domains/not-an-id"), 404, "domain_id")
    assert_error(client.get("/v1/jobs/deadbeef"), 404, "job_id", "not_found")
    assert_error(client.get("/v1/jobs/deadbeef/result"), 404, "job_id")
    assert_error(client.delete("/v1/jobs/deadbeef"), 404, "job_id")
    r = client.get("/v1/nothing")
    assert r.status_code == 404 and r.json()["error"]["code"] == "not_found"


def test_list_jobs_state_filter_is_validated(client):
    assert client.get("/v1/jobs?state=queued").json() == {"jobs": [], "next_cursor": None}
    assert_error(client.get("/v1/jobs?state=sleeping"), 422, "state")
