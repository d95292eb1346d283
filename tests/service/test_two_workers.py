"""Same request, same answer on any worker: ``otgeo serve`` with its defaults and two worker
processes answers the same ``/distances`` request identically every time (issue: one worker
answered the spot request by the exact route, the other by the convolutional one).

Two repeats of each body, taken by the two workers at once (an exact job takes seconds), and the
test checks that both workers answered the default request: the bug was a per-worker route, so
one answer from each worker compares them."""

from __future__ import annotations

import time

import httpx
from liveserver import API, wait_for

from service.jobs.db import JobRepository

SPOT_REQUEST = {"mu0": {"vertex": 935, "radius": 0.15}, "mu1": {"vertex": 615, "radius": 0.15}}
REPEATS = 2  # per body (was 10, then 4: each exact LP on spot takes seconds)


def _submit_all(http, mid: str, body: dict) -> list[str]:
    ids = []
    for _ in range(REPEATS):
        r = http.post(f"/v1/domains/{mid}/distances", json=body)
        assert r.status_code in (200, 202), r.text
        ids.append(r.json()["id"])
    return ids


def _results(http, ids: list[str]) -> list[dict]:
    def finished():
        jobs = [http.get(f"/v1/jobs/{i}").json() for i in ids]
        bad = [j for j in jobs if j["state"] in ("failed", "cancelled")]
        assert not bad, bad
        return jobs if all(j["state"] == "succeeded" for j in jobs) else None

    jobs = wait_for(finished, timeout=240, interval=0.2, what="the distance jobs")
    out = []
    for job in jobs:
        result = http.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()
        assert result["decision"] == job["decision"]
        out.append(result)
    return out


def test_two_workers_give_identical_answers(tmp_path, meshes_dir):
    # Neither worker is reserved for short jobs: the spot jobs' costs may send them to the long
    # queue, and the test needs both workers to take them.
    api = API({"OTGEO_DATA_DIR": str(tmp_path), "OTGEO_WORKERS": "2",
               "OTGEO_RESERVED_SHORT_WORKERS": "0"}, tmp_path)
    try:
        api.wait_healthy(60)
        wait_for(lambda: api.log(10**7).count(" ready (queue ") >= 2, timeout=120,
                 what="two workers ready")
        with httpx.Client(base_url=api.url, timeout=60) as http:
            with open(meshes_dir / "spot.obj", "rb") as fh:
                mid = http.post("/v1/domains", files={"file": ("spot.obj", fh)}).json()["id"]
            bodies = [SPOT_REQUEST, {**SPOT_REQUEST, "method": "convolutional"}]
            ids = {i: _submit_all(http, mid, body) for i, body in enumerate(bodies)}
            started = time.monotonic()
            results = {i: _results(http, job_ids) for i, job_ids in ids.items()}
        repo = JobRepository(f"sqlite:///{tmp_path / 'jobs.sqlite3'}")
        workers = {i: {repo.get(j).worker for j in job_ids} for i, job_ids in ids.items()}
        repo.dispose()
        # both answered the default request (the one whose route differed between workers)
        assert len(workers[0]) == 2, (workers, time.monotonic() - started)
        for i, route in ((0, "exact"), (1, "convolutional")):
            first = results[i][0]
            assert first["values"]["method"] == first["decision"]["method"] == route
            for other in results[i][1:]:
                assert other["decision"] == first["decision"]
                assert other["values"]["value"] == first["values"]["value"]
                assert other["values"]["method"] == route
        assert abs(results[0][0]["values"]["value"] - 0.020168) < 5e-7  # the exact LP
    finally:
        api.stop()
