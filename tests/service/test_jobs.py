"""Jobs: end to end through the queue, cancellation, time limits, reaper, persistence,
server-sent events and metrics."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from service_testing import assert_error, upload_mesh

from service.jobs.db import JobRow
from service.operations.base import Operation, OperationOutput, OperationRequest
from solvers.emd import earth_movers_distance
from solvers.errors import CancelledError

ROOT = Path(__file__).resolve().parents[2]


# -- a controllable operation (registered for these tests only) ---------------------
class LoopRequest(OperationRequest):
    iterations: int = 10
    sleep: float = 0.0
    arrays: bool = True  # False: a result of values only
    padding: int = 0  # a list of this many floats among the values


def _loop(domain, req, progress, should_cancel):
    for i in range(req.iterations):
        if should_cancel():
            raise CancelledError("stopped")
        progress(i + 1, 1.0 / (i + 1))
        time.sleep(req.sleep)
    values = {"iterations": req.iterations}
    if req.padding:
        values["padding"] = [0.125] * req.padding
    return OperationOutput(values, {"ones": np.ones(domain.n)} if req.arrays else {})


LOOP_OP = Operation("test-loop", "createTestLoopJob", "test", LoopRequest, _loop,
                    lambda view, req: [])


@pytest.fixture
def loop_op():
    return LOOP_OP


def _grid(client, shape=(6, 6)) -> str:
    return client.post("/v1/domains", json={"kind": "grid", "shape": list(shape)}).json()["id"]


def _submit(client, domain_id, **params):
    """Create a test-loop job through the service layer (no HTTP route for test ops)."""
    from service.job_service import JobService

    rt = client.app.state.runtime
    rt.operations[LOOP_OP.name] = LOOP_OP  # test-only operation, no HTTP route
    return JobService(rt).create("test-loop", domain_id, LoopRequest(**params))


def _bump(mesh, vertex, radius):
    d = np.linalg.norm(mesh.vertices - mesh.vertices[vertex], axis=1)
    m = mesh.areas * np.clip(1 - d / radius, 0, None)
    return m / m.sum()


FLOW_BODY = {"mu0": {"vertex": 0, "radius": 0.15}, "mu1": {"vertex": 500, "radius": 0.15},
             "tol": 1e-3}


# -- end to end --------------------------------------------------------------------
def test_flow_job_immediate_matches_solver(client, meshes_dir, shared_mesh):
    mesh = shared_mesh("woody.obj")
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    r = client.post(f"/v1/domains/{mid}/flows?wait=10", json=FLOW_BODY)
    assert r.status_code == 200, r.text
    job = r.json()
    assert job["state"] == "succeeded" and job["attempts"] == 1
    assert job["progress"]["iteration"] > 0
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    direct = earth_movers_distance(mesh, _bump(mesh, 0, 0.15), _bump(mesh, 500, 0.15), tol=1e-3)
    assert result["values"]["value"] == pytest.approx(direct.value, rel=1e-9)
    assert result["values"]["converged"] is True
    assert np.allclose(result["arrays"]["flow"], direct.flow)
    assert len(result["arrays"]["potential"]) == mesh.n
    report = {r["field"]: r for r in result["values"]["normalization"]}
    assert report["mu0"]["normalized"] and report["mu0"]["scale"] > 1
    # Without arrays, and as glTF.
    slim = client.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()
    assert slim["arrays"] == {} and slim["values"]["value"] == result["values"]["value"]
    glb = client.get(f"/v1/jobs/{job['id']}/result.glb")
    assert glb.status_code == 200 and glb.content[:4] == b"glTF"


def test_barycenter_job_matches_solver(client):
    from solvers.convolutional import barycenter
    from solvers.domains import Grid

    grid = Grid((20, 20))
    gid = _grid(client, (20, 20))
    rng = np.random.default_rng(1)
    a, b = rng.random(400), rng.random(400)  # unnormalized on purpose
    body = {"distributions": [a.tolist(), {"indices": [0, 399], "masses": [1.0, 3.0]},
                              b.tolist()],
            "weights": [1, 2, 1], "gamma": 0.01, "tol": 1e-7}
    r = client.post(f"/v1/domains/{gid}/barycenters?wait=20", json=body)
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    result = client.get(f"/v1/jobs/{r.json()['id']}/result").json()
    sparse = np.zeros(400)
    sparse[[0, 399]] = [0.25, 0.75]
    mus = np.stack([a / a.sum(), sparse, b / b.sum()], axis=1)
    direct = barycenter(grid, mus, np.array([0.25, 0.5, 0.25]), gamma=0.01, tol=1e-7)
    assert np.allclose(result["arrays"]["masses"], direct.masses, rtol=1e-9, atol=1e-15)
    assert sum(result["arrays"]["masses"]) == pytest.approx(1.0)
    assert result["values"]["weights"] == [0.25, 0.5, 0.25]
    assert result["values"]["iterations"] == direct.iterations
    assert np.allclose(result["arrays"]["density"], direct.masses / grid.areas)
    report = result["values"]["normalization"]
    assert [x["field"] for x in report] == [f"distributions[{i}]" for i in range(3)]
    assert report[1]["given_total"] == pytest.approx(4.0)


def test_pointwise_distances_job(client, meshes_dir, shared_mesh):
    from solvers.emd import pointwise_distances

    mesh = shared_mesh("woody.obj")
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    job = client.post(f"/v1/domains/{mid}/pointwise-distances", json={"source": 7}).json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    d = np.asarray(result["arrays"]["distances"])
    assert np.allclose(d, pointwise_distances(mesh, 7).distances, rtol=1e-9, atol=1e-12)
    assert d[7] == pytest.approx(0.0, abs=1e-9) and result["values"]["unreachable"] == 0
    # k > 0: the batched spectral ADMM, per-vertex certified gaps and the unconverged count
    job = client.post(f"/v1/domains/{mid}/pointwise-distances", json={"source": 7, "k": 5}).json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    lib = pointwise_distances(mesh, 7, k=5)
    assert np.allclose(result["arrays"]["distances"], lib.distances, rtol=1e-12)
    gaps = np.asarray(result["arrays"]["residuals"])
    assert result["values"]["converged"] and result["values"]["unconverged_targets"] == 0
    assert gaps.max() == pytest.approx(result["values"]["residual"]) and gaps.max() <= 1e-3
    # On a mesh with several components, other components are unreachable (null in JSON).
    suz = shared_mesh("suzanne.obj")
    sid = upload_mesh(client, meshes_dir / "suzanne.obj").json()["id"]
    job = client.post(f"/v1/domains/{sid}/pointwise-distances", json={"source": 3}).json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    other = suz.component_labels != suz.component_labels[3]
    values = result["arrays"]["distances"]
    assert all(values[i] is None for i in np.flatnonzero(other))
    assert all(values[i] is not None for i in np.flatnonzero(~other))
    assert result["values"]["unreachable"] == int(other.sum())


def test_interpolation_job_matches_solver(client):
    from solvers.convolutional import displacement_interpolation
    from solvers.domains import Grid

    grid = Grid((24, 24))
    gid = _grid(client, (24, 24))
    body = {"mu0": {"vertex": 30, "radius": 0.25}, "mu1": {"vertex": 540, "radius": 0.25},
            "times": [0.0, 0.5, 1.0], "gamma": 0.005}
    job = client.post(f"/v1/domains/{gid}/interpolations?wait=20", json=body).json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    d0 = np.linalg.norm(grid.points - grid.points[30], axis=1)
    d1 = np.linalg.norm(grid.points - grid.points[540], axis=1)
    mu0 = grid.areas * np.clip(1 - d0 / 0.25, 0, None)
    mu1 = grid.areas * np.clip(1 - d1 / 0.25, 0, None)
    direct = displacement_interpolation(grid, mu0 / mu0.sum(), mu1 / mu1.sum(), [0.0, 0.5, 1.0],
                                        gamma=0.005)
    frames = np.asarray(result["arrays"]["masses"])
    assert frames.shape == (576, 3)
    assert np.allclose(frames, direct.masses, rtol=1e-9, atol=1e-15)
    assert np.allclose(frames.sum(axis=0), 1.0)
    assert result["export"]["frames"] == [0.0, 0.5, 1.0]
    # The midpoint's mean sits halfway between the endpoints' means.
    means = grid.points.T @ frames
    assert np.allclose(means[:, 1], 0.5 * (means[:, 0] + means[:, 2]), atol=0.02)


def test_propagation_job_matches_solver(client):
    from solvers.convolutional import wasserstein_propagation
    from solvers.domains import Grid

    grid = Grid((20, 20))
    gid = _grid(client, (20, 20))
    ends = {0: {"indices": [0], "masses": [1.0]}, 2: {"indices": [399], "masses": [1.0]}}
    body = {"n_nodes": 3, "edges": [[0, 1], [1, 2]], "gamma": 0.01,
            "fixed": [{"node": k, "distribution": v} for k, v in ends.items()]}
    job = client.post(f"/v1/domains/{gid}/propagations?wait=20", json=body).json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    m = np.asarray(result["arrays"]["masses"])
    direct = wasserstein_propagation(grid, 3, [[0, 1], [1, 2]],
                                     {0: np.eye(400)[0], 2: np.eye(400)[399]}, gamma=0.01)
    assert np.allclose(m, direct.masses, rtol=1e-9, atol=1e-15)
    assert result["values"]["free_nodes"] == [1]
    # The free node sits halfway between the two corners.
    assert np.allclose(grid.points.T @ m[:, 1], [0.5, 0.5], atol=1e-6)
    assert_error(client.post(f"/v1/domains/{gid}/propagations",
                             json={**body, "fixed": body["fixed"] * 2}), 422, "fixed[2].node")


@pytest.mark.parametrize("method", ["sinkhorn", "debiased"])
def test_distance_job_matches_solver(client, meshes_dir, shared_mesh, method):
    from solvers.convolutional import wasserstein_distance

    mesh = shared_mesh("woody.obj")
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    body = {"mu0": {"vertex": 0, "radius": 0.15}, "mu1": {"vertex": 500, "radius": 0.15},
            "debiased": method == "debiased", "gamma": 0.01}
    job = client.post(f"/v1/domains/{mid}/distances", json=body).json()
    assert job["state"] == "succeeded", job
    values = client.get(f"/v1/jobs/{job['id']}/result").json()["values"]
    direct = wasserstein_distance(mesh, _bump(mesh, 0, 0.15), _bump(mesh, 500, 0.15),
                                  gamma=0.01, debiased=method == "debiased")
    assert values["value"] == pytest.approx(direct.value, rel=1e-9)
    assert values["converged"] == direct.converged and values["gamma"] == 0.01


def test_job_input_errors_name_the_field(client, meshes_dir, shared_mesh):
    gid = _grid(client, (5, 5))
    url = f"/v1/domains/{gid}/interpolations"
    ok = [1.0] * 25
    cases = [
        ({"mu0": [1.0] * 24, "mu1": ok, "times": [0.5]}, "mu0", None),
        ({"mu0": ok, "mu1": [1.0] * 24 + [-2.0], "times": [0.5]}, "mu1", None),
        ({"mu0": ok, "mu1": [0.0] * 25, "times": [0.5]}, "mu1", None),
        ({"mu0": {"indices": [3, 99], "masses": [1, 1]}, "mu1": ok, "times": [0.5]},
         "mu0.indices", None),
        ({"mu0": {"indices": [3, 4], "masses": [1]}, "mu1": ok, "times": [0.5]},
         "mu0.masses", None),
        ({"mu0": {"vertex": 25, "radius": 0.1}, "mu1": ok, "times": [0.5]}, "mu0.vertex", None),
        ({"mu0": ok, "mu1": ok, "times": [0.5, 1.5]}, "times", None),  # message: times[1]
        ({"mu0": ok, "mu1": ok, "times": []}, "times", None),
        ({"mu0": ok, "mu1": ok, "times": [0.5], "gamma": -1}, "gamma", None),
        ({"mu0": ok, "mu1": ok, "times": [0.5], "bogus": 1}, "bogus", None),
    ]
    for body, field, code in cases:
        assert_error(client.post(url, json=body), 422, field, code)
    # JSON NaN (accepted by Python's parser) is caught by the mass check.
    raw = ('{"mu0": [NaN' + ", 1" * 24 + '], "mu1": [1' + ", 1" * 24 + '], "times": [0.5]}')
    assert_error(client.post(url, content=raw, headers={"content-type": "application/json"}),
                 422, "mu0")
    bary = f"/v1/domains/{gid}/barycenters"
    assert_error(client.post(bary, json={"distributions": [ok, ok], "weights": [1.0]}), 422,
                 "weights")
    assert_error(client.post(bary, json={"distributions": [ok, [-1.0] + ok[1:]]}), 422,
                 "distributions[1]")
    # Mesh-only operations on a grid; W1 on a grid.
    assert_error(client.post(f"/v1/domains/{gid}/pointwise-distances", json={"source": 0}),
                 422, "domain_id", "unsupported_operation")
    assert_error(client.post(f"/v1/domains/{gid}/distances",
                             json={"mu0": ok, "mu1": ok, "metric": "w1"}), 422, "metric")
    # Several components: mass cannot cross them.
    suz = shared_mesh("suzanne.obj")
    sid = upload_mesh(client, meshes_dir / "suzanne.obj").json()["id"]
    labels = suz.component_labels
    mu0 = np.where(labels == 0, 1.0, 0.0).tolist()
    mu1 = np.where(labels == 1, 1.0, 0.0).tolist()
    err = assert_error(client.post(f"/v1/domains/{sid}/distances", json={"mu0": mu0, "mu1": mu1}),
                       422, "mu1", "unsupported_operation")
    assert "component" in err["message"]
    assert_error(client.post(f"/v1/domains/{sid}/pointwise-distances",
                             json={"source": suz.n}), 422, "source")
    assert_error(client.post(f"/v1/domains/{gid}/barycenters?wait=-1",
                             json={"distributions": [ok]}), 422, "wait")


# -- cancellation and time limits ----------------------------------------------------
def test_cancel_queued_job(make_client, loop_op):
    client = make_client(queue="sqlite")  # no consumer: jobs stay queued
    gid = _grid(client)
    job = _submit(client, gid, iterations=5)
    assert client.get(f"/v1/jobs/{job.id}").json()["state"] == "queued"
    r = client.delete(f"/v1/jobs/{job.id}")
    assert r.status_code == 200 and r.json()["state"] == "cancelled"
    client.app.state.runtime.runner.run(job.id)  # a worker receiving it later does nothing
    after = client.get(f"/v1/jobs/{job.id}").json()
    assert after["state"] == "cancelled" and after["attempts"] == 0
    assert_error(client.get(f"/v1/jobs/{job.id}/result"), 409, "job_id", "job_cancelled")


def test_cancel_running_job(make_client, loop_op):
    client = make_client(queue="sqlite", heartbeat_interval=0.05)
    rt = client.app.state.runtime
    job = _submit(client, _grid(client), iterations=100_000, sleep=0.002)
    worker = threading.Thread(target=rt.runner.run, args=(job.id,))
    worker.start()
    deadline = time.monotonic() + 10
    while (client.get(f"/v1/jobs/{job.id}").json()["progress"]["iteration"] or 0) < 5:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    running = client.get(f"/v1/jobs/{job.id}").json()
    assert running["state"] == "running"
    assert_error(client.get(f"/v1/jobs/{job.id}/result"), 409, "job_id", "job_not_finished")
    r = client.delete(f"/v1/jobs/{job.id}")
    assert r.status_code == 200 and r.json()["cancel_requested"] is True
    worker.join(timeout=10)
    assert not worker.is_alive()
    done = client.get(f"/v1/jobs/{job.id}").json()
    assert done["state"] == "cancelled" and done["error"]["code"] == "cancelled"
    assert done["progress"]["iteration"] < 100_000
    again = client.delete(f"/v1/jobs/{job.id}")  # cancelling twice is harmless
    assert again.status_code == 200 and again.json()["state"] == "cancelled"


def test_time_limit(make_client, loop_op):
    client = make_client()
    job = _submit(client, _grid(client), iterations=100_000, sleep=0.002, time_limit=0.2)
    done = client.get(f"/v1/jobs/{job.id}").json()
    assert done["state"] == "failed"
    assert done["error"]["code"] == "time_limit_exceeded"
    assert done["error"]["field"] == "time_limit"
    assert 0.2 <= done["duration_seconds"] < 5


def test_job_on_a_domain_deleted_meanwhile_fails_cleanly(make_client, loop_op):
    client = make_client(queue="sqlite")
    rt = client.app.state.runtime
    gid = _grid(client)
    done = _submit(client, gid, iterations=2)
    rt.runner.run(done.id)
    queued = _submit(client, gid, iterations=2)
    assert client.delete(f"/v1/domains/{gid}").status_code == 204
    rt.cache.discard(("domain", gid))  # a worker that never loaded it
    rt.runner.run(queued.id)
    failed = client.get(f"/v1/jobs/{queued.id}").json()
    assert failed["state"] == "failed"
    assert failed["error"]["code"] == "not_found" and failed["error"]["field"] == "domain_id"
    # Earlier results are kept.
    assert client.get(f"/v1/jobs/{done.id}/result").json()["values"] == {"iterations": 2}


def test_finished_job_cannot_be_cancelled(client, loop_op):
    job = _submit(client, _grid(client), iterations=2)
    assert client.get(f"/v1/jobs/{job.id}").json()["state"] == "succeeded"
    assert_error(client.delete(f"/v1/jobs/{job.id}"), 409, "job_id", "job_finished")


# -- reaper ----------------------------------------------------------------------------
def test_reaper_requeues_stale_jobs_then_fails(make_client, loop_op):
    client = make_client(queue="sqlite", max_attempts=2, stale_after=1.0)
    rt = client.app.state.runtime
    sent = []
    rt.reaper.enqueue = lambda job_id, queue=None: sent.append(job_id)
    job = _submit(client, _grid(client))
    repo = rt.repo

    def die_while_running(expected_attempt):
        claim = repo.claim(job.id, "dead-worker")
        assert claim is not None and claim.attempt == expected_attempt
        repo._update((JobRow.id == job.id,), heartbeat_at=time.time() - 10)

    die_while_running(1)
    assert rt.reaper.run_once()["requeued"] == [job.id]
    assert sent == [job.id]
    assert client.get(f"/v1/jobs/{job.id}").json()["state"] == "queued"
    assert rt.reaper.run_once() == {"requeued": [], "failed": [], "resent": []}
    die_while_running(2)
    assert rt.reaper.run_once()["failed"] == [job.id]
    failed = client.get(f"/v1/jobs/{job.id}").json()
    assert failed["state"] == "failed" and failed["error"]["code"] == "worker_lost"
    assert failed["attempts"] == 2


def test_reaper_fails_jobs_stuck_past_their_time_limit(make_client, loop_op):
    client = make_client(queue="sqlite", stale_after=1.0)
    rt = client.app.state.runtime
    job = _submit(client, _grid(client), time_limit=5)
    claim = rt.repo.claim(job.id, "busy-worker")
    assert rt.reaper.run_once()["failed"] == []  # within its limit
    rt.repo._update((JobRow.id == job.id,), started_at=time.time() - 10,
                    heartbeat_at=time.time())  # alive, but 10 s into a 5 s limit
    assert rt.reaper.run_once()["failed"] == [job.id]
    failed = client.get(f"/v1/jobs/{job.id}").json()
    assert failed["state"] == "failed" and failed["error"]["code"] == "time_limit_exceeded"
    assert not rt.repo.finish(job.id, claim.attempt, "succeeded")  # late result refused


def test_fresh_heartbeat_is_not_reaped_and_release_keeps_attempts(make_client, loop_op):
    client = make_client(queue="sqlite", stale_after=60)
    rt = client.app.state.runtime
    rt.reaper.enqueue = lambda job_id, queue=None: None
    job = _submit(client, _grid(client))
    claim = rt.repo.claim(job.id, "w")
    assert rt.repo.claim(job.id, "other") is None  # never claimed twice
    assert rt.reaper.run_once()["requeued"] == []
    assert rt.repo.release(job.id, claim.attempt)
    row = rt.repo.get(job.id)
    assert row.state == "queued" and row.attempts == 0
    # A finish by the released attempt is refused.
    assert not rt.repo.finish(job.id, claim.attempt, "succeeded")


# -- persistence, events, metrics --------------------------------------------------------
def test_jobs_and_results_survive_app_recreation(make_client, loop_op, tmp_path):
    first = make_client(queue="sqlite")
    gid = _grid(first)
    job = _submit(first, gid, iterations=3)
    first.app.state.runtime.runner.run(job.id)
    assert first.get(f"/v1/jobs/{job.id}").json()["state"] == "succeeded"
    second = make_client(queue="sqlite")
    again = second.get(f"/v1/jobs/{job.id}").json()
    assert again["state"] == "succeeded" and again["progress"]["iteration"] == 3
    result = second.get(f"/v1/jobs/{job.id}/result").json()
    assert result["values"] == {"iterations": 3} and result["arrays"]["ones"] == [1.0] * 36
    assert [d["id"] for d in second.get("/v1/domains").json()["domains"]] == [gid]
    assert [j["id"] for j in second.get("/v1/jobs").json()["jobs"]] == [job.id]


def test_small_results_live_in_the_job_row_large_ones_in_files(make_client, loop_op):
    from service.store import IN_ROW, ROW_RESULT_BYTES

    first = make_client(queue="sqlite")
    rt = first.app.state.runtime
    gid = _grid(first)
    small = _submit(first, gid, iterations=2, arrays=False, padding=10)
    large = _submit(first, gid, iterations=2, arrays=False, padding=ROW_RESULT_BYTES // 4)
    with_arrays = _submit(first, gid, iterations=2)
    for job in (small, large, with_arrays):
        rt.runner.run(job.id)
    files = rt.store.result_dir
    kept = rt.repo.get(small.id)
    assert kept.result_location == IN_ROW and kept.result["values"]["iterations"] == 2
    assert not (files / f"{small.id}.json").exists()
    for job in (large, with_arrays):  # over the bound, or with arrays: files as before
        row = rt.repo.get(job.id)
        assert row.result is None and (files / f"{job.id}.json").exists()
        assert row.result_location == f"results/{job.id}.json"
    second = make_client(queue="sqlite")  # read back by another process's API
    docs = {job.id: second.get(f"/v1/jobs/{job.id}/result").json()
            for job in (small, large, with_arrays)}
    assert docs[small.id]["values"] == {"iterations": 2, "padding": [0.125] * 10}
    assert docs[large.id]["values"]["padding"] == [0.125] * (ROW_RESULT_BYTES // 4)
    assert docs[with_arrays.id]["arrays"]["ones"] == [1.0] * 36
    assert set(docs[small.id]) == set(docs[large.id])  # the same document either way
    assert_error(second.get(f"/v1/jobs/{small.id}/files/result.png"), 404, "name")
    assert all(j.result is None for j in rt.repo.list())  # pages leave results out


def test_server_sent_events(client, loop_op):
    job = _submit(client, _grid(client), iterations=4)
    r = client.get(f"/v1/jobs/{job.id}/events")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
    blocks = [b for b in r.text.split("\n\n") if b.strip()]
    assert blocks[0].startswith("event: progress")
    data = json.loads(blocks[0].split("data: ", 1)[1])
    assert data["state"] == "succeeded" and data["progress"]["iteration"] == 4
    assert blocks[-1].startswith("event: end")


def _metric(text: str, name: str, **labels) -> float:
    for line in text.splitlines():
        if line.startswith(name + "{") or line.startswith(name + " "):
            found = dict(re.findall(r'(\w+)="([^"]*)"', line.split(" ")[0]))
            if all(found.get(k) == v for k, v in labels.items()):
                return float(line.rsplit(" ", 1)[1])
    raise AssertionError(f"{name} {labels} not in metrics")


def test_operator_builds_counted_once_per_kernel(client):
    gid = _grid(client, (16, 16))
    body = {"mu0": {"vertex": 0, "radius": 0.3}, "mu1": {"vertex": 255, "radius": 0.3},
            "gamma": 0.01}
    for gamma in (0.01, 0.01, 0.02):
        job = client.post(f"/v1/domains/{gid}/distances", json={**body, "gamma": gamma}).json()
        assert job["state"] == "succeeded", job
    text = client.get("/metrics").text
    assert _metric(text, "otgeo_operator_builds_total") == 2  # gamma 0.01 reused, 0.02 new
    assert _metric(text, "otgeo_cache_operators") == 2


def test_metrics_cache_and_jobs(client, meshes_dir):
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    for _ in range(2):
        assert client.post(f"/v1/domains/{mid}/flows", json=FLOW_BODY).json()["state"] == \
            "succeeded"
    text = client.get("/metrics").text
    assert _metric(text, "otgeo_cache_misses_all_total") == 1
    assert _metric(text, "otgeo_cache_hits_all_total") == 1
    assert _metric(text, "otgeo_cache_entries") == 1
    assert _metric(text, "otgeo_cache_bytes") > 0
    assert _metric(text, "otgeo_jobs", operation="flows", state="succeeded") == 2
    assert _metric(text, "otgeo_job_duration_seconds_count", operation="flows",
                   state="succeeded") == 2
    assert _metric(text, "otgeo_queue_depth") == 0


# -- a real Huey consumer in its own process ----------------------------------------------
def _start_worker(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("OTGEO_")}
    env.update({"OTGEO_DATA_DIR": str(tmp_path), "OTGEO_HEARTBEAT_INTERVAL": "0.2",
                "OTGEO_WORKER_POLL_INTERVAL": "0.02"})
    log = open(tmp_path / "worker.log", "ab")  # noqa: SIM115
    proc = subprocess.Popen([sys.executable, "-m", "service.cli", "worker"], cwd=ROOT, env=env,
                            stdout=log, stderr=subprocess.STDOUT)
    return proc, log


def _worker_running_long_job(client, tmp_path, stop) -> dict:
    """Submit a barycenter that runs until stopped, start a worker process, wait until it
    runs the job, then ``stop(proc)`` (SIGTERM or SIGKILL); returns the job."""
    gid = _grid(client, (120, 120))
    body = {"distributions": [{"vertex": 0, "radius": 0.2}, {"vertex": 14399, "radius": 0.2}],
            "gamma": 1e-4, "tol": 1e-15, "max_iter": 100_000}
    job = client.post(f"/v1/domains/{gid}/barycenters", json=body).json()
    proc, log = _start_worker(tmp_path)
    try:
        deadline = time.monotonic() + 30
        while client.get(f"/v1/jobs/{job['id']}").json()["state"] != "running":
            assert time.monotonic() < deadline, (tmp_path / "worker.log").read_text()[-2000:]
            time.sleep(0.02)
        stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
        log.close()
    return job


def test_worker_sigterm_hands_running_job_back(make_client, tmp_path):
    client = make_client(queue="sqlite")

    def terminate(proc):
        proc.terminate()
        assert proc.wait(timeout=15) == 0

    job = _worker_running_long_job(client, tmp_path, terminate)
    back = client.get(f"/v1/jobs/{job['id']}").json()
    assert back["state"] == "queued" and back["attempts"] == 0, back
    assert client.delete(f"/v1/jobs/{job['id']}").json()["state"] == "cancelled"


def test_job_of_a_killed_worker_reruns_from_the_job_table(make_client, tmp_path):
    """Embedded queue (the job table is the queue): a worker killed with SIGKILL mid-job
    loses nothing; the reaper puts the stale job back in the table and the next worker
    claims and finishes it (attempt 2)."""
    client = make_client(queue="sqlite", stale_after=1.0, reaper_interval=0.2)
    rt = client.app.state.runtime

    def kill(proc):  # SIGKILL: no hand-back
        proc.kill()
        proc.wait(timeout=10)

    job = _worker_running_long_job(client, tmp_path, kill)
    deadline = time.monotonic() + 30
    while client.get(f"/v1/jobs/{job['id']}").json()["state"] != "queued":
        rt.reaper.run_once()
        assert time.monotonic() < deadline
        time.sleep(0.1)
    claim = rt.repo.claim_next(("short", "long"), "next-worker")
    assert claim is not None and claim.job.id == job["id"] and claim.attempt == 2
    rt.repo.request_cancel(job["id"])  # the re-run need not finish: it was claimed again
    assert rt.repo.claim_next(("short", "long"), "other") is None


def test_real_worker_process(make_client, meshes_dir, tmp_path):
    proc, log = _start_worker(tmp_path)
    try:
        client = make_client(queue="sqlite")
        mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
        jobs = [client.post(f"/v1/domains/{mid}/flows?wait=30", json=FLOW_BODY).json()
                for _ in range(2)]
        assert [j["state"] for j in jobs] == ["succeeded", "succeeded"], \
            (tmp_path / "worker.log").read_text()[-3000:]
        assert all(j["attempts"] == 1 for j in jobs)
        values = [client.get(f"/v1/jobs/{j['id']}/result?arrays=false").json()["values"]
                  for j in jobs]
        assert values[0]["value"] == values[1]["value"] > 0
        # The worker publishes its cache statistics: one build, then a hit.
        deadline = time.monotonic() + 10
        while True:
            text = client.get("/metrics").text
            if _metric(text, "otgeo_cache_hits_all_total") >= 1 or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        assert _metric(text, "otgeo_workers_alive") == 1
        assert _metric(text, "otgeo_cache_hits_all_total") == 1
        assert _metric(text, "otgeo_cache_misses_all_total") == 1
        # its address space is bounded (base + operator cache + one job: service.limits)
        from service.limits import worker_memory_limit
        from service.settings import Settings

        limits = open(f"/proc/{proc.pid}/limits").read()
        row = next(line for line in limits.splitlines() if line.startswith("Max address space"))
        assert int(row.split()[3]) == worker_memory_limit(Settings())
    finally:
        proc.terminate()
        assert proc.wait(timeout=15) == 0
        log.close()


def test_progress_arity_read_off_the_code_matches_the_signature():
    """The worker's progress callback (a bound method) takes the fraction; the fast reading
    of a callable's arity agrees with ``inspect.signature`` on every kind of callable."""
    import functools

    from service.jobs.runner import _Heartbeat
    from solvers.monitor import _arity, _signature_arity

    class Hook:
        def __call__(self, it, res):
            pass

        def three(self, it, res, fraction=None):
            pass

    def wrapped(*args):
        pass

    @functools.wraps(lambda it, res: None)
    def decorated(*args):
        pass

    hb = _Heartbeat.__new__(_Heartbeat)
    cases = [hb.on_progress, Hook().three, Hook(), lambda it, res: None, wrapped, decorated,
             functools.partial(lambda a, it, res: None, 1), print]
    for fn in cases:
        assert _arity(fn) == _signature_arity(fn), fn
    assert _arity(hb.on_progress) == 3 and _arity(Hook().three) == 3
