"""Every operation declares the schema of its result values, and real results fit it."""

from __future__ import annotations

import pytest
from service_testing import upload_mesh

from service.operations import build_registry

BUMPS = {"mu0": {"vertex": 0, "radius": 0.2}, "mu1": {"vertex": 300, "radius": 0.2}}
REQUESTS = {
    "distances": BUMPS,
    "barycenters": {"distributions": [BUMPS["mu0"], BUMPS["mu1"]], "weights": [0.3, 0.7]},
    "interpolations": {**BUMPS, "times": [0.0, 0.5, 1.0]},
    "propagations": {"n_nodes": 3, "edges": [[0, 1], [1, 2]],
                     "fixed": [{"node": 0, "distribution": BUMPS["mu0"]},
                               {"node": 2, "distribution": BUMPS["mu1"]}]},
    "pointwise-distances": {"source": 0},
    "flows": {**BUMPS, "tol": 1e-3},
}


def test_every_operation_declares_its_result_model():
    missing = [name for name, op in build_registry().items() if op.result_model is None]
    assert missing == []


@pytest.mark.parametrize("name", sorted(REQUESTS))
def test_transport_results_fit_their_models(client, meshes_dir, name):
    op = build_registry()[name]
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    job = client.post(f"/v1/domains/{mid}/{name}?wait=60", json=REQUESTS[name]).json()
    assert job["state"] == "succeeded", job
    values = client.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()["values"]
    parsed = op.result_model.model_validate(values)
    assert parsed.converged in (True, False) and parsed.iterations >= 0
