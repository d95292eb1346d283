"""The latency paths: wake-up datagrams (service.jobs.wake: enqueue wakes a worker blocked on
the SQLite queue, "done" wakes the API's waiting requests, dead registrations are dropped) and
the job row returned by create without reading it back."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest

from service.domains import DomainService
from service.job_service import JobService
from service.jobs.db import JOBS
from service.jobs.wake import JobWaiters, WakeSender, WakeSocket
from service.operations import build_registry
from service.runtime import Runtime
from service.schemas import GridSpec, JobOut
from service.settings import Settings


def _run_in_own_loop(scenario) -> None:
    """``asyncio.run(scenario())`` in a thread of its own: the test process may already run
    an event loop in its main thread (the browser tests' shared Playwright, kept for the
    session), where ``asyncio.run`` refuses to start."""
    failure: list[BaseException] = []

    def run():
        try:
            asyncio.run(scenario())
        except BaseException as exc:  # re-raised in the test's thread
            failure.append(exc)

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    if failure:
        raise failure[0]


def test_sender_reaches_role_and_forgets_closed_sockets(tmp_path):
    worker, api = WakeSocket(tmp_path, "worker"), WakeSocket(tmp_path, "api")
    if worker.sock is None:
        pytest.fail("abstract unix sockets are available on Linux")
    sender = WakeSender(tmp_path)
    try:
        assert sender.notify("worker", "job-1") == 1
        assert worker.wait(1.0) == ["job-1"]
        assert api.drain() == []  # other role untouched
        worker.close()
        assert sender.notify("worker", "job-2") == 0
        assert not any(p.name.startswith("worker@") for p in (tmp_path / "wake").iterdir())
    finally:
        api.close()
        sender.close()


def test_enqueue_wakes_blocked_worker_which_claims_from_the_job_table(tmp_path):
    """The embedded queue is the job table: enqueue only wakes the local workers (no queue
    message), and the woken consumer claims the recorded job."""
    from service.jobs.consumer import Consumer
    from service.jobs.db import QUEUED, JobRow

    rt = Runtime(Settings(data_dir=tmp_path, queue="sqlite"), role="worker")
    wake = WakeSocket(tmp_path, "worker")
    got: list = []
    thread = threading.Thread(target=lambda: got.append((wake.wait(10.0), time.monotonic())))
    try:
        thread.start()
        time.sleep(0.2)  # blocked on the socket by now
        rt.repo.create(JobRow(id="abc", operation="distances", domain_id="", params={},
                              state=QUEUED, queue="short", cost=1.0, attempts=0,
                              max_attempts=3, cancel_requested=False, time_limit=60.0,
                              created_at=time.time(), enqueued_at=time.time()))
        sent = time.monotonic()
        rt.enqueue("abc")
        thread.join(5.0)
        assert got and got[0][0] == ["abc"], "the worker was not woken"
        assert got[0][1] - sent < 2.0  # woken, not the 10 s timeout
        assert sum(int(h.pending_count()) for h in rt.hueys.values()) == 0  # no message
        assert rt.pending_messages() == 1  # the queued job
        claimed: list = []
        rt.runner.run_claimed = claimed.append
        assert Consumer(rt, ("short", "long")).step(0.05) == "abc"
        assert claimed[0].job.id == "abc" and claimed[0].attempt == 1
        assert rt.repo.get("abc").state == "running" and rt.pending_messages() == 0
    finally:
        wake.close()
        rt.close()


def test_done_datagram_sets_waiting_event(tmp_path):
    async def scenario():
        waiters = JobWaiters(tmp_path)
        waiters.attach(asyncio.get_running_loop())
        sender = WakeSender(tmp_path)
        try:
            assert waiters.active
            event, other = waiters.register("job-a"), waiters.register("job-b")
            assert sender.notify("api", "job-a") == 1
            await asyncio.wait_for(event.wait(), 2.0)
            assert not other.is_set()
            waiters.unregister("job-a", event)
            waiters.unregister("job-b", other)
            assert waiters._events == {}
        finally:
            waiters.detach()
            sender.close()

    _run_in_own_loop(scenario)


def test_created_job_is_complete_without_reading_it_back(tmp_path):
    """JobService.create returns the row it wrote (no SELECT): every column must be set."""
    rt = Runtime(Settings(data_dir=tmp_path, queue="sqlite"), role="api")
    try:
        meta, _ = DomainService(rt).from_spec(GridSpec(kind="grid", shape=[6, 6]))
        body = build_registry().get_operation("distances").request_model.model_validate(
            {"mu0": {"vertex": 0, "radius": 0.2}, "mu1": {"vertex": 35, "radius": 0.2}})
        job = JobService(rt).create("distances", meta["id"], body)
        assert set(JOBS.c.keys()) <= set(vars(job))
        assert JobOut.from_row(job, rt.operations) == JobOut.from_row(rt.repo.get(job.id),
                                                            rt.operations)
    finally:
        rt.close()


def test_done_before_registration_wakes_at_once(tmp_path):
    """A job can end before its request registers (submission in the thread pool, a quick
    worker): the remembered "done" datagram sets the late event at once."""

    async def scenario():
        waiters = JobWaiters(tmp_path)
        waiters.attach(asyncio.get_running_loop())
        sender = WakeSender(tmp_path)
        try:
            assert sender.notify("api", "job-a") == 1
            for _ in range(100):  # the loop reads the datagram
                await asyncio.sleep(0.01)
                if "job-a" in waiters._done:
                    break
            late, other = waiters.register("job-a"), waiters.register("job-b")
            assert late.is_set() and not other.is_set()
        finally:
            waiters.detach()
            sender.close()

    _run_in_own_loop(scenario)


def _grid_runtime(tmp_path, shape=(6, 6)):
    rt = Runtime(Settings(data_dir=tmp_path, queue="sqlite"), role="api")
    meta, _ = DomainService(rt).from_spec(GridSpec(kind="grid", shape=list(shape)))
    return rt, meta["id"]


def _distance(**extra):
    return build_registry().get_operation("distances").request_model.model_validate(
        {"mu0": {"vertex": 0, "radius": 0.2}, "mu1": {"vertex": 35, "radius": 0.2}, **extra})


def test_only_bounded_small_submissions_run_on_the_loop(tmp_path, monkeypatch):
    """An explicit gamma (no automatic choice) on a small domain: on the loop; the automatic
    decision (exact-route estimate, regularization policy), route 'exact', W1 or a domain
    above LOOP_SUBMISSION_POINTS: in the thread pool."""
    import service.job_service as jobs_service

    rt, domain_id = _grid_runtime(tmp_path)
    try:
        svc = JobService(rt)
        assert svc.submits_on_loop("distances", domain_id, _distance(gamma=0.01))
        assert not svc.submits_on_loop("distances", domain_id, _distance())
        assert not svc.submits_on_loop("distances", domain_id,
                                       _distance(gamma=0.01, method="exact"))
        assert not svc.submits_on_loop("distances", domain_id,
                                       _distance(gamma=0.01, metric="w1"))
        monkeypatch.setattr(jobs_service, "LOOP_SUBMISSION_POINTS", 35)
        assert not svc.submits_on_loop("distances", domain_id, _distance(gamma=0.01))
    finally:
        rt.close()


def test_loop_submission_skips_the_thread_pool_and_records_the_same_job(make_client,
                                                                       monkeypatch):
    import service.api.operations as routes

    hops: list = []
    original = routes.run_in_threadpool

    async def counted(fn, *args, **kwargs):
        hops.append(fn)
        return await original(fn, *args, **kwargs)

    monkeypatch.setattr(routes, "run_in_threadpool", counted)
    client = make_client(queue="sqlite", workers=0)
    domain_id = client.post("/v1/domains", json={"kind": "grid", "shape": [6, 6]}).json()["id"]
    body = {"mu0": {"vertex": 0, "radius": 0.2}, "mu1": {"vertex": 35, "radius": 0.2}}
    on_loop = client.post(f"/v1/domains/{domain_id}/distances", json={**body, "gamma": 0.01})
    assert on_loop.status_code == 202 and hops == []
    job = on_loop.json()
    assert job["state"] == "queued" and job["decision"]["method"] == "convolutional"
    assert client.get(f"/v1/jobs/{job['id']}").json() == job
    pooled = client.post(f"/v1/domains/{domain_id}/distances", json=body)
    assert pooled.status_code == 202 and hops == [routes.submit_job]
    # errors are the same 4xx on the loop
    bad = client.post(f"/v1/domains/{domain_id}/distances",
                      json={**body, "gamma": 0.01, "mu1": {"vertex": 99, "radius": 0.2}})
    assert bad.status_code == 422 and bad.json()["error"]["field"] == "mu1.vertex"


def test_insert_that_would_wait_for_the_write_lock_is_handed_on(tmp_path):
    """On the loop the INSERT does not wait for another writer: PendingJob carries the
    validated job, written by ``record`` once the lock is free (in the thread pool)."""
    import sqlite3

    from service.job_service import PendingJob
    from service.jobs.db import WriteBusy

    rt, domain_id = _grid_runtime(tmp_path)
    other = sqlite3.connect(rt.repo.engine.url.database, isolation_level=None)
    try:
        svc = JobService(rt)
        other.execute("BEGIN IMMEDIATE")  # another process's write transaction
        t0 = time.monotonic()
        with pytest.raises(PendingJob) as pending:
            svc.create("distances", domain_id, _distance(gamma=0.01), nowait=True)
        assert time.monotonic() - t0 < 1.0  # not the 30 s busy timeout
        assert isinstance(pending.value.__cause__, WriteBusy)
        job = pending.value.job
        assert rt.repo.get(job.id) is None  # nothing written
        other.execute("COMMIT")
        assert svc.record(job) is job and rt.repo.get(job.id).state == "queued"
        # the pool connection waits again (busy timeout restored) for the next writer
        with rt.repo.engine.connect() as conn:
            assert conn.exec_driver_sql("PRAGMA busy_timeout").scalar() == 30_000
    finally:
        other.close()
        rt.close()


def test_idle_worker_sees_an_empty_queue_without_taking_the_write_lock(tmp_path):
    """After every job a worker asks for the next one: on an empty queue that is a read, not
    a write transaction waiting behind other writers."""
    import sqlite3

    rt = Runtime(Settings(data_dir=tmp_path, queue="sqlite"), role="worker")
    other = sqlite3.connect(rt.repo.engine.url.database, isolation_level=None)
    try:
        other.execute("BEGIN IMMEDIATE")
        t0 = time.monotonic()
        assert rt.repo.claim_next(("short", "long"), "w") is None
        assert rt.hueys["short"].storage.dequeue_now() is None
        assert time.monotonic() - t0 < 1.0
    finally:
        other.execute("ROLLBACK")
        other.close()
        rt.close()
