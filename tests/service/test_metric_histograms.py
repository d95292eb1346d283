"""POST /v1/domains/{id}/metric-histogram-propagations: the §5.4 LP with a user cost matrix
(checked against the full LP solved independently by scipy's HiGHS) and on the circle
(Diracs walk along the shorter arc, wrapping through 0)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog
from service_testing import assert_error

from service.operations.metric_histograms import MetricHistogramValues


def _graph(client, n, edges):
    r = client.post("/v1/domains", json={"kind": "graph", "n_nodes": n, "edges": edges,
                                         "positions": [[i, 0, 0] for i in range(n)]})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _submit(client, gid, body):
    r = client.post(f"/v1/domains/{gid}/metric-histogram-propagations?wait=30", json=body)
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    job = r.json()["id"]
    return job, client.get(f"/v1/jobs/{job}/result").json()


def full_lp(n, edges, labeled, C):
    """min sum_e <C, pi_e> over plans pi_e and free histograms (all variables, dense)."""
    B, m = len(C), len(edges)
    free = [u for u in range(n) if u not in labeled]
    col = {u: m * B * B + k * B for k, u in enumerate(free)}
    size = m * B * B + len(free) * B
    A, b = [], []

    def marginal(u, coeffs_row):
        if u in labeled:
            return labeled[u]
        coeffs_row[:, col[u]:col[u] + B] -= np.eye(B)
        return np.zeros(B)

    for e, (u, v) in enumerate(edges):
        base = e * B * B
        for side, node in ((0, u), (1, v)):
            rows = np.zeros((B, size))
            for i in range(B):
                idx = base + (np.arange(B) + i * B if side == 0 else i + B * np.arange(B))
                rows[i, idx] = 1.0
            rhs = marginal(node, rows)
            A.append(rows)
            b.append(rhs)
    for u in free:
        row = np.zeros((1, size))
        row[0, col[u]:col[u] + B] = 1.0
        A.append(row)
        b.append([1.0])
    c = np.concatenate([np.tile(C.ravel(), m), np.zeros(len(free) * B)])
    res = linprog(c, A_eq=np.vstack(A), b_eq=np.concatenate(b), bounds=(0, None),
                  method="highs")
    assert res.status == 0
    return res.fun


def test_user_cost_matches_the_full_lp(client):
    rng = np.random.default_rng(3)
    pts = rng.uniform(size=(5, 2))
    C = np.linalg.norm(pts[:, None] - pts[None], axis=2) ** 2
    edges = [[0, 1], [1, 2], [2, 3], [1, 4], [4, 5]]
    gid = _graph(client, 6, edges)
    labels = {0: rng.dirichlet(np.ones(5)), 3: rng.dirichlet(np.ones(5)),
              5: np.eye(5)[2]}
    body = {"cost": C.tolist(),
            "labeled": [{"node": u, "histogram": h.tolist()} for u, h in labels.items()]}
    job, res = _submit(client, gid, body)
    v, a = res["values"], res["arrays"]
    MetricHistogramValues.model_validate(v)
    assert v["space"] == "metric" and v["points"] == 5 and v["certified"] and v["converged"]
    assert v["value"] == pytest.approx(full_lp(6, edges, labels, C), rel=1e-7, abs=1e-10)
    H = np.asarray(a["histograms"])
    assert H.shape == (6, 5) and np.allclose(H.sum(axis=1), 1.0)
    np.testing.assert_allclose(H[0], labels[0], atol=1e-9)
    assert np.shape(a["spread"]) == (6,) and np.shape(a["mode"]) == (6,)
    glb = client.get(f"/v1/jobs/{job}/result.glb")
    assert glb.status_code == 200 and glb.content[:4] == b"glTF"


def test_circle_diracs_walk_the_shorter_arc(client):
    gid = _graph(client, 5, [[i, i + 1] for i in range(4)])
    B = 12
    body = {"circle": {"points": B},
            "labeled": [{"node": 0, "histogram": np.eye(B)[10].tolist()},
                        {"node": 4, "histogram": np.eye(B)[2].tolist()}]}
    _, res = _submit(client, gid, body)
    v, a = res["values"], res["arrays"]
    cell = 2 * np.pi / B
    assert v["space"] == "circle" and v["certified"]
    assert v["value"] == pytest.approx(4 * cell**2, rel=1e-9)
    H = np.asarray(a["histograms"])
    np.testing.assert_allclose(H, np.eye(B)[[10, 11, 0, 1, 2]], atol=1e-9)
    centers = (np.arange(B) + 0.5) * cell
    mean = np.asarray(a["circular_mean"])
    np.testing.assert_allclose(np.cos(mean), np.cos(centers[[10, 11, 0, 1, 2]]), atol=1e-9)


@pytest.mark.parametrize("change, field", [
    ({}, "cost"),
    ({"cost": [[0, 1], [1, 0]], "circle": {"points": 2}}, "cost"),
    ({"cost": [[0, 1], [2, 0]]}, "cost"),
    ({"cost": [[1, 1], [1, 0]]}, "cost"),
    ({"cost": [[0, -1], [-1, 0]]}, "cost"),
    ({"cost": [[0, 1], [1]]}, "cost"),
    ({"circle": {"points": 1}}, "circle.points"),
    ({"cost": [[0, 1, 1], [1, 0, 1], [1, 1, 0]]}, "labeled[0].histogram"),
])
def test_bad_input_is_refused(client, change, field):
    gid = _graph(client, 3, [[0, 1], [1, 2]])
    body = {"labeled": [{"node": 0, "histogram": [1, 0]}, {"node": 2, "histogram": [0, 1]}],
            **change}
    assert_error(client.post(f"/v1/domains/{gid}/metric-histogram-propagations", json=body),
                 422, field)


def test_unanchored_components_are_refused(client):
    gid = _graph(client, 4, [[0, 1], [2, 3]])
    body = {"cost": [[0, 1], [1, 0]], "labeled": [{"node": 0, "histogram": [1, 0]}]}
    assert_error(client.post(f"/v1/domains/{gid}/metric-histogram-propagations", json=body),
                 422, "labeled")
