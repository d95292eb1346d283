"""The latency paths: wake-up datagrams (service.jobs.wake: enqueue wakes a worker blocked on
the SQLite queue, "done" wakes the API's waiting requests, dead registrations are dropped) and
the job row returned by create without reading it back."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest

from service.domains import DomainService
from service.jobs.db import JOBS
from service.jobs.service import JobService
from service.jobs.wake import JobWaiters, WakeSender, WakeSocket
from service.operations import build_registry
from service.runtime import Runtime
from service.schemas import GridSpec, JobOut
from service.settings import Settings


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

    asyncio.run(scenario())


def test_created_job_is_complete_without_reading_it_back(tmp_path):
    """JobService.create returns the row it wrote (no SELECT): every column must be set."""
    rt = Runtime(Settings(data_dir=tmp_path, queue="sqlite"), role="api")
    try:
        meta, _ = DomainService(rt).from_spec(GridSpec(kind="grid", shape=[6, 6]))
        body = build_registry().get_operation("distances").request_model.model_validate(
            {"mu0": {"vertex": 0, "radius": 0.2}, "mu1": {"vertex": 35, "radius": 0.2}})
        job = JobService(rt).create("distances", meta["id"], body)
        assert set(JOBS.c.keys()) <= set(vars(job))
        assert JobOut.from_row(job) == JobOut.from_row(rt.repo.get(job.id))
    finally:
        rt.close()
