"""The viewer's routes without a browser: the page and its assets are served from the package,
the vendored three.js is the pinned one, and GET /v1/domains/{id}/geometry returns what the page
draws (mesh positions at unit area, faces; graph edges; grid shape), under the API key."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from shared_meshes import MESHES_DIR

from service.api.viewer import STATIC_DIR
from service.app import create_app
from service.settings import Settings
from solvers import load_mesh

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(Settings(data_dir=tmp_path, queue="immediate"))) as c:
        yield c


def test_page_and_assets(client):
    for path in ("/", "/viewer"):
        r = client.get(path)
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
        assert 'type="importmap"' in r.text and "/static/app.js" in r.text
    for asset in ("app.js", "api.js", "forms.js", "scene.js", "colormap.js", "style.css",
                  "vendor/three.module.min.js", "vendor/addons/controls/OrbitControls.js"):
        r = client.get(f"/static/{asset}")
        assert r.status_code == 200 and len(r.content) > 500, asset
    assert "/" not in client.get("/openapi.json").json()["paths"]  # pages are not API routes


def test_vendored_three_matches_the_pinned_version():
    """service/static/vendor holds the three.js that viewer/package-lock.json pins
    (`cd viewer && npm ci && npm run build` re-vendors it)."""
    import json

    lock = json.loads((ROOT / "viewer" / "package-lock.json").read_text())
    pinned = lock["packages"]["node_modules/three"]["version"]  # e.g. "0.170.0"
    head = (STATIC_DIR / "vendor" / "three.module.min.js").read_text()[:400]
    assert f'const t="{pinned.split(".")[1]}"' in head, (pinned, head[-80:])
    assert (STATIC_DIR / "vendor" / "LICENSE.three.txt").exists()
    assert (STATIC_DIR / "vendor" / "addons" / "controls" / "OrbitControls.js").exists()


def test_mesh_geometry(client):
    path = MESHES_DIR / "spot.obj"
    with path.open("rb") as fh:
        domain = client.post("/v1/domains", files={"file": ("spot.obj", fh)}).json()
    g = client.get(f"/v1/domains/{domain['id']}/geometry").json()
    mesh = load_mesh(path)
    assert g["kind"] == "mesh" and g["n"] == mesh.n and g["dim"] == 3
    pos = np.asarray(g["positions"]).reshape(-1, 3)
    # the coordinates bump radii are measured in (unit total area), as the server uses them
    np.testing.assert_allclose(pos, mesh.vertices, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(g["faces"]).reshape(-1, 3), mesh.faces)


def test_graph_and_grid_geometry(client):
    graph = client.post("/v1/domains", json={"kind": "graph", "n_nodes": 3,
                                             "edges": [[0, 1], [1, 2]],
                                             "positions": [[0, 0], [1, 0], [1, 1]]}).json()
    g = client.get(f"/v1/domains/{graph['id']}/geometry").json()
    assert g["edges"] == [0, 1, 1, 2] and g["dim"] == 2 and g["faces"] is None
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 3]}).json()
    g = client.get(f"/v1/domains/{grid['id']}/geometry").json()
    assert g["shape"] == [4, 3] and g["bounds"] == [[0, 1], [0, 1]] and g["positions"] is None
    assert client.get("/v1/domains/" + "0" * 64 + "/geometry").status_code == 404


def test_geometry_needs_the_key(tmp_path):
    app = create_app(Settings(data_dir=tmp_path, queue="immediate", api_keys=["k1"]))
    with TestClient(app) as c:
        grid = c.post("/v1/domains", json={"kind": "grid", "shape": [2, 2]},
                      headers={"X-API-Key": "k1"}).json()
        assert c.get(f"/v1/domains/{grid['id']}/geometry").status_code == 401
        assert c.get(f"/v1/domains/{grid['id']}/geometry",
                     headers={"X-API-Key": "k1"}).status_code == 200
        assert c.get("/").status_code == 200  # the page itself asks for the key
