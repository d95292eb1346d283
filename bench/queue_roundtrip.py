"""Round trip of a tiny job through the embedded queue (``otgeo serve``, one worker).

``POST /v1/domains/{id}/distances?wait=10`` on a 6x6 grid, 40 times after 5 warm-ups, then 40
``GET /healthz``; prints p50/p90 and /proc/loadavg. Compare trees side by side with
``cd TREE && PYTHONPATH=TREE .venv/bin/python bench/queue_roundtrip.py`` (the live server is
started from TREE's tests/service/liveserver.py, so API and worker run TREE's code).
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx

TREE = Path(os.environ.get("PYTHONPATH") or Path(__file__).resolve().parents[1])
sys.path.insert(0, str(TREE / "tests" / "service"))
from liveserver import API  # noqa: E402


def main(n: int = 40) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        api = API({"OTGEO_DATA_DIR": tmp, "OTGEO_WORKERS": "1"}, Path(tmp))
        try:
            api.wait_healthy(60)
            c = httpx.Client(base_url=api.url, timeout=60)
            gid = c.post("/v1/domains", json={"kind": "grid", "shape": [6, 6]}).json()["id"]
            body = {"mu0": {"vertex": 0, "radius": 0.5}, "mu1": {"vertex": 35, "radius": 0.5}}
            load = Path("/proc/loadavg").read_text().split()[0]
            for _ in range(5):
                c.post(f"/v1/domains/{gid}/distances?wait=10", json=body)
            jobs, health = [], []
            for _ in range(n):
                t = time.perf_counter()
                r = c.post(f"/v1/domains/{gid}/distances?wait=10", json=body)
                jobs.append(time.perf_counter() - t)
                assert r.json()["state"] == "succeeded", r.text
            for _ in range(n):
                t = time.perf_counter()
                c.get("/healthz")
                health.append(time.perf_counter() - t)
            after = Path("/proc/loadavg").read_text().split()[0]
            print(f"{TREE}: job round trip p50 {statistics.median(jobs) * 1e3:.1f} ms, p90 "
                  f"{sorted(jobs)[int(0.9 * n)] * 1e3:.1f} ms; healthz p50 "
                  f"{statistics.median(health) * 1e3:.1f} ms; load {load} -> {after}")
        finally:
            api.stop()


if __name__ == "__main__":
    main()
