"""POST /v1/domains/{id}/histogram-propagations: results match the library; 4xx name fields."""

from __future__ import annotations

import numpy as np
import pytest
from service_testing import assert_error, upload_mesh

from service.operations.histograms import HistogramPropagationValues
from solvers import Graph
from solvers.histograms import make_bins, propagate_histograms


def _path_graph(client, n=11, positions=True):
    body = {"kind": "graph", "n_nodes": n,
            "edges": [[i, i + 1] for i in range(n - 1)]}
    if positions:
        body["positions"] = [[float(i), 0.0, 0.0] for i in range(n)]
    r = client.post("/v1/domains", json=body)
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _gauss(centers, mu, s):
    h = np.exp(-0.5 * ((centers - mu) / s) ** 2)
    return (h / h.sum()).tolist()


BINS = {"lo": 0.0, "hi": 1.0, "count": 40}
CENTERS = make_bins(lo=0.0, hi=1.0, count=40).centers


def _submit(client, gid, body):
    return client.post(f"/v1/domains/{gid}/histogram-propagations?wait=30", json=body)


def test_path_graph_matches_library_and_exports(client):
    gid = _path_graph(client)
    labeled = [{"node": 0, "histogram": _gauss(CENTERS, 0.2, 0.04)},
               {"node": 10, "histogram": _gauss(CENTERS, 0.8, 0.04)}]
    r = _submit(client, gid, {"bins": BINS, "labeled": labeled})
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    job = r.json()["id"]
    res = client.get(f"/v1/jobs/{job}/result").json()
    v, a = res["values"], res["arrays"]
    g = Graph(11, np.c_[np.arange(10), np.arange(1, 11)])
    lib = propagate_histograms(g, [0, 10], np.array([x["histogram"] for x in labeled]),
                               bins=make_bins(lo=0, hi=1, count=40))
    H = np.asarray(a["histograms"])
    assert H.shape == (11, 40) and np.allclose(H, lib.histograms, atol=1e-12)
    assert np.allclose(a["mean"], np.linspace(0.2, 0.8, 11), atol=3e-3)
    assert v["method"] == "wasserstein" and v["converged"] and v["n_labeled"] == 2
    HistogramPropagationValues.model_validate(v)  # the documented result model
    assert v["mean_range"][0] == pytest.approx(min(a["mean"]))
    row = client.get(f"/v1/jobs/{job}/arrays/histograms/rows/5")
    assert row.status_code == 200 and np.allclose(row.json()["values"], H[5])
    glb = client.get(f"/v1/jobs/{job}/result.glb")
    assert glb.status_code == 200 and glb.content[:4] == b"glTF"
    assert b"_MEAN" in glb.content and b"_STD" in glb.content
    # the PDF baseline is bimodal in the middle; diffusion returns one frame per time
    pdf = _submit(client, gid, {"bins": BINS, "labeled": labeled, "method": "pdf"}).json()
    a_pdf = client.get(f"/v1/jobs/{pdf['id']}/result").json()["arrays"]
    assert a_pdf["std"][5] > 3 * a["std"][5]
    dif = _submit(client, gid, {"bins": BINS, "labeled": labeled, "method": "diffusion",
                                "times": [0.0, 5.0]}).json()
    assert dif["state"] == "succeeded", dif
    a_dif = client.get(f"/v1/jobs/{dif['id']}/result").json()["arrays"]
    assert np.asarray(a_dif["histograms"]).shape == (11, 80)
    assert np.asarray(a_dif["mean"]).shape == (11, 2)
    m = np.asarray(a_dif["mean"])
    assert np.ptp(m[:, 1]) < np.ptp(m[:, 0])  # diffusion pulls the means together
    assert client.get(f"/v1/jobs/{dif['id']}/result.glb").status_code == 200


def test_samples_and_periodic_bins(client):
    gid = _path_graph(client, 9, positions=False)
    body = {"bins": {"lo": -1.0, "hi": 1.0, "count": 20},
            "labeled": [{"node": 0, "samples": [-0.5] * 3}, {"node": 8, "samples": [0.5]}]}
    r = _submit(client, gid, body).json()
    assert r["state"] == "succeeded", r
    mean = client.get(f"/v1/jobs/{r['id']}/result").json()["arrays"]["mean"]
    assert np.allclose(mean, np.linspace(-0.5, 0.5, 9), atol=0.06)  # Diracs: harmonic
    two_pi = 2 * np.pi
    circ = make_bins(lo=0, hi=two_pi, count=24, periodic=True)
    def vm(mu):
        h = np.exp(30 * np.cos(circ.centers - mu))
        return (h / h.sum()).tolist()
    labeled = [{"node": 0, "histogram": vm(np.deg2rad(330))},
               {"node": 8, "histogram": vm(np.deg2rad(30))}]
    for algorithm in ("lp", "entropic"):
        body = {"bins": {"lo": 0.0, "hi": two_pi, "count": 24, "periodic": True},
                "labeled": labeled, "periodic_method": algorithm}
        r = _submit(client, gid, body).json()
        assert r["state"] == "succeeded", r
        res = client.get(f"/v1/jobs/{r['id']}/result").json()
        ang = np.rad2deg(np.asarray(res["arrays"]["mean"]))
        assert np.all(np.minimum(ang, 360 - ang) <= 31)  # across 0, the short way
        assert res["values"]["periodic_method"] == algorithm and res["values"]["value"] > 0
        HistogramPropagationValues.model_validate(res["values"])


def test_mesh_domain(client, meshes_dir):
    up = upload_mesh(client, meshes_dir / "woody.obj")
    assert up.status_code == 201, up.text
    mid, n = up.json()["id"], up.json()["n"]
    rng = np.random.default_rng(0)
    nodes = rng.choice(n, 20, replace=False)
    labeled = [{"node": int(u), "histogram": _gauss(CENTERS, float(m), 0.05)}
               for u, m in zip(nodes, rng.uniform(0.2, 0.8, 20), strict=True)]
    r = _submit(client, mid, {"bins": BINS, "labeled": labeled}).json()
    assert r["state"] == "succeeded", r
    res = client.get(f"/v1/jobs/{r['id']}/result").json()
    assert np.asarray(res["arrays"]["histograms"]).shape == (n, 40)
    glb = client.get(f"/v1/jobs/{r['id']}/result.glb")
    assert glb.status_code == 200 and b"_MEAN" in glb.content
    r = _submit(client, mid, {"bins": BINS, "labeled": labeled, "color": "std"}).json()
    glb_std = client.get(f"/v1/jobs/{r['id']}/result.glb")
    assert glb_std.status_code == 200 and glb_std.content != glb.content  # other colors


@pytest.mark.parametrize("patch, field", [
    ({"bins": {"edges": [0.0, 0.5, 0.5, 1.0]}}, "bins.edges"),
    ({"bins": {"lo": 1.0, "hi": 0.0, "count": 4}}, "bins.hi"),
    ({"bins": {"lo": 0.0, "hi": 1.0}}, "bins.count"),
    ({"labeled": [{"node": 0, "histogram": [1, -1, 0, 0]}, {"node": 3, "histogram": [1] * 4}]},
     "labeled[0].histogram"),
    ({"labeled": [{"node": 0, "histogram": [0, 0, 0, 0]}, {"node": 3, "histogram": [1] * 4}]},
     "labeled[0].histogram"),
    ({"labeled": [{"node": 0, "histogram": [1, 1, 1]}, {"node": 3, "histogram": [1] * 4}]},
     "labeled[0].histogram"),
    ({"labeled": [{"node": 0, "samples": [5.0]}, {"node": 3, "histogram": [1] * 4}]},
     "labeled[0].samples"),
    ({"labeled": [{"node": 0}, {"node": 3, "histogram": [1] * 4}]}, "labeled[0].histogram"),
    ({"labeled": [{"node": 0, "histogram": [1] * 4}]}, "labeled"),  # component 1 unlabeled
    ({"labeled": [{"node": 0, "histogram": [1] * 4}, {"node": 0, "histogram": [1] * 4}]},
     "labeled"),
    ({"labeled": [{"node": 9, "histogram": [1] * 4}, {"node": 3, "histogram": [1] * 4}]},
     "labeled"),
    ({"method": "diffusion"}, "times"),
    ({"times": [1.0]}, "times"),
    ({"method": "diffusion", "times": [-1.0]}, "times[0]"),
    ({"method": "sideways"}, "method"),
])
def test_bad_input_is_4xx_naming_the_field(client, patch, field):
    r = client.post("/v1/domains", json={"kind": "graph", "n_nodes": 6,
                                         "edges": [[0, 1], [1, 2], [3, 4], [4, 5]]})
    gid = r.json()["id"]
    body = {"bins": {"lo": 0.0, "hi": 1.0, "count": 4},
            "labeled": [{"node": 0, "histogram": [1, 2, 3, 4]},
                        {"node": 3, "histogram": [4, 3, 2, 1]}], **patch}
    resp = client.post(f"/v1/domains/{gid}/histogram-propagations", json=body)
    assert resp.status_code in (413, 422), resp.text
    err = resp.json()["error"]
    assert err["field"] == field, err


def test_unsupported_domain_kind_and_periodic_diffusion(client):
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4]}).json()["id"]
    body = {"bins": BINS, "labeled": [{"node": 0, "histogram": [1.0] * 40}]}
    assert_error(client.post(f"/v1/domains/{grid}/histogram-propagations", json=body), 422,
                 "domain_id")
    gid = _path_graph(client, 4, positions=False)
    body = {"bins": {"lo": 0, "hi": 6.28, "count": 8, "periodic": True}, "method": "diffusion",
            "times": [1.0], "labeled": [{"node": 0, "histogram": [1.0] * 8}]}
    assert_error(client.post(f"/v1/domains/{gid}/histogram-propagations", json=body), 422,
                 "bins.periodic")
