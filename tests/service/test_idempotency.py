"""Idempotency-Key on every POST: the same key and request return the first job or domain,
the same key with another request gets 422 naming the header, keys are per tenant, last at
least a day, and survive a restart of the API process."""

from __future__ import annotations

import threading

import httpx
import pytest
from example_inputs import png_images, sphere_obj
from liveserver import API
from service_testing import assert_error

from service.tenants import key_digest

GRID = {"kind": "grid", "shape": [8, 8]}
BODY = {"mu0": {"vertex": 0, "radius": 0.3}, "mu1": {"vertex": 10, "radius": 0.3}}
HEADER = "Idempotency-Key"


def _grid(client, headers=None) -> str:
    return client.post("/v1/domains", json=GRID, headers=headers or {}).json()["id"]


def test_same_key_same_body_returns_the_first_job(make_client):
    client = make_client(queue="sqlite")  # no worker: the job stays queued
    grid = _grid(client)
    first = client.post(f"/v1/domains/{grid}/distances", json=BODY, headers={HEADER: "k-1"})
    assert first.status_code == 202, first.text
    assert HEADER not in first.headers and "Idempotent-Replayed" not in first.headers
    # the same request again, keys reordered and a default spelled out: the same job
    body = {"mu1": BODY["mu1"], "mu0": BODY["mu0"]}
    again = client.post(f"/v1/domains/{grid}/distances", json=body, headers={HEADER: "k-1"})
    assert again.status_code == 202, again.text
    assert again.json()["id"] == first.json()["id"]
    assert again.headers["Location"] == first.headers["Location"]
    assert again.headers["Idempotent-Replayed"] == "true"
    assert len(client.get("/v1/jobs").json()["jobs"]) == 1
    # another key: another job
    other = client.post(f"/v1/domains/{grid}/distances", json=BODY, headers={HEADER: "k-2"})
    assert other.json()["id"] != first.json()["id"]


def test_replay_of_a_finished_job_has_the_finished_status(client):
    grid = _grid(client)
    first = client.post(f"/v1/domains/{grid}/distances?wait=30", json=BODY,
                        headers={HEADER: "done"})
    assert first.status_code == 200 and first.json()["state"] == "succeeded", first.text
    again = client.post(f"/v1/domains/{grid}/distances", json=BODY, headers={HEADER: "done"})
    assert again.status_code == 200, again.text
    assert again.json()["id"] == first.json()["id"]
    assert again.json()["state"] == "succeeded"


def test_same_key_other_request_is_422_naming_the_header(client):
    grid = _grid(client)
    other_grid = client.post("/v1/domains", json={"kind": "grid", "shape": [6, 6]}).json()["id"]
    assert client.post(f"/v1/domains/{grid}/distances", json=BODY,
                       headers={HEADER: "k"}).status_code in (200, 202)
    changed = {**BODY, "mu1": {"vertex": 11, "radius": 0.3}}
    r = client.post(f"/v1/domains/{grid}/distances", json=changed, headers={HEADER: "k"})
    err = assert_error(r, 422, HEADER, "idempotency_key_reused")
    assert "different request" in err["message"]
    # the same body on another domain or another operation is another request too
    assert_error(client.post(f"/v1/domains/{other_grid}/distances", json=BODY,
                             headers={HEADER: "k"}), 422, HEADER)
    assert_error(client.post(f"/v1/domains/{grid}/flows", json=BODY, headers={HEADER: "k"}),
                 422, HEADER)
    assert_error(client.post("/v1/domains", json=GRID, headers={HEADER: "k"}), 422, HEADER)
    assert len(client.get("/v1/jobs").json()["jobs"]) == 1


@pytest.mark.parametrize("key", ["", "x" * 256, "tab\there", "é"])
def test_malformed_keys_are_refused(client, key):
    grid = _grid(client)
    r = client.post(f"/v1/domains/{grid}/distances", json=BODY,
                    headers={HEADER: key.encode("utf-8")})
    assert_error(r, 422, HEADER)


def test_domain_creation_replays_with_its_status(client):
    first = client.post("/v1/domains", json=GRID, headers={HEADER: "d-1"})
    assert first.status_code == 201, first.text
    again = client.post("/v1/domains", json=GRID, headers={HEADER: "d-1"})
    assert again.status_code == 201 and again.headers["Idempotent-Replayed"] == "true"
    assert again.json()["id"] == first.json()["id"]
    # without the key the same content is "already stored" (200): the key kept the 201
    assert client.post("/v1/domains", json=GRID).status_code == 200
    r = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4]},
                    headers={HEADER: "d-1"})
    assert_error(r, 422, HEADER)


def test_multipart_uploads_compare_content_not_boundaries(client):
    def upload(name="ball.obj", data=None):
        return client.post("/v1/domains/upload", headers={HEADER: "u-1"},
                           files={"file": (name, data or sphere_obj(), "text/plain")})

    first = upload()
    assert first.status_code == 201, first.text
    again = upload()  # a new multipart boundary, the same parts
    assert again.status_code == 201 and again.headers["Idempotent-Replayed"] == "true"
    assert again.json()["id"] == first.json()["id"]
    assert_error(upload(name="other.obj"), 422, HEADER)
    # color transfers: the images' content decides
    warm, cool = png_images()

    def transfer(images):
        files = [("images", (f"{i}.png", d, "image/png")) for i, d in enumerate(images)]
        return client.post("/v1/color-transfers?wait=60", headers={HEADER: "c-1"},
                           files=files, data={"bins": "16"})

    job = transfer([warm, cool])
    assert job.status_code == 200, job.text
    replay = transfer([warm, cool])
    assert replay.json()["id"] == job.json()["id"] and replay.status_code == 200
    assert_error(transfer([cool, warm]), 422, HEADER)


def test_keys_are_per_tenant(make_client):
    keys = [{"tenant": "alpha", "sha256": key_digest("ka")},
            {"tenant": "beta", "sha256": key_digest("kb")}]
    client = make_client(tenant_keys=keys, queue="sqlite")
    a = {"X-API-Key": "ka", HEADER: "shared-key"}
    b = {"X-API-Key": "kb", HEADER: "shared-key"}
    grid_a, grid_b = _grid(client, {"X-API-Key": "ka"}), _grid(client, {"X-API-Key": "kb"})
    assert grid_a == grid_b  # same content, held by both
    job_a = client.post(f"/v1/domains/{grid_a}/distances", json=BODY, headers=a).json()["id"]
    r = client.post(f"/v1/domains/{grid_b}/distances", json=BODY, headers=b)
    assert r.status_code == 202 and "Idempotent-Replayed" not in r.headers
    assert r.json()["id"] != job_a
    assert client.get(f"/v1/jobs/{r.json()['id']}", headers={"X-API-Key": "ka"}) \
        .status_code == 404


def test_keys_last_their_ttl_then_expire(make_client):
    from sqlalchemy import update

    from service.jobs.tenancy import KEYS

    client = make_client(queue="sqlite")
    grid = _grid(client)
    first = client.post(f"/v1/domains/{grid}/distances", json=BODY, headers={HEADER: "t"})
    rt = client.app.state.runtime
    assert rt.settings.idempotency_key_ttl >= 86400

    def age(seconds):
        with rt.tenancy.engine.begin() as conn:
            conn.execute(update(KEYS).values(created_at=KEYS.c.created_at - seconds))

    age(86400 - 60)  # just under a day old: still the first job
    again = client.post(f"/v1/domains/{grid}/distances", json=BODY, headers={HEADER: "t"})
    assert again.json()["id"] == first.json()["id"]
    age(120)  # past the ttl: forgotten, the key makes a new job
    new = client.post(f"/v1/domains/{grid}/distances", json=BODY, headers={HEADER: "t"})
    assert new.status_code == 202 and new.json()["id"] != first.json()["id"]
    assert rt.tenancy.prune_keys(rt.settings.idempotency_key_ttl, force=True) == 0


def race_one_key(rt, tenant: str, domain_id: str, threads: int = 4) -> list[str]:
    """Submit the same request with one key from ``threads`` threads that all pass the
    look-up before any inserts (a barrier), so every insert but one hits the key's unique
    constraint; returns the job ids they got."""
    from service.idempotency import Idempotency, fingerprint
    from service.job_service import JobService
    from service.operations.transport import DistanceRequest
    from service.tenants import Tenant

    barrier = threading.Barrier(threads)

    class AllMissFirst(Idempotency):
        looked = False

        def previous(self):
            found = super().previous()
            if not self.looked:
                self.looked = True
                barrier.wait(timeout=30)
            return found

    ids, errors = [], []

    def submit():
        idem = AllMissFirst(rt.tenancy, tenant, "race", fingerprint("r", BODY), 86400)
        try:
            ids.append(JobService(rt, Tenant(tenant, admin=tenant == "anonymous")).create(
                "distances", domain_id, DistanceRequest(**BODY), idem).id)
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    workers = [threading.Thread(target=submit) for _ in range(threads)]
    for t in workers:
        t.start()
    for t in workers:
        t.join()
    assert not errors, errors
    return ids


def test_concurrent_requests_with_one_key_make_one_job(make_client):
    client = make_client(queue="sqlite")
    grid = _grid(client)
    rt = client.app.state.runtime
    ids = race_one_key(rt, "anonymous", grid)
    assert len(ids) == 4 and len(set(ids)) == 1
    assert len(rt.repo.list(10)) == 1


def test_a_key_survives_an_api_restart(tmp_path):
    """The key is written with the job: after the API process is killed (the client never saw
    the answer) and started again, the retry finds the job instead of making a second one."""
    data = tmp_path / "data"
    env = {"OTGEO_DATA_DIR": str(data), "OTGEO_WORKERS": "0"}
    api = API(env, tmp_path)
    try:
        api.wait_healthy(60)
        grid = httpx.post(api.url + "/v1/domains", json=GRID).json()["id"]
        first = httpx.post(f"{api.url}/v1/domains/{grid}/distances", json=BODY,
                           headers={HEADER: "restart"}, timeout=30)
        assert first.status_code == 202, first.text
        api.kill()  # SIGKILL: no clean shutdown
        api.stop()
        api = API(env, tmp_path, name="api2")
        api.wait_healthy(60)
        again = httpx.post(f"{api.url}/v1/domains/{grid}/distances", json=BODY,
                           headers={HEADER: "restart"}, timeout=30)
        assert again.status_code == 202, again.text
        assert again.json()["id"] == first.json()["id"]
        assert again.headers["Idempotent-Replayed"] == "true"
        other = httpx.post(f"{api.url}/v1/domains/{grid}/distances",
                           json={**BODY, "tol": 1e-4}, headers={HEADER: "restart"}, timeout=30)
        assert_error(other, 422, HEADER)
        assert len(httpx.get(api.url + "/v1/jobs").json()["jobs"]) == 1
    finally:
        api.stop()


@pytest.fixture
def postgres_url():
    """A fresh PostgreSQL database (the server .ci/run starts), dropped afterwards."""
    import uuid

    from test_scale import _admin

    admin = _admin()
    dbname = f"otgeo_idem_{uuid.uuid4().hex[:12]}"
    with admin.cursor() as cur:
        cur.execute(f'CREATE DATABASE "{dbname}"')
    try:
        yield f"postgresql://postgres@127.0.0.1:5432/{dbname}"
    finally:
        with admin.cursor() as cur:
            cur.execute(f'DROP DATABASE IF EXISTS "{dbname}" WITH (FORCE)')
        admin.close()


def test_keys_and_tenants_on_postgresql(make_client, postgres_url):
    keys = [{"tenant": "alpha", "sha256": key_digest("ka")},
            {"tenant": "beta", "sha256": key_digest("kb")}]
    client = make_client(tenant_keys=keys, queue="sqlite", database_url=postgres_url)
    a, b = {"X-API-Key": "ka"}, {"X-API-Key": "kb"}
    grid = _grid(client, a)
    assert _grid(client, b) == grid
    first = client.post(f"/v1/domains/{grid}/distances", json=BODY, headers={**a, HEADER: "p"})
    again = client.post(f"/v1/domains/{grid}/distances", json=BODY, headers={**a, HEADER: "p"})
    assert first.status_code == again.status_code == 202
    assert again.json()["id"] == first.json()["id"]
    assert_error(client.post(f"/v1/domains/{grid}/flows", json=BODY, headers={**a, HEADER: "p"}),
                 422, HEADER)
    assert_error(client.get(f"/v1/jobs/{first.json()['id']}", headers=b), 404, "job_id")
    # concurrent submissions with one key: one job (the losers of the insert find it)
    rt = client.app.state.runtime
    ids = race_one_key(rt, "beta", grid)
    assert len(ids) == 4 and len(set(ids)) == 1
    assert len(client.get("/v1/jobs", headers=b).json()["jobs"]) == 1
    # shared content counted once per tenant, deleted with the last holding
    assert rt.tenancy.stored_bytes("alpha") == rt.store.domain_bytes(grid) > 0
    assert client.delete(f"/v1/domains/{grid}", headers=a).status_code == 204
    assert client.get(f"/v1/domains/{grid}", headers=b).status_code == 200
    assert client.delete(f"/v1/domains/{grid}", headers=b).status_code == 204
    rt.sweep_released()  # the files go at the background sweep, off the request path
    assert not rt.store.has_domain(grid)
