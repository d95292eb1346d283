"""The job queues: JSON-only messages (a pickle pushed into the queue is dropped, never
unpickled), a Redis broker behind a password, the short/long split with a reserved worker,
and progress with queue position, fraction done and an estimate."""

from __future__ import annotations

import os
import pickle
import shutil
import socket
import subprocess
import time

import pytest
from huey.registry import Message

from service.jobs.consumer import Consumer
from service.jobs.queue import (
    TASK_STRING,
    JsonSerializer,
    UnsafeMessage,
    make_huey,
    queue_for_cost,
    register_task,
)
from service.operations.cost import estimate_cost
from service.runtime import Runtime
from service.settings import Settings

JOB_ID = "0123456789abcdef0123456789abcdef"


class _Boom:
    """Unpickling this runs code: the attack a pickle queue allows."""

    def __reduce__(self):
        return (os.system, ("touch pwned",))


def test_messages_are_json_carrying_one_job_id(tmp_path):
    huey = make_huey(Settings(data_dir=tmp_path, queue="sqlite"))
    task = register_task(huey, lambda job_id: None)
    raw = huey.serialize_task(task.s(JOB_ID))
    assert raw.startswith(b"{") and JOB_ID.encode() in raw
    back = huey.deserialize_task(raw)
    assert back.args == (JOB_ID,)
    with pytest.raises(UnsafeMessage):
        huey.serialize_task(task.s(JOB_ID, "extra"))
    with pytest.raises(UnsafeMessage):
        huey.serialize_task(task.s({"not": "an id"}))


@pytest.mark.parametrize("payload", [
    pickle.dumps(Message(JOB_ID, TASK_STRING, None, 0, 0, None, (JOB_ID,), {}, None, None,
                         None, None, None, None, None)),
    pickle.dumps(_Boom()),
    b'{"v": 1, "id": "x", "name": "service.jobs.queue.otgeo.run_job", "args": ["../../x y"]}',
    b'{"v": 1, "id": "x", "name": "builtins.eval", "args": ["' + JOB_ID.encode() + b'"]}',
    b"[" * 100_000,
])
def test_serializer_refuses_everything_else(payload):
    with pytest.raises(UnsafeMessage):
        JsonSerializer().deserialize(payload)


def test_pickle_pushed_into_the_queue_is_dropped_not_unpickled(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rt = Runtime(Settings(data_dir=tmp_path, queue="sqlite"), role="worker")
    ran: list[str] = []
    rt.runner.run = ran.append
    try:
        storage = rt.hueys["short"].storage
        storage.enqueue(pickle.dumps(_Boom()))  # what an attacker with broker access writes
        legit = rt.hueys["short"].serialize_task(rt.tasks["short"].s(JOB_ID))
        storage.enqueue(legit)
        consumer = Consumer(rt, ("short", "long"))
        assert consumer.step(0.1) is None  # the pickle: read, logged, dropped
        assert consumer.dropped == 1
        assert consumer.step(0.1) == JOB_ID
        assert ran == [JOB_ID]
        assert not (tmp_path / "pwned").exists()
        assert rt.pending_messages() == 0
    finally:
        rt.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_redis_url_with_password(tmp_path):
    """A Redis of our own with ``requirepass`` (redis-server is installed where .ci/run
    starts the shared one)."""
    assert shutil.which("redis-server"), "redis-server is needed (apt package redis-server)"
    port = _free_port()
    proc = subprocess.Popen(["redis-server", "--port", str(port), "--bind", "127.0.0.1",
                             "--requirepass", "s3cret pass", "--save", "", "--appendonly",
                             "no"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        import redis

        deadline = time.monotonic() + 10
        while True:
            try:
                redis.Redis(port=port, password="s3cret pass").ping()
                break
            except redis.ConnectionError:
                assert time.monotonic() < deadline
                time.sleep(0.05)
        # URL-encoded password (the space), as in OTGEO_REDIS_URL
        good = Settings(data_dir=tmp_path, queue="redis",
                        redis_url=f"redis://:s3cret%20pass@127.0.0.1:{port}/0")
        rt = Runtime(good, role="worker")
        ran: list[str] = []
        rt.runner.run = ran.append
        try:
            rt.enqueue(JOB_ID, "long")
            assert rt.pending_messages() == 1
            consumer = Consumer(rt, ("short", "long"))
            assert consumer.step(2.0) == JOB_ID and ran == [JOB_ID]
        finally:
            rt.close()
        bad = Settings(data_dir=tmp_path, queue="redis",
                       redis_url=f"redis://127.0.0.1:{port}/0")
        with pytest.raises(redis.AuthenticationError):
            make_huey(bad).storage.conn.ping()
    finally:
        proc.terminate()
        proc.wait(10)


def test_cost_chooses_the_queue(tmp_path):
    from service.operations.base import BumpDistribution, OperationRequest

    class Req(OperationRequest):
        distributions: list[BumpDistribution]
        weights: list[float] | None = None
        max_iter: int = 1000

    bumps = [BumpDistribution(vertex=0, radius=0.1)] * 3
    assert estimate_cost(100, Req(distributions=bumps, weights=[0.2, 0.3, 0.5])) == \
        100 * 1000 * 3
    settings = Settings(data_dir=tmp_path, long_job_cost=1e6)
    assert queue_for_cost(settings, estimate_cost(100, Req(distributions=bumps))) == "short"
    assert queue_for_cost(settings, estimate_cost(10_000, Req(distributions=bumps))) == "long"


def test_older_job_table_gains_the_new_columns(tmp_path):
    import sqlalchemy as sa

    from service.jobs.db import ADDED_COLUMNS, ADDED_INDEXES, JobRepository

    url = f"sqlite:///{tmp_path / 'old.sqlite3'}"
    engine = sa.create_engine(url)
    with engine.begin() as conn:  # the table as the first release created it
        conn.execute(sa.text(
            "CREATE TABLE jobs (id VARCHAR(32) PRIMARY KEY, operation VARCHAR(64), "
            "domain_id VARCHAR(64), params JSON, state VARCHAR(16), iteration INTEGER, "
            "residual FLOAT, error JSON, attempts INTEGER, max_attempts INTEGER, "
            "cancel_requested BOOLEAN, time_limit FLOAT, worker VARCHAR(128), "
            "created_at FLOAT, enqueued_at FLOAT, started_at FLOAT, heartbeat_at FLOAT, "
            "finished_at FLOAT, duration FLOAT, result_location VARCHAR(256))"))
        conn.execute(sa.text("INSERT INTO jobs (id, operation, domain_id, params, state, "
                             "attempts, max_attempts, cancel_requested, time_limit, "
                             "created_at, enqueued_at) VALUES ('j1', 'distances', 'd', '{}', "
                             "'queued', 0, 3, 0, 60, 1.0, 1.0)"))
    engine.dispose()
    repo = JobRepository(url)
    try:
        columns = {c["name"] for c in sa.inspect(repo.engine).get_columns("jobs")}
        assert set(ADDED_COLUMNS) <= columns
        indexes = {i["name"] for i in sa.inspect(repo.engine).get_indexes("jobs")}
        assert set(ADDED_INDEXES.values()) <= indexes
        job = repo.get("j1")
        assert job.queue is None and repo.queue_position(job) == 1
        JobRepository(url).dispose()  # a second process starting on it: nothing to add
    finally:
        repo.dispose()


def test_a_job_database_without_update_returning_is_refused_at_start(tmp_path, monkeypatch):
    """Claims and heartbeats are one ``UPDATE ... RETURNING`` each (no fallback): an SQLite
    before 3.35 is refused when the repository opens, naming what is needed, before the
    job table is created."""
    from sqlite3 import dbapi2

    from service.jobs.db import JobRepository

    path = tmp_path / "jobs.sqlite3"
    monkeypatch.setattr(dbapi2, "sqlite_version_info", (3, 31, 1))
    with pytest.raises(RuntimeError, match=r"RETURNING.*SQLite >= 3\.35"):
        JobRepository(f"sqlite:///{path}")
    assert not path.exists()
    monkeypatch.undo()
    repo = JobRepository(f"sqlite:///{path}")  # the SQLite this Python links has it
    try:
        assert repo.engine.dialect.update_returning
        assert repo.claim("no-such-job", "w") is None
    finally:
        repo.dispose()


@pytest.mark.parametrize("backend", ["sqlite", "redis"])
def test_first_submitted_first_started_on_one_worker(make_client, tmp_path, backend):
    """20 jobs on one worker start in submission order, and the recovery checks re-send
    none of them while they merely wait. On SQLite the broker check took every waiting job
    for lost (Huey's SQLite queue holds no message: the job table is the queue), re-sent it
    and rewrote its ``enqueued_at``, which the worker ordered by: the jobs submitted before
    a check then ran after those submitted since (0, 7, 8, 9, 5, 3, ...)."""
    import threading

    from service.jobs import broker

    settings = {"queue": backend, "broker_check_interval": 3600.0, "reaper_interval": 3600.0,
                "requeue_queued_after": 1.0}
    if backend == "redis":  # the local Redis, on a queue of this test's own
        settings.update(redis_url="redis://127.0.0.1:6379/0",
                        queue_name=f"fifo-{os.getpid()}-{time.monotonic_ns()}")
    client = make_client(**settings)
    rt = client.app.state.runtime
    gid = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4]}).json()["id"]

    def submit(k: int) -> list[str]:
        body = {"mu0": {"vertex": 0, "radius": 0.5}, "mu1": {"vertex": 15, "radius": 0.5}}
        return [client.post(f"/v1/domains/{gid}/distances", json=body).json()["id"]
                for _ in range(k)]

    first = submit(10)
    time.sleep(broker.SETTLE_SECONDS + 0.1)  # the first ten are old enough to be checked
    ids = first + submit(10)
    resent = rt.broker_watch.check()
    assert resent == [], resent  # nothing was lost
    if backend == "sqlite":  # the job row is the message: nothing to re-send, ever
        assert rt.reaper.run_once()["resent"] == []
    assert [client.get(f"/v1/jobs/{i}").json()["queue_position"] for i in ids] == \
        list(range(1, 21))

    worker_rt = Runtime(Settings(data_dir=tmp_path, **settings), role="worker")
    consumer = Consumer(worker_rt)
    thread = threading.Thread(target=consumer.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 120
        while not all(rt.repo.get(i).state == "succeeded" for i in ids):
            assert time.monotonic() < deadline, "the jobs did not finish"
            time.sleep(0.05)
    finally:
        consumer.stop()
        thread.join(timeout=10)
        worker_rt.close()
    jobs = [rt.repo.get(i) for i in ids]
    started = sorted(range(len(ids)), key=lambda i: jobs[i].started_at)
    assert started == list(range(len(ids))), started
    assert all(j.attempts == 1 for j in jobs)
    if backend == "redis":
        rt.hueys["short"].storage.flush_queue()
