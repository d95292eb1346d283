"""The kernel of the shape operations over HTTP (issue 40): ``method`` decided from the stored
domain, reported in the result, equal to the library's, and refused where not offered."""

from __future__ import annotations

import io

import numpy as np
from service_testing import assert_error, bump_masses

from solvers.convolutional import barycenter

BUMPS = [{"vertex": 0, "radius": 0.3}, {"vertex": 500, "radius": 0.3}]


def _values(client, job) -> dict:
    assert job["state"] == "succeeded", job
    return client.get(f"/v1/jobs/{job['id']}/result", params={"arrays": False}).json()["values"]


def test_mesh_barycenter_defaults_to_the_geodesic_kernel(client, woody):
    mesh, mid = woody
    job = client.post(f"/v1/domains/{mid}/barycenters", json={"distributions": BUMPS}).json()
    values = _values(client, job)
    assert values["method"] == "geodesic"
    # what ran: the geodesic kernel has no substeps (the heat kernel's policy took 8)
    assert values["substeps"] is None and values["regularization"]["substeps"] is None
    masses = np.load(io.BytesIO(client.get(f"/v1/jobs/{job['id']}/arrays/masses.npy").content))
    mus = np.stack([bump_masses(mesh, b["vertex"], b["radius"]) for b in BUMPS], axis=1)
    ref = barycenter(mesh, mus)
    assert ref.method == "geodesic"
    np.testing.assert_allclose(masses, ref.masses, rtol=0, atol=1e-12)
    heat = client.post(f"/v1/domains/{mid}/interpolations",
                       json={"mu0": BUMPS[0], "mu1": BUMPS[1], "times": [0.5],
                             "method": "convolutional"}).json()
    assert _values(client, heat)["method"] == "convolutional"


def test_geodesic_method_refused_on_a_grid_naming_the_field(client):
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [8, 8]}).json()["id"]
    body = {"distributions": [{"indices": [0], "masses": [1.0]},
                              {"indices": [63], "masses": [1.0]}]}
    job = client.post(f"/v1/domains/{grid}/barycenters", json=body).json()
    assert _values(client, job)["method"] == "convolutional"
    err = assert_error(client.post(f"/v1/domains/{grid}/barycenters",
                                   json={**body, "method": "geodesic"}), 422, "method")
    assert "convolutional" in err["message"]
