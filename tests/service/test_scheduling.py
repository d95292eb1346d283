"""Short jobs do not wait behind long ones: a job's estimated cost picks the short or long
queue, consumers take short jobs first, and a worker reserved for short jobs runs one while
the other worker is busy with a long job. Jobs show their queue, queue position, fraction
done and an estimate."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from service.jobs.consumer import Consumer
from service.runtime import Runtime
from service.settings import Settings

A, B = "a" * 32, "b" * 32

# a barycenter that runs until cancelled (tol unreachable): estimated 14400 x 1e5 x 2
LONG = {"distributions": [{"vertex": 0, "radius": 0.2}, {"vertex": 14399, "radius": 0.2}],
        "gamma": 1e-4, "tol": 1e-15, "max_iter": 100_000}
SHORT = {"mu0": {"vertex": 0, "radius": 0.5}, "mu1": {"vertex": 35, "radius": 0.5}}


def _queued(rt: Runtime, job_id: str, queue: str, at: float) -> None:
    """A queued job row (the embedded queue's message: the job table is the queue)."""
    from service.jobs.db import QUEUED, JobRow

    rt.repo.create(JobRow(id=job_id, operation="distances", domain_id="", params={},
                          state=QUEUED, queue=queue, cost=1.0, attempts=0, max_attempts=3,
                          cancel_requested=False, time_limit=60.0, created_at=at,
                          enqueued_at=at))


def test_consumer_takes_short_jobs_first_and_reserved_ones_only_short(tmp_path):
    rt = Runtime(Settings(data_dir=tmp_path, queue="sqlite"), role="worker")
    ran: list[str] = []
    rt.runner.run_claimed = lambda claim: ran.append(claim.job.id)
    try:
        _queued(rt, A, "long", 1.0)
        _queued(rt, B, "short", 2.0)
        reserved = Consumer(rt, ("short",))
        both = Consumer(rt, ("short", "long"))
        assert reserved.step(0.05) == B  # the short job, although enqueued second
        assert reserved.step(0.05) is None  # never takes the long one
        assert both.step(0.05) == A
        assert ran == [B, A]
        assert both.step(0.05) is None  # each job claimed once
        assert rt.repo.get(A).state == "running" and rt.repo.get(A).attempts == 1
    finally:
        rt.close()


def _start_consumers(tmp_path: Path, specs) -> list:
    """Worker runtimes with their consumers in threads of this process (the code a worker
    process runs, without two interpreter start-ups)."""
    started = []
    for queues in specs:
        rt = Runtime(Settings(data_dir=tmp_path, queue="sqlite", heartbeat_interval=0.2,
                              worker_poll_interval=0.02), role="worker")
        consumer = Consumer(rt, queues)
        thread = threading.Thread(target=consumer._loop, daemon=True, name=f"worker-{queues}")
        thread.start()
        started.append((rt, consumer, thread))
    return started


def _wait(predicate, timeout, what, logs=()):
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            tails = "\n".join(p.read_text()[-1500:] for p in logs if p.exists())
            raise AssertionError(f"timed out waiting for {what}\n{tails}")
        time.sleep(0.05)


def test_short_job_runs_while_long_jobs_occupy_the_other_worker(make_client, tmp_path):
    client = make_client(queue="sqlite")
    big = client.post("/v1/domains", json={"kind": "grid", "shape": [120, 120]}).json()["id"]
    small = client.post("/v1/domains", json={"kind": "grid", "shape": [6, 6]}).json()["id"]
    workers = _start_consumers(tmp_path, [("short", "long"), ("short",)])
    logs = ()
    try:
        long1 = client.post(f"/v1/domains/{big}/barycenters", json=LONG).json()
        long2 = client.post(f"/v1/domains/{big}/barycenters", json=LONG).json()
        assert long1["queue"] == long2["queue"] == "long"

        def running():
            job = client.get(f"/v1/jobs/{long1['id']}").json()
            return job if job["state"] == "running" and job["progress"]["fraction"] is not None \
                else None

        job = _wait(running, 60, "the first long job to run and report progress", logs)
        assert 0.0 <= job["progress"]["fraction"] <= 1.0
        waiting = client.get(f"/v1/jobs/{long2['id']}").json()
        assert waiting["state"] == "queued" and waiting["queue_position"] == 1  # next in line
        metrics = client.get("/metrics").text
        assert 'otgeo_queue_depth_by_queue{queue="long"} 1' in metrics, metrics
        assert 'otgeo_queue_depth_by_queue{queue="short"} 0' in metrics

        t0 = time.monotonic()
        short = client.post(f"/v1/domains/{small}/distances?wait=30", json=SHORT).json()
        waited = time.monotonic() - t0
        assert short["queue"] == "short"
        assert short["state"] == "succeeded", short
        assert waited < 15, waited  # it did not wait for a long job (they run until cancelled)
        assert client.get(f"/v1/jobs/{long1['id']}").json()["state"] == "running"
        assert client.get(f"/v1/jobs/{long2['id']}").json()["state"] == "queued"

        def with_eta():  # the ETA needs a fraction above 0: a few iterations on a busy machine
            job = client.get(f"/v1/jobs/{long1['id']}").json()
            return job if job["progress"]["eta_seconds"] is not None else None

        later = _wait(with_eta, 60, "the running long job to report an ETA", logs)
        assert later["state"] == "running"
        assert later["progress"]["eta_seconds"] >= 0
        for job in (long2, long1):
            client.delete(f"/v1/jobs/{job['id']}")
        _wait(lambda: client.get(f"/v1/jobs/{long1['id']}").json()["state"] == "cancelled",
              30, "the long job to stop", logs)
    finally:
        for _, consumer, _ in workers:
            consumer.stop()
        for rt, _, thread in workers:
            thread.join(30)
            rt.close()
