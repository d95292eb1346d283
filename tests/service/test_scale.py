"""Scaled-out deployment against a real Redis (queue) and PostgreSQL (job table).

API and workers are separate ``otgeo`` processes, as in docker/compose.yaml. Workers are
killed with SIGKILL mid-job (by pid) and the reaper must re-run the job, or fail it after
``max_attempts``; two workers never run a job twice; a running job can be cancelled; the
API restarts without losing jobs or results. Redis and PostgreSQL must be reachable
(``.ci/run`` starts them): these tests fail, never skip, when they are not.
"""

from __future__ import annotations

import signal
import uuid

import httpx
import pytest
import sqlalchemy as sa
from liveserver import API, Worker, stop_all, wait_for

from service.jobs.db import make_engine

REDIS_URL = "redis://127.0.0.1:6379/0"
PG_ADMIN = dict(host="127.0.0.1", port=5432, user="postgres", dbname="postgres")
STALE_AFTER = 2.0
MAX_ATTEMPTS = 2
# W1 flow by ADMM on cow.obj (2,903 vertices): ~1.2 ms per iteration (measured), progress
# every 10; LONG runs ~3.5 s so cancels and kills land mid-job.
# ADMM flows: a job of a chosen length (the interior point stops at its certified optimum)
LONG = {"method": "admm", "max_iter": 3000, "tol": 1e-12}  # never converges early
SHORT = {"method": "admm", "max_iter": 20, "tol": 1e-12}


def ran_to_its_cap(job: dict) -> bool:
    """These jobs stop at ``max_iter`` short of tol 1e-12: a full run ends ``failed`` with
    ``not_converged`` (never a success), its partial result kept."""
    return job["state"] == "failed" and (job["error"] or {}).get("code") == "not_converged"


def _require_redis() -> None:
    import redis

    try:
        redis.Redis.from_url(REDIS_URL, socket_connect_timeout=2).ping()
    except Exception as exc:
        pytest.fail(f"Redis at {REDIS_URL} is not reachable ({exc}); .ci/run starts it")


def _admin():
    import psycopg2

    try:
        conn = psycopg2.connect(connect_timeout=3, **PG_ADMIN)
    except Exception as exc:
        pytest.fail(f"PostgreSQL at 127.0.0.1:5432 is not reachable ({exc}); .ci/run starts it")
    conn.autocommit = True
    return conn


class Stack:
    """API + workers sharing one Redis queue, one PostgreSQL database and one data dir."""

    def __init__(self, env: dict[str, str], logs, db_url: str):
        self.env, self.logs = env, logs
        self.db = make_engine(db_url)
        self.workers: list[Worker] = []
        self.serial = 0
        self.api = API(self.env, self.logs, name="api-0")

    def restart_api(self) -> None:
        self.api.kill(signal.SIGKILL)
        self.api.stop()
        self.api = API(self.env, self.logs, name=f"api-{uuid.uuid4().hex[:6]}")
        self.api.wait_healthy(timeout=60)

    def spawn_workers(self, count: int) -> list[Worker]:
        """Start workers without waiting: they come up while the test goes on."""
        new = []
        for _ in range(count):
            self.serial += 1
            new.append(Worker(self.env, self.logs, name=f"worker-{self.serial}"))
        self.workers += new
        return new

    def live_workers(self) -> list[Worker]:
        return [w for w in self.workers if w.alive()]

    def ensure_workers(self, count: int, ready: bool = False) -> None:
        missing = count - len(self.live_workers())
        if missing > 0:
            self.spawn_workers(missing)
        if ready:
            live = self.live_workers()
            wait_for(lambda: all(w.ready() for w in live), 60, 0.1, "workers ready")

    # -- HTTP ---------------------------------------------------------------
    def post(self, path: str, **kw) -> httpx.Response:
        return httpx.post(self.api.url + path, timeout=30, **kw)

    def get(self, path: str, **kw) -> httpx.Response:
        return httpx.get(self.api.url + path, timeout=30, **kw)

    def job(self, job_id: str) -> dict:
        r = self.get(f"/v1/jobs/{job_id}")
        assert r.status_code == 200, r.text
        return r.json()

    def submit_flow(self, domain_id: str, options: dict) -> str:
        body = {"mu0": {"vertex": 0, "radius": 0.15}, "mu1": {"vertex": 1500, "radius": 0.15},
                **options}
        r = self.post(f"/v1/domains/{domain_id}/flows", json=body)
        assert r.status_code == 202, r.text
        return r.json()["id"]

    def wait_state(self, job_id: str, states, timeout: float) -> dict:
        states = {states} if isinstance(states, str) else set(states)
        return wait_for(lambda: (j := self.job(job_id))["state"] in states and j, timeout,
                        0.05, f"job {job_id} in {states}")

    def wait_running(self, job_id: str, attempts: int = 1, timeout: float = 20) -> dict:
        def running():
            j = self.job(job_id)
            assert j["state"] in ("queued", "running"), j
            ok = (j["state"] == "running" and j["attempts"] == attempts
                  and (j["progress"]["iteration"] or 0) >= 1)
            return ok and j
        return wait_for(running, timeout, 0.05, f"job {job_id} running (attempt {attempts})")

    # -- job table ------------------------------------------------------------
    def row(self, job_id: str) -> dict:
        with self.db.connect() as c:
            return dict(c.execute(sa.text("SELECT * FROM jobs WHERE id = :id"),
                                  {"id": job_id}).mappings().one())

    def worker_of(self, job_id: str) -> Worker:
        pid = int(self.row(job_id)["worker"].rsplit(":", 1)[1])
        (worker,) = [w for w in self.workers if w.pid == pid]
        return worker

    def started_lines(self, job_id: str) -> int:
        return sum(w.log(10**7).count(f"job {job_id} (") for w in self.workers)

    def close(self) -> None:
        stop_all([*self.workers, self.api])
        self.db.dispose()


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    _require_redis()
    admin = _admin()
    tag = uuid.uuid4().hex[:12]
    dbname = f"otgeo_test_{tag}"
    queue = f"otgeotest{tag}"
    with admin.cursor() as cur:
        cur.execute(f'CREATE DATABASE "{dbname}"')
    data = tmp_path_factory.mktemp("scale")
    db_url = f"postgresql://postgres@127.0.0.1:5432/{dbname}"  # the README's form
    env = {
        "OTGEO_DATA_DIR": str(data),
        "OTGEO_QUEUE": "redis",
        "OTGEO_QUEUE_NAME": queue,
        "OTGEO_REDIS_URL": REDIS_URL,
        "OTGEO_DATABASE_URL": db_url,
        "OTGEO_WORKERS": "0",
        "OTGEO_HEARTBEAT_INTERVAL": "0.2",
        "OTGEO_STALE_AFTER": str(STALE_AFTER),
        "OTGEO_REAPER_INTERVAL": "0.25",
        "OTGEO_MAX_ATTEMPTS": str(MAX_ATTEMPTS),
        "OTGEO_BLAS_THREADS": "1",
    }
    s = None
    try:
        s = Stack(env, data, db_url)
        s.spawn_workers(2)  # API and workers start in parallel
        s.api.wait_healthy(timeout=60)
        yield s
    finally:
        if s is not None:
            s.close()
        with admin.cursor() as cur:
            cur.execute(f'DROP DATABASE IF EXISTS "{dbname}" WITH (FORCE)')
        admin.close()
        import redis

        r = redis.Redis.from_url(REDIS_URL)
        keys = list(r.scan_iter(f"*{queue}*"))
        if keys:
            r.delete(*keys)


@pytest.fixture(scope="module")
def cow(stack, meshes_dir):
    r = stack.post("/v1/domains", files={"file": ("cow.obj", (meshes_dir / "cow.obj")
                                                  .read_bytes())})
    assert r.status_code in (200, 201), r.text
    return r.json()["id"]


def test_services_use_redis_and_postgres(stack, cow):
    assert stack.get("/healthz").json()["queue"] == "redis"
    with stack.db.connect() as c:
        assert c.execute(sa.text("SELECT count(*) FROM jobs")).scalar() == 0


def test_two_workers_never_run_a_job_twice(stack, cow):
    stack.ensure_workers(2, ready=True)
    ids = [stack.submit_flow(cow, SHORT) for _ in range(8)]
    jobs = [stack.wait_state(i, ("succeeded", "failed"), 60) for i in ids]
    assert all(ran_to_its_cap(j) for j in jobs), [j["error"] for j in jobs]
    assert [j["attempts"] for j in jobs] == [1] * len(ids)
    # both workers took jobs, and each job was started exactly once across their logs
    assert len({stack.row(i)["worker"] for i in ids}) == 2
    assert [stack.started_lines(i) for i in ids] == [1] * len(ids)


def test_killed_worker_job_is_rerun_by_another_worker(stack, cow):
    stack.ensure_workers(2)
    job_id = stack.submit_flow(cow, LONG)
    stack.wait_running(job_id)
    victim = stack.worker_of(job_id)
    victim.kill(signal.SIGKILL)
    assert not victim.alive()
    # the reaper sees the stale heartbeat and re-queues; the surviving worker runs it
    job = stack.wait_running(job_id, attempts=2, timeout=STALE_AFTER + 15)
    assert stack.worker_of(job_id) is not victim
    job = stack.wait_state(job_id, ("succeeded", "failed"), 30)
    assert ran_to_its_cap(job), job["error"]
    assert job["attempts"] == 2
    assert stack.get(f"/v1/jobs/{job_id}/result").status_code == 200


def test_job_fails_after_max_attempts(stack, cow):
    stack.ensure_workers(2)
    job_id = stack.submit_flow(cow, LONG)
    for attempt in range(1, MAX_ATTEMPTS + 1):
        stack.wait_running(job_id, attempts=attempt, timeout=STALE_AFTER + 15)
        stack.worker_of(job_id).kill(signal.SIGKILL)
        stack.ensure_workers(2)  # replace it (the other worker takes the re-queued attempt)
    job = stack.wait_state(job_id, ("failed", "succeeded"), STALE_AFTER + 15)
    assert job["state"] == "failed"
    assert job["attempts"] == MAX_ATTEMPTS
    assert job["error"]["code"] == "worker_lost"
    assert stack.get(f"/v1/jobs/{job_id}/result").status_code == 409


def test_cancel_running_job(stack, cow):
    stack.ensure_workers(2)
    job_id = stack.submit_flow(cow, LONG)
    running = stack.wait_running(job_id)
    worker = stack.worker_of(job_id)
    r = httpx.delete(f"{stack.api.url}/v1/jobs/{job_id}", timeout=10)
    assert r.status_code == 200 and r.json()["cancel_requested"] is True
    job = stack.wait_state(job_id, ("cancelled", "succeeded", "failed"), 5)
    assert job["state"] == "cancelled"
    assert job["progress"]["iteration"] < LONG["max_iter"]
    assert job["progress"]["iteration"] >= running["progress"]["iteration"]
    assert job["attempts"] == 1
    assert worker.alive()  # cancellation stops the job, not the worker
    assert stack.get(f"/v1/jobs/{job_id}/result").status_code == 409


def test_api_restart_keeps_jobs_and_results(stack, cow):
    stack.ensure_workers(2)
    done = stack.submit_flow(cow, SHORT)
    assert ran_to_its_cap(stack.wait_state(done, ("succeeded", "failed"), 30))
    before_jobs = {j["id"]: j for j in stack.get("/v1/jobs").json()["jobs"]}
    before_result = stack.get(f"/v1/jobs/{done}/result").json()
    before_glb = stack.get(f"/v1/jobs/{done}/result.glb").content
    assert httpx.delete(f"{stack.api.url}/v1/jobs/{done}", timeout=10).status_code == 409
    # a job running while the API is killed still finishes (workers do not need the API)
    running = stack.submit_flow(cow, LONG)
    stack.wait_running(running)
    stack.restart_api()  # SIGKILL, then a new API process on the same database and storage
    assert stack.get(f"/v1/domains/{cow}").status_code == 200
    after_jobs = {j["id"]: j for j in stack.get("/v1/jobs", params={"limit": 1000}).json()
                  ["jobs"]}
    for job_id, job in before_jobs.items():
        if job["state"] in ("succeeded", "failed", "cancelled"):
            assert after_jobs[job_id] == job
    assert stack.get(f"/v1/jobs/{done}/result").json() == before_result
    assert stack.get(f"/v1/jobs/{done}/result.glb").content == before_glb
    job = stack.wait_state(running, ("succeeded", "failed"), 30)
    assert ran_to_its_cap(job) and job["attempts"] == 1


def test_every_job_was_started_exactly_attempts_times(stack, cow):
    """Across the whole module: workers' logs show one start per counted attempt."""
    # run on its own (with -k, say) the module's jobs are missing: audit one of its own
    stack.ensure_workers(2, ready=True)
    stack.wait_state(stack.submit_flow(cow, SHORT), ("succeeded", "failed"), 60)
    with stack.db.connect() as c:
        rows = c.execute(sa.text("SELECT id, attempts FROM jobs")).all()
    assert rows
    for job_id, attempts in rows:
        assert stack.started_lines(job_id) == attempts, job_id


def test_job_tables_created_concurrently_on_postgresql():
    """API and workers starting together all create the job table: the loser of the race
    (a unique violation in PostgreSQL's type catalogue) must not crash."""
    import threading

    from service.jobs.db import JobRepository

    admin = _admin()
    dbname = f"otgeo_race_{uuid.uuid4().hex[:12]}"
    with admin.cursor() as cur:
        cur.execute(f'CREATE DATABASE "{dbname}"')
    url = f"postgresql://postgres@127.0.0.1:5432/{dbname}"
    errors, repos, start = [], [], threading.Barrier(6)

    def create():
        start.wait()
        try:
            repos.append(JobRepository(url))
        except Exception as exc:  # noqa: BLE001 - the test reports any failure
            errors.append(repr(exc))

    try:
        threads = [threading.Thread(target=create) for _ in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert errors == [] and len(repos) == 6
        assert repos[0].list(limit=5) == []  # the table works
    finally:
        for repo in repos:
            repo.dispose()
        with admin.cursor() as cur:
            cur.execute(f'DROP DATABASE IF EXISTS "{dbname}" WITH (FORCE)')
        admin.close()
