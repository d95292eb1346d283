"""``/barycenter-batches``: many barycenters of the same inputs through HTTP equal the
library's ``barycenters()``; bad weight vectors are refused naming ``weights[b]``; a job too
large for the memory bound is refused at submission naming the larger part; progress counts
problems; a cancelled job keeps no result."""

from __future__ import annotations

import io
import threading
import time

import numpy as np
import pytest
from service_testing import assert_error, bump_masses, upload_mesh

from solvers.convolutional import barycenters

BUMPS = [{"vertex": v, "radius": 0.3} for v in (0, 300, 500)]
WEIGHTS = [[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.2, 0.3, 0.5], [0.0, 1.0, 3.0]]


def _npy(client, job_id, name) -> np.ndarray:
    r = client.get(f"/v1/jobs/{job_id}/arrays/{name}.npy")
    assert r.status_code == 200, r.text
    return np.load(io.BytesIO(r.content))


def test_batch_equals_library_barycenters(client, woody):
    mesh, mid = woody
    job = client.post(f"/v1/domains/{mid}/barycenter-batches",
                      json={"distributions": BUMPS, "weights": WEIGHTS}).json()
    assert job["state"] == "succeeded", job
    values = client.get(f"/v1/jobs/{job['id']}/result", params={"arrays": False}).json()["values"]
    mus = np.stack([bump_masses(mesh, b["vertex"], b["radius"]) for b in BUMPS], axis=1)
    ref = barycenters(mesh, mus, np.array(WEIGHTS))
    masses = _npy(client, job["id"], "masses")
    assert masses.shape == (mesh.n, len(WEIGHTS))
    np.testing.assert_allclose(masses, ref.masses, rtol=0, atol=1e-12)
    np.testing.assert_allclose(_npy(client, job["id"], "density"),
                               ref.masses / mesh.areas[:, None], rtol=1e-12, atol=1e-12)
    assert np.array_equal(_npy(client, job["id"], "problem_iterations"),
                          ref.problem_iterations)
    assert values["problems"] == 4 and values["converged"] == bool(ref.converged)
    assert values["iterations"] == int(ref.iterations)
    assert values["gamma"] == pytest.approx(ref.gamma, rel=1e-15)
    np.testing.assert_allclose(values["weights"][3], [0.0, 0.25, 0.75])
    assert values["regularization"]["purpose"] == "shapes"
    # progress counts problems, not iterations
    done = client.get(f"/v1/jobs/{job['id']}").json()["progress"]
    assert done["iteration"] == 4 and done["fraction"] == 1.0


@pytest.mark.parametrize(("weights", "field", "named"), [
    # negative: refused by the request model (the spec says >= 0), the item named
    ([[0.5, 0.5, 0.0], [1.0, -0.5, 0.5]], "weights", "weights[1][1]"),
    ([[0.5, 0.5, 0.0], [0.2, 0.3, 0.5], [0.0, 0.0, 0.0]], "weights[2]", "sums to 0"),
    ([[0.5, 0.5]], "weights[0]", "needs 3 values"),  # length 2 for 3 distributions
    ([[0.5, 0.5, 0.0], [1e308, 1e308, 0.0]], "weights[1]", "float range"),  # sum overflows
])
def test_bad_weights_name_the_field_and_index(client, woody, weights, field, named):
    _, mid = woody
    r = client.post(f"/v1/domains/{mid}/barycenter-batches",
                    json={"distributions": BUMPS, "weights": weights})
    err = assert_error(r, 422, field)
    assert named in err["message"] and field in err["message"]


def test_single_barycenter_weights_whose_sum_overflows_are_a_422(client, woody):
    """``/barycenters`` checks its weights with the same library validator: a finite row
    whose sum overflows is refused at submission naming ``weights`` (was normalized to
    zeros)."""
    _, mid = woody
    r = client.post(f"/v1/domains/{mid}/barycenters",
                    json={"distributions": BUMPS[:2], "weights": [1e308, 1e308]})
    err = assert_error(r, 422, "weights")
    assert "float range" in err["message"]


def test_bad_inputs_refused(client, woody):
    _, mid = woody
    url = f"/v1/domains/{mid}/barycenter-batches"
    assert_error(client.post(url, json={"distributions": BUMPS, "weights": []}), 422, "weights")
    assert_error(client.post(url, json={"distributions": [{"vertex": 10_000, "radius": 0.2}],
                                        "weights": [[1.0]]}), 422, "distributions[0].vertex")


def test_memory_refused_at_submission_naming_the_larger_part(make_client, meshes_dir):
    client = make_client(job_memory_bytes=8 * 2**20)
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    url = f"/v1/domains/{mid}/barycenter-batches"
    # the default geodesic kernel's dense matrices (3 x 8 x 694^2 bytes) exceed 8 MiB alone
    assert_error(client.post(url, json={"distributions": BUMPS[:2], "weights": [[0.5, 0.5]]}),
                 413, "method")
    heat = {"method": "convolutional"}
    ok = client.post(url, json={"distributions": BUMPS[:2], "weights": [[0.5, 0.5]], **heat})
    assert ok.status_code in (200, 202), ok.text
    # many problems over two inputs: the (V, B) results dominate
    many = [[b / 4000, 1 - b / 4000] for b in range(4000)]
    err = assert_error(client.post(url, json={"distributions": BUMPS[:2], "weights": many,
                                              **heat}), 413, "weights")
    assert "GiB" in err["message"]
    # many inputs, one problem: the active problems' (V, k) state dominates
    inputs = [{"vertex": v, "radius": 0.3} for v in range(0, 640, 10)]
    err = assert_error(client.post(url, json={"distributions": inputs,
                                              "weights": [[1.0] * 64] * 64, **heat}),
                       413, "distributions")


def test_progress_over_problems_and_cancel_keeps_no_result(make_client, meshes_dir):
    client = make_client(queue="sqlite", heartbeat_interval=0.05)
    rt = client.app.state.runtime
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    B = 1024
    weights = [[b / B, 1 - b / B] for b in range(B)]
    job = client.post(f"/v1/domains/{mid}/barycenter-batches",
                      json={"distributions": BUMPS[:2], "weights": weights, "tol": 1e-9,
                            "max_iter": 3000}).json()
    assert job["state"] == "queued", job
    worker = threading.Thread(target=rt.runner.run, args=(job["id"],))
    worker.start()
    deadline = time.monotonic() + 120
    while True:
        progress = client.get(f"/v1/jobs/{job['id']}").json()["progress"]
        if (progress["iteration"] or 0) >= 1:
            break
        assert time.monotonic() < deadline and worker.is_alive()
        time.sleep(0.01)
    # fraction = problems done / B (not iterations / max_iter)
    assert progress["fraction"] == pytest.approx(progress["iteration"] / B)
    assert progress["iteration"] < B
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 200
    worker.join(timeout=120)
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["state"] == "cancelled" and done["error"]["code"] == "cancelled"
    assert_error(client.get(f"/v1/jobs/{job['id']}/result"), 409, "job_id", "job_cancelled")
