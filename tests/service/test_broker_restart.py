"""Recovery from a broker restart: queued jobs whose messages a Redis restart (without
persistence) or a flush lost are re-sent from the job table at once, /healthz reports the
broker, and every job runs once."""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time

import pytest

pytestmark = pytest.mark.skipif(shutil.which("redis-server") is None,
                                reason="needs a redis-server binary")

JOBS = 6
CHECK = 0.2  # seconds between broker checks in this test


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class RedisServer:
    """A dedicated redis-server on a spare port, keeping nothing on disk."""

    def __init__(self, port: int, workdir):
        self.port, self.workdir, self.proc = port, workdir, None

    def start(self) -> None:
        import redis

        self.proc = subprocess.Popen(
            ["redis-server", "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "no", "--dir", str(self.workdir)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while True:
            try:
                redis.Redis(port=self.port).ping()
                return
            except redis.ConnectionError:
                assert time.monotonic() < deadline, "redis-server did not start"
                time.sleep(0.02)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)


def _wait(predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def test_jobs_queued_across_a_broker_restart_are_resent_at_once(make_client, tmp_path):
    from service.jobs.consumer import Consumer
    from service.runtime import Runtime
    from service.settings import Settings

    port = _free_port()
    server = RedisServer(port, tmp_path)
    server.start()
    settings = {"queue": "redis", "redis_url": f"redis://127.0.0.1:{port}/0",
                "broker_check_interval": CHECK, "queue_name": f"restart{port}"}
    worker_rt = consumer = thread = None
    try:
        client = make_client(**settings)
        rt = client.app.state.runtime
        gid = client.post("/v1/domains", json={"kind": "grid", "shape": [8, 8]}).json()["id"]
        body = {"mu0": {"vertex": 0, "radius": 0.3}, "mu1": {"vertex": 63, "radius": 0.3}}
        ids = [client.post(f"/v1/domains/{gid}/distances", json=body).json()["id"]
               for _ in range(JOBS)]
        health = client.get("/healthz").json()
        assert health["broker"] == {"reachable": True, "reason": None}, health  # no counts
        assert rt.pending_messages() == JOBS

        _wait(lambda: rt.broker_watch.run_id, 5, "a first check of the broker (its run id)")
        server.stop()  # every message is gone with it
        time.sleep(rt.BROKER_CHECK_EVERY + 0.1)
        down = client.get("/healthz")
        assert down.status_code == 503 and not down.json()["broker"]["reachable"], down.text
        server.start()
        restarted = time.monotonic()
        _wait(lambda: rt.pending_messages() == JOBS, 5, "the re-sent messages")
        resent_after = time.monotonic() - restarted
        assert resent_after < 3.0, resent_after  # not requeue_queued_after (300 s)
        # the count path (fewer messages than queued jobs) may re-send before the run-id
        # path has counted the restart: both run every check, so the count follows at once
        _wait(lambda: rt.broker_watch.restarts == 1, 5, "the restart counted")
        time.sleep(rt.BROKER_CHECK_EVERY + 0.1)  # the health probe's cached answer expires
        assert "otgeo_broker_restarts_total 1\n" in client.get("/metrics").text

        # a flush (same run id): the queue holds fewer messages than the table has jobs
        rt.huey.storage.conn.flushall()
        time.sleep(1.5)  # the just re-sent jobs settle first (SETTLE_SECONDS)
        _wait(lambda: rt.pending_messages() == JOBS, 5, "the messages re-sent after a flush")

        worker_rt = Runtime(Settings(data_dir=tmp_path, **settings), role="worker")
        consumer = Consumer(worker_rt)
        thread = threading.Thread(target=consumer.run, daemon=True)
        thread.start()

        def finished():
            jobs = [client.get(f"/v1/jobs/{i}").json() for i in ids]
            return jobs if all(j["state"] == "succeeded" for j in jobs) else None

        jobs = _wait(finished, 60, "every job to finish")
        assert all(j["attempts"] == 1 for j in jobs), jobs  # each ran once
        assert consumer.dropped == 0
    finally:
        if consumer is not None:
            consumer.stop()
            thread.join(timeout=10)
        if worker_rt is not None:
            worker_rt.close()
        server.stop()
