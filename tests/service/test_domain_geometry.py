"""GET /v1/domains/{id}/geometry draws what each kind's domain class says it has, and
GLB exports of every kind."""

from __future__ import annotations

import numpy as np

from service.export import domain_glb
from solvers.domains import Graph, Grid, PointCloud, TriangleMesh

TETRA = {"kind": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
         "faces": [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]}


def _geometry(client, spec) -> dict:
    created = client.post("/v1/domains", json=spec)
    assert created.status_code in (200, 201), created.text
    got = client.get(f"/v1/domains/{created.json()['id']}/geometry")
    assert got.status_code == 200, got.text
    return got.json()


def test_geometry_of_every_kind(client):
    mesh = _geometry(client, TETRA)
    assert mesh["faces"] == [i for f in TETRA["faces"] for i in f]
    assert mesh["dim"] == 3 and len(mesh["positions"]) == 12
    assert mesh["edges"] is None and mesh["shape"] is None

    grid = _geometry(client, {"kind": "grid", "shape": [3, 4], "bounds": [[0, 1], [0, 2]]})
    assert grid["shape"] == [3, 4] and grid["bounds"] == [[0.0, 1.0], [0.0, 2.0]]
    assert grid["dim"] == 2 and grid["positions"] is None and grid["faces"] is None

    graph = _geometry(client, {"kind": "graph", "n_nodes": 3, "edges": [[0, 1], [1, 2]],
                               "positions": [[0, 0], [1, 0], [2, 1]]})
    assert graph["edges"] == [0, 1, 1, 2] and graph["dim"] == 2
    assert graph["positions"] == [0, 0, 1, 0, 2, 1] and graph["faces"] is None

    bare = _geometry(client, {"kind": "graph", "n_nodes": 2, "edges": [[0, 1]]})
    assert bare["positions"] is None and bare["edges"] == [0, 1]

    pts = np.random.default_rng(1).random((8, 3)).tolist()
    cloud = _geometry(client, {"kind": "pointcloud", "points": pts, "n_neighbors": 4})
    assert len(cloud["positions"]) == 24 and cloud["faces"] is None and cloud["edges"] is None


def test_glb_of_every_kind():
    """Each kind exports; a 2-D grid as a triangulated sheet, larger than its point set."""
    mesh = TriangleMesh(TETRA["vertices"], TETRA["faces"])
    grid2, grid3 = Grid([4, 4]), Grid([3, 3, 3])
    graph = Graph(3, [[0, 1], [1, 2]], positions=[[0, 0, 0], [1, 0, 0], [1, 1, 0]])
    cloud = PointCloud(np.random.default_rng(2).random((10, 3)), n_neighbors=4)
    for domain in (mesh, grid2, grid3, graph, cloud):
        glb = domain_glb(domain, fields={"u": np.arange(domain.n, dtype=float)})
        assert glb[:4] == b"glTF", domain.kind
    face_field = domain_glb(mesh, fields={"f": np.ones(mesh.n_faces)}, per_face=["f"])
    assert face_field[:4] == b"glTF"
