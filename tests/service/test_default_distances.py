"""The default ``/distances`` (no options) against the exact LP on the shared meshes that fit in
a test (woody, cow); larger meshes are in ``bench/convolutional.py`` (accuracy table).

The oracle is independent of the service: POT ``ot.emd2`` between the two bumps' supports
with squared exact geodesics from :mod:`solvers.geodesics`.
"""

from __future__ import annotations

import numpy as np
import ot
import pytest
from service_testing import upload_mesh

from solvers.geodesics import geodesic_distances


def _bump(mesh, vertex, radius=0.1):
    d = np.linalg.norm(mesh.vertices - mesh.vertices[vertex], axis=1)
    m = mesh.areas * np.clip(1 - d / radius, 0, None)
    return m / m.sum()


def _lp(mesh, m0, m1) -> float:
    s0, s1 = np.flatnonzero(m0), np.flatnonzero(m1)
    cost = geodesic_distances(mesh, s0, s1) ** 2
    return float(ot.emd2(m0[s0], m1[s1], cost, numItermax=10**7))


def _targets(mesh, fractions):
    """Vertices at the given fractions of the largest geodesic distance from vertex 0."""
    d0 = geodesic_distances(mesh, [0])[0]
    return [int(np.argmin(np.abs(d0 - f * d0.max()))) for f in fractions]


@pytest.mark.parametrize(("name", "fractions"), [("woody.obj", (0.15, 0.5, 0.9)),
                                                 ("cow.obj", (0.5,))])
def test_default_distance_within_10_percent_of_lp(client, meshes_dir, shared_mesh, name,
                                                  fractions):
    mesh = shared_mesh(name)
    mid = upload_mesh(client, meshes_dir / name).json()["id"]
    for j in _targets(mesh, fractions):
        body = {"mu0": {"vertex": 0, "radius": 0.1}, "mu1": {"vertex": j, "radius": 0.1}}
        job = client.post(f"/v1/domains/{mid}/distances", json=body).json()
        assert job["state"] == "succeeded", job
        values = client.get(f"/v1/jobs/{job['id']}/result").json()["values"]
        lp = _lp(mesh, _bump(mesh, 0), _bump(mesh, j))
        assert values["converged"], values
        assert values["value"] == pytest.approx(lp, rel=0.10), (name, j, values, lp)
        # The result says what was computed and with which parameters.
        assert values["metric"] == "w2" and values["route"] in ("exact", "convolutional")
        if values["route"] == "convolutional":
            reg = values["regularization"]
            assert reg["purpose"] == "values" and reg["debiased"] and values["debiased"]
            assert values["gamma"] == pytest.approx(reg["gamma"]) and values["substeps"] >= 64
        else:
            assert values["support_sizes"] == [int(np.count_nonzero(_bump(mesh, k)))
                                               for k in (0, j)]


def test_explicit_gamma_reports_no_policy(client, meshes_dir):
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    body = {"mu0": {"vertex": 0, "radius": 0.1}, "mu1": {"vertex": 500, "radius": 0.1},
            "gamma": 0.01}
    job = client.post(f"/v1/domains/{mid}/distances", json=body).json()
    values = client.get(f"/v1/jobs/{job['id']}/result").json()["values"]
    assert values["route"] == "convolutional" and values["regularization"] is None
    assert values["gamma"] == 0.01 and values["substeps"] == 1 and values["debiased"] is False


def test_pointwise_cost_is_checked_at_submission(client, meshes_dir):
    from service_testing import assert_error

    mid = upload_mesh(client, meshes_dir / "spot.obj").json()["id"]
    err = assert_error(client.post(f"/v1/domains/{mid}/pointwise-distances",
                                   json={"source": 0, "k": 50}), 422, "k")
    assert "limit" in err["message"]
