"""A job whose solver did not converge never looks like a success, and a regularization
below what the domain resolves is refused at submission."""

from __future__ import annotations

import pytest
from service_testing import assert_error

BODY = {"mu0": {"vertex": 0, "radius": 0.3}, "mu1": {"vertex": 63, "radius": 0.3},
        "method": "convolutional"}


def _grid(client, shape=(8, 8)) -> str:
    return client.post("/v1/domains", json={"kind": "grid", "shape": list(shape)}).json()["id"]


def test_not_converged_job_fails_with_partial_result(client):
    gid = _grid(client)
    job = client.post(f"/v1/domains/{gid}/distances",
                      json={**BODY, "gamma": 0.01, "tol": 1e-12, "max_iter": 2}).json()
    assert job["state"] == "failed", job
    assert job["error"]["code"] == "not_converged" and job["error"]["field"] == "max_iter"
    result = client.get(f"/v1/jobs/{job['id']}/result")
    assert result.status_code == 200, result.text
    values = result.json()["values"]
    assert values["converged"] is False and values["iterations"] <= 2
    assert values["residual"] > 1e-12  # the measured residual says why
    assert f"{values['residual']:.3g}" in job["error"]["message"]


def test_converged_job_succeeds(client):
    gid = _grid(client)
    job = client.post(f"/v1/domains/{gid}/distances",
                      json={**BODY, "gamma": 0.01, "tol": 1e-6}).json()
    assert job["state"] == "succeeded", job
    assert client.get(f"/v1/jobs/{job['id']}/result").json()["values"]["converged"] is True


@pytest.mark.parametrize("gamma", [1e-300, 1e-12, 1e-8])
def test_gamma_below_resolution_refused_on_distances(client, gamma):
    gid = _grid(client, (32, 32))
    err = assert_error(client.post(f"/v1/domains/{gid}/distances",
                                   json={**BODY, "gamma": gamma}), 422, "gamma")
    assert "resolve" in err["message"]


def test_gamma_below_resolution_refused_on_grid_barycenters(client):
    gid = _grid(client, (32, 32))
    body = {"distributions": [BODY["mu0"], BODY["mu1"]], "gamma": 1e-12}
    assert_error(client.post(f"/v1/domains/{gid}/barycenters", json=body), 422, "gamma")
    h2 = (1.0 / 31) ** 2  # the grid's spacing, squared: sharp but resolved
    ok = client.post(f"/v1/domains/{gid}/barycenters", json={**body, "gamma": h2})
    assert ok.status_code in (200, 202), ok.text


def test_gamma_below_resolution_refused_on_color_transfer(client):
    import numpy as np

    from solvers.color import write_image

    rng = np.random.default_rng(0)
    files = [("images", (f"{i}.png", write_image(rng.integers(0, 255, (8, 8, 3),
                                                              dtype=np.uint8), "png"),
                         "application/octet-stream")) for i in range(2)]
    resp = client.post("/v1/color-transfers", files=files, data={"bins": "64", "gamma": "1e-300"})
    assert_error(resp, 422, "gamma")


def test_resolution_bound_is_the_neighbour_weight_at_machine_epsilon():
    import numpy as np

    from solvers.errors import InputError
    from solvers.validation import GAMMA_RESOLUTION, check_gamma_resolved

    h = 0.01
    low = GAMMA_RESOLUTION * h * h
    assert np.exp(-h * h / low) == pytest.approx(np.finfo(float).eps)
    assert check_gamma_resolved(low * 1.01, h) == low * 1.01
    with pytest.raises(InputError):
        check_gamma_resolved(low * 0.99, h)
