"""POST /v1/soft-map-analyses: point maps as soft maps, their energies and bases (ch. 4, §4.6).

Ground truth on a sphere: the blurred identity map's singular values are the heat spectrum
1 / (1 + tau lambda_i) (Laplace-Beltrami eigenvalues, tau = gamma / 4) and its bijectivity
density is 1; identity and a rotation share the low spherical-harmonic bands, so their
rank-4 collection basis (§4.6.2) spans {1, x, y, z}."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
import trimesh
from scipy.spatial import cKDTree
from service_testing import assert_error, upload_mesh

from service.export import parse_glb
from service.operations.soft_map_analyses import SoftMapAnalysisValues
from solvers import TriangleMesh


@pytest.fixture
def sphere(client, tmp_path):
    s = trimesh.creation.icosphere(subdivisions=2)
    path = tmp_path / "sphere.obj"
    path.write_text(trimesh.exchange.obj.export_obj(s))
    return upload_mesh(client, path).json()["id"], TriangleMesh(s.vertices, s.faces)


def _rotation(mesh, angle=0.9):
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return cKDTree(mesh.vertices).query(mesh.vertices @ R.T)[1].tolist()


def _run(client, body):
    r = client.post("/v1/soft-map-analyses?wait=60", json=body)
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    job = r.json()
    return job, client.get(f"/v1/jobs/{job['id']}/result").json()


def test_identity_spectrum_and_collection_basis(client, sphere):
    sid, mesh = sphere
    gamma = 4 * mesh.mean_edge_length**2
    body = {"target_id": sid, "samples": mesh.n, "gamma": gamma, "rank": 4,
            "dirichlet_method": "potential", "descriptor_k": 0, "show": 3,
            "maps": [{"source_id": sid, "correspondence": list(range(mesh.n))},
                     {"source_id": sid, "correspondence": _rotation(mesh)}]}
    job, res = _run(client, body)
    assert job["domain_id"] == sid
    v, a = res["values"], res["arrays"]
    SoftMapAnalysisValues.model_validate(v)
    ident, rot = v["maps"]
    lam = sla.eigh(mesh.laplacian.toarray(), np.diag(mesh.areas), eigvals_only=True)
    expected = 1.0 / (1.0 + gamma / 4 * lam[:64])
    np.testing.assert_allclose(ident["singular_values"], expected, rtol=1e-6, atol=1e-9)
    assert ident["bijectivity"] == pytest.approx(1.0, rel=1e-6)
    np.testing.assert_allclose(ident["bijectivity_range"], 1.0, rtol=1e-6)
    assert ident["descriptor"] is None and ident["dirichlet"] > 0
    assert rot["dirichlet"] > 0 and rot["low_rank_error"] > 0
    basis = np.asarray(a["collection_basis"])
    assert basis.shape == (mesh.n, 4)
    w = np.sqrt(mesh.areas)[:, None]
    qa = np.linalg.qr(w * basis)[0]
    qb = np.linalg.qr(w * np.c_[np.ones(mesh.n), mesh.vertices])[0]
    assert np.linalg.svd(qa.T @ qb, compute_uv=False).min() > 0.995  # measured 0.997
    captured = v["collection"]["captured"]
    # Eckart-Young: each map's own rank-4 basis captures at least as much of it
    assert len(captured) == 2
    assert all(0 < c <= m["captured"] + 1e-9 for c, m in zip(captured, v["maps"], strict=True))
    assert np.shape(a["target_basis_1"]) == (mesh.n, 4)
    assert np.shape(a["source_basis_0"]) == (mesh.n, 4)
    doc, _ = parse_glb(client.get(f"/v1/jobs/{job['id']}/result.glb").content)
    assert [n["name"] for n in doc["nodes"]] == ["bijectivity density", "basis 1", "basis 2",
                                                 "basis 3"]


def test_energies_rank_a_scramble_below_the_identity(client, sphere):
    """W2 Dirichlet (eq. 4.2) and the WKS descriptor energy (eq. 4.6) of the identity and a
    random permutation on the same sphere."""
    sid, mesh = sphere
    scramble = np.random.default_rng(0).permutation(mesh.n).tolist()
    body = {"target_id": sid, "samples": 24, "rank": 3, "descriptor_k": 10, "n_energies": 20,
            "maps": [{"source_id": sid, "correspondence": list(range(mesh.n))},
                     {"source_id": sid, "correspondence": scramble}]}
    _, res = _run(client, body)
    ident, scr = res["values"]["maps"]
    assert ident["samples"] == 24 and ident["dirichlet_method"] == "w2"
    assert scr["dirichlet"] > 1.8 * ident["dirichlet"]  # measured 2.5x at this blur
    assert ident["descriptor"] < scr["descriptor"]
    assert scr["bijectivity"] > ident["bijectivity"]


def test_bad_requests_are_refused(client, sphere, tmp_path):
    sid, mesh = sphere
    ok = {"source_id": sid, "correspondence": list(range(mesh.n))}
    cases = [({"maps": [ok]}, "target_id", 422),
             ({"target_id": sid, "maps": []}, "maps", 422),
             ({"target_id": sid, "maps": [{**ok, "correspondence": [0, 1]}]},
              "maps[0].correspondence", 422),
             ({"target_id": sid, "maps": [{**ok, "correspondence": [mesh.n] * mesh.n}]},
              "maps[0].correspondence", 422),
             ({"target_id": sid, "maps": [ok], "samples": 10, "rank": 20}, "rank", 422),
             ({"target_id": sid, "maps": [ok], "descriptor_k": 200}, "descriptor_k", 422),
             ({"target_id": "0" * 64, "maps": [ok]}, "target_id", 404)]
    for change, field, status in cases:
        assert_error(client.post("/v1/soft-map-analyses", json=change), status, field)
    graph = client.post("/v1/domains", json={"kind": "graph", "n_nodes": 3,
                                              "edges": [[0, 1], [1, 2]]}).json()["id"]
    assert_error(client.post("/v1/soft-map-analyses",
                             json={"target_id": sid, "maps": [{**ok, "source_id": graph}]}),
                 422, "maps[0].source_id", "unsupported_operation")
