"""A W2 distance matrix fanned out over the workers (service.jobs.fanout): its row blocks are
jobs of their own on the same queue, the job merges them.  Same values as the matrix in one
call, one worker or two; a block of a killed worker re-runs (only it); cancellation keeps
the finished blocks; the memory estimate (whole matrix and per block) refuses at submission.
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from service_testing import assert_error, upload_mesh

from service.jobs.db import JobRow
from service.jobs.fanout import block_id
from service.jobs.runner import JobRunner
from service.operations import matrices
from solvers.convolutional.matrix import distance_matrix

ROOT = Path(__file__).resolve().parents[2]
SHAPE = (14, 14)
SPOTS = [{"vertex": v, "radius": 3.5} for v in range(0, 196, 9)]  # 22 distributions
BODY = {"distributions": SPOTS, "gamma": 0.02, "substeps": 4, "debiased": True}
BLOCK_PAIRS = 40  # pairs per block in these tests (22 rows: 6 blocks)


@pytest.fixture(autouse=True)
def small_blocks(monkeypatch):
    monkeypatch.setattr(matrices, "block_target", lambda points: BLOCK_PAIRS)


def _grid(client) -> str:
    return client.post("/v1/domains", json={"kind": "grid", "shape": list(SHAPE)}).json()["id"]


def _matrix(client, job_id) -> np.ndarray:
    r = client.get(f"/v1/jobs/{job_id}/arrays/matrix.npy")
    assert r.status_code == 200, r.text
    return np.load(io.BytesIO(r.content))


def _unsplit(client, gid: str, body: dict) -> np.ndarray:
    """The matrix as one library call on the job's masses (what one worker computed before
    the fan-out), with the job's decided arguments."""
    rt = client.app.state.runtime
    domain = rt.runner.domain(gid)
    req = matrices.DistanceMatrixRequest(**body)
    view = matrices.view_of_domain(domain)
    rows, others, _ = matrices._inputs(view, req)
    decision = matrices.decide_matrix_job(view, req)
    return distance_matrix(domain, rows, others, **matrices._solver_kwargs(req, decision)).values


def _blocks(rt, job_id: str) -> list[JobRow]:
    return rt.repo.children(job_id)


def _serve(runner: JobRunner, stop: threading.Event) -> None:
    """A second worker in this process: claims any queued job (the blocks) until stopped."""
    while not stop.is_set():
        claim = runner.repo.claim_next(("short", "long"), runner.worker_id, probe=True)
        if claim is None:
            time.sleep(0.005)
        else:
            runner.run_claimed(claim)


def test_one_worker_equals_the_unsplit_matrix(make_client):
    client = make_client(queue="sqlite")
    rt = client.app.state.runtime
    gid = _grid(client)
    job = client.post(f"/v1/domains/{gid}/distance-matrices", json=BODY).json()
    blocks = job["decision"]["blocks"]
    assert len(blocks) == 6 and blocks[0][0] == 0 and blocks[-1][1] == len(SPOTS)
    assert all(a[1] == b[0] for a, b in zip(blocks, blocks[1:], strict=False))
    rt.runner.run(job["id"])  # one worker: the job runs every block itself
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["state"] == "succeeded", done
    values = client.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()["values"]
    assert values["complete"] and values["pairs_solved"] == 231  # 22 * 21 / 2, zero diagonal
    assert values["finished_rows"] == list(range(len(SPOTS)))
    D = _matrix(client, job["id"])
    assert np.array_equal(D, _unsplit(client, gid, BODY))  # bit for bit
    rows = _blocks(rt, job["id"])
    assert len(rows) == 6 and all(r.state == "succeeded" and r.attempts == 1 for r in rows)
    assert {r.worker for r in rows} == {rt.runner.worker_id}
    # blocks are part of their job: not listed among the jobs
    assert [j["id"] for j in client.get("/v1/jobs").json()["jobs"]] == [job["id"]]


def _run_on_two_workers(rt, job_id: str) -> None:
    """Run job ``job_id`` on the first worker while a second one (a thread of this
    process) takes blocks from the queue."""
    second = JobRunner(rt.settings, rt.store, rt.repo, rt.cache, rt.operations)
    second.worker_id = "second-worker"
    stop = threading.Event()
    helper = threading.Thread(target=_serve, args=(second, stop))
    claim = rt.repo.claim(job_id, rt.runner.worker_id)  # the job on the first worker
    helper.start()
    try:
        rt.runner.run_claimed(claim)
    finally:
        stop.set()
        helper.join(timeout=60)


def test_two_workers_give_the_values_of_one(make_client):
    client = make_client(queue="sqlite", heartbeat_interval=0.05)
    rt = client.app.state.runtime
    gid = _grid(client)
    body = {**BODY, "others": SPOTS[:9]}  # 22 x 9: 198 pairs, 5 blocks
    job = client.post(f"/v1/domains/{gid}/distance-matrices", json=body).json()
    _run_on_two_workers(rt, job["id"])
    assert client.get(f"/v1/jobs/{job['id']}").json()["state"] == "succeeded"
    rows = _blocks(rt, job["id"])
    assert len(rows) == len(job["decision"]["blocks"]) == 5
    assert all(r.state == "succeeded" and r.attempts == 1 for r in rows)  # each ran once
    assert "second-worker" in {r.worker for r in rows}
    D = _matrix(client, job["id"])
    assert D.shape == (22, 9) and np.isfinite(D).all()
    assert np.array_equal(D, _unsplit(client, gid, body))


def test_one_or_two_workers_give_the_same_bits_on_a_mesh(make_client, meshes_dir):
    """On a mesh the blocks are fixed by the decision, so who runs them does not change a
    bit (a block against the matrix in one call differs by ulps: see the docs)."""
    client = make_client(queue="sqlite", heartbeat_interval=0.05)
    rt = client.app.state.runtime
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    body = {"distributions": [{"vertex": v, "radius": 0.3} for v in range(0, 690, 60)],
            "gamma": 0.01, "substeps": 4, "debiased": True}  # 12 bumps, 66 pairs
    one = client.post(f"/v1/domains/{mid}/distance-matrices", json=body).json()
    assert len(one["decision"]["blocks"]) >= 2
    rt.runner.run(one["id"])
    two = client.post(f"/v1/domains/{mid}/distance-matrices", json=body).json()
    _run_on_two_workers(rt, two["id"])
    for job in (one, two):
        assert client.get(f"/v1/jobs/{job['id']}").json()["state"] == "succeeded"
    assert np.array_equal(_matrix(client, one["id"]), _matrix(client, two["id"]))
    D = _matrix(client, one["id"])
    whole = _unsplit(client, mid, body)
    np.testing.assert_allclose(D, whole, rtol=1e-9, atol=0)


def _start_worker(tmp_path: Path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("OTGEO_")}
    env.update({"OTGEO_DATA_DIR": str(tmp_path), "OTGEO_HEARTBEAT_INTERVAL": "0.05",
                "OTGEO_WORKER_POLL_INTERVAL": "0.02"})
    log = open(tmp_path / "worker.log", "ab")  # noqa: SIM115
    proc = subprocess.Popen([sys.executable, "-m", "service.cli", "worker"], cwd=ROOT,
                            env=env, stdout=log, stderr=subprocess.STDOUT)
    return proc, log


def _wait(what, check, timeout=120, tmp_path=None):
    deadline = time.monotonic() + timeout
    while True:
        got = check()
        if got:
            return got
        assert time.monotonic() < deadline, (what, (tmp_path / "worker.log").read_text()[-3000:]
                                             if tmp_path else "")
        time.sleep(0.02)


def test_a_killed_worker_loses_only_its_block(make_client, tmp_path, monkeypatch):
    """A worker process runs the job (and so its blocks); killed with SIGKILL in the middle
    of a block, the reaper re-queues that block and the job; the next worker keeps the
    finished blocks, re-runs the lost one: every entry once, each block's result merged
    once (the killed block ran twice, the others once)."""
    client = make_client(queue="sqlite", stale_after=1.0, reaper_interval=0.2,
                         heartbeat_interval=0.05)
    rt = client.app.state.runtime
    gid = _grid(client)
    # 5 blocks of slow pairs: a window of seconds in which a later block runs, wide enough
    # for this process's polls on a loaded machine (with 3 blocks of ~1 s the whole job once
    # finished between two polls in CI)
    monkeypatch.setattr(matrices, "block_target", lambda points: 50)
    body = {**BODY, "gamma": 0.004, "substeps": 16}
    job = client.post(f"/v1/domains/{gid}/distance-matrices", json=body).json()
    ids = [block_id(job["id"], k) for k in range(len(job["decision"]["blocks"]))]
    assert len(ids) >= 4
    proc, log = _start_worker(tmp_path)
    try:
        def mid_block():  # a later block running with pairs done, an earlier one finished
            assert rt.repo.get(job["id"]).state != "succeeded", "no block caught running"
            rows = {r.id: r for r in _blocks(rt, job["id"])}
            running = [i for i in ids[1:] if i in rows and rows[i].state == "running"
                       and (rows[i].iteration or 0) >= 1]
            return running[0] if running and rows[ids[0]].state == "succeeded" else None

        killed = _wait("a block in progress", mid_block, tmp_path=tmp_path)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        log.close()
    before = {r.id: (r.state, r.attempts, r.finished_at) for r in _blocks(rt, job["id"])}
    assert before[killed][0] == "running"
    # the reaper (this process's thread) puts the job and the killed block back
    _wait("the job re-queued", lambda: rt.repo.get(job["id"]).state == "queued")
    _wait("the block re-queued", lambda: rt.repo.get(killed).state == "queued")
    rt.runner.run(job["id"])  # the next worker: this process
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["state"] == "succeeded" and done["attempts"] == 2, done
    after = {r.id: r for r in _blocks(rt, job["id"])}
    assert after[killed].attempts == 2  # the lost block ran again, once
    for i, (state, attempts, finished_at) in before.items():
        if state == "succeeded":  # finished blocks kept, not re-run
            assert after[i].attempts == attempts == 1 and after[i].finished_at == finished_at
    values = client.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()["values"]
    assert values["complete"] and values["pairs_solved"] == 231
    per_block = [rt.store.get_result(i)["values"]["pairs_solved"] for i in ids]
    assert sum(per_block) == 231  # each pair in exactly one merged block result
    assert np.array_equal(_matrix(client, job["id"]), _unsplit(client, gid, body))


def test_cancelled_fanned_matrix_keeps_its_finished_blocks(make_client, monkeypatch):
    client = make_client(queue="sqlite", heartbeat_interval=0.05)
    rt = client.app.state.runtime
    gid = _grid(client)
    monkeypatch.setattr(matrices, "block_target", lambda points: 90)  # 3 blocks of ~1 s
    body = {**BODY, "gamma": 0.004, "substeps": 8}
    job = client.post(f"/v1/domains/{gid}/distance-matrices", json=body).json()
    ids = [block_id(job["id"], k) for k in range(len(job["decision"]["blocks"]))]
    worker = threading.Thread(target=rt.runner.run, args=(job["id"],))
    worker.start()
    _wait("the first block finished", lambda: [r.state for r in _blocks(rt, job["id"])
                                               if r.id == ids[0]] == ["succeeded"])
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 200
    worker.join(timeout=60)
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["state"] == "cancelled" and done["error"]["code"] == "cancelled"
    rows = {r.id: r for r in _blocks(rt, job["id"])}
    assert all(r.state in ("succeeded", "cancelled") for r in rows.values())
    assert rows[ids[-1]].state == "cancelled"  # the last block never ran to its end
    values = client.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()["values"]
    assert not values["complete"] and not values["converged"]
    stop0 = job["decision"]["blocks"][0][1]  # rows of the first block
    assert values["finished_rows"][:stop0] == list(range(stop0))
    assert values["pairs_solved"] < 231
    D = _matrix(client, job["id"])
    whole = _unsplit(client, gid, body)
    finished = ~np.isnan(D)
    assert np.array_equal(D[finished], whole[finished])  # what finished is the full value
    assert np.isnan(D[-2, -1])


def test_memory_estimated_for_the_matrix_and_per_block(make_client):
    client = make_client()
    gid = _grid(client)
    job = client.post(f"/v1/domains/{gid}/distance-matrices", json=BODY).json()
    d = job["decision"]
    assert 0 < d["block_bytes"] <= d["matrix_bytes"]
    # refused at submission once the larger of the block and the merge exceeds the limit
    small = make_client(job_memory_bytes=d["block_bytes"] // 2)
    gid = _grid(small)
    assert_error(small.post(f"/v1/domains/{gid}/distance-matrices", json=BODY), 413,
                 "distributions")


def test_a_matrix_whose_pairs_may_be_exact_runs_as_one_block(make_client, meshes_dir):
    """Default W2 on a mesh may take the exact method, whose ground distances are built once
    for the whole matrix: it is not split (a block would rebuild them for its rows)."""
    client = make_client(queue="sqlite")
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    bumps = [{"vertex": v, "radius": 0.3} for v in range(0, 690, 60)]
    auto = client.post(f"/v1/domains/{mid}/distance-matrices",
                       json={"distributions": bumps}).json()
    assert auto["decision"]["blocks"] == [[0, len(bumps)]]
    given = client.post(f"/v1/domains/{mid}/distance-matrices",
                        json={"distributions": bumps, "gamma": 0.01, "substeps": 4}).json()
    assert len(given["decision"]["blocks"]) >= 2
