"""Queue order and waits under concurrent clients on a running service with one worker.

``CLIENTS`` threads each submit ``JOBS`` distance jobs (convolutional, between two bumps
on an icosphere of 2562 vertices: about 0.16 s each, in the short queue) without waiting, as
fast as the API takes them, so that most wait longer than the broker check's 2 s; then every
job's ``created_at`` and ``started_at`` are read back. Prints, per queue, the out-of-order
pairs (a job submitted earlier but started later; 0 is first submitted, first started), the
longest and median wait (start minus submission) and /proc/loadavg.

Start the server outside ``cpu bench`` (a server must not inherit its lock), e.g.
``PYTHONPATH=TREE .venv/bin/python -m service.cli serve --port 18410 --workers 1
--data-dir /tmp/q``, then ``cpu bench .venv/bin/python bench/queue_order.py --url
http://127.0.0.1:18410``.
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time
from datetime import datetime
from pathlib import Path

import httpx
import trimesh

BODY = {"mu0": {"vertex": 0, "radius": 0.3}, "mu1": {"vertex": 2000, "radius": 0.3},
        "method": "convolutional"}


def submit_all(url: str, gid: str, clients: int, jobs: int) -> list[str]:
    """Job ids of ``clients`` x ``jobs`` submissions from concurrent clients."""
    ids: list[str] = []
    lock = threading.Lock()

    def client():
        with httpx.Client(base_url=url, timeout=60) as c:
            for _ in range(jobs):
                r = c.post(f"/v1/domains/{gid}/distances", json=BODY)
                r.raise_for_status()
                with lock:
                    ids.append(r.json()["id"])

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return ids


def finished_jobs(c: httpx.Client, ids: list[str], timeout: float) -> list[dict]:
    deadline = time.monotonic() + timeout
    while True:
        jobs = [c.get(f"/v1/jobs/{i}").json() for i in ids]
        if all(j["state"] in ("succeeded", "failed") for j in jobs):
            return jobs
        if time.monotonic() > deadline:
            raise TimeoutError("jobs still waiting")
        time.sleep(0.5)


def stamp(text: str) -> float:
    return datetime.fromisoformat(text).timestamp()


def order_report(jobs: list[dict]) -> dict:
    """Per queue: out-of-order pairs, longest and median wait (s)."""
    out = {}
    for queue in sorted({j["queue"] for j in jobs}):
        mine = sorted((j for j in jobs if j["queue"] == queue),
                      key=lambda j: stamp(j["created_at"]))
        starts = [stamp(j["started_at"]) for j in mine]
        inverted = sum(1 for i in range(len(starts)) for k in range(i + 1, len(starts))
                       if starts[k] < starts[i])
        waits = [s - stamp(j["created_at"]) for s, j in zip(starts, mine, strict=True)]
        out[queue] = {"jobs": len(mine), "out_of_order_pairs": inverted,
                      "longest_wait_s": max(waits), "median_wait_s": statistics.median(waits)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--url", required=True)
    parser.add_argument("--clients", type=int, default=16)
    parser.add_argument("--jobs", type=int, default=5, help="jobs per client")
    args = parser.parse_args()
    load = Path("/proc/loadavg").read_text().strip()
    with httpx.Client(base_url=args.url, timeout=60) as c:
        sphere = trimesh.creation.icosphere(subdivisions=4)
        gid = c.post("/v1/domains", json={"kind": "mesh", "vertices": sphere.vertices.tolist(),
                                          "faces": sphere.faces.tolist()}).json()["id"]
        c.post(f"/v1/domains/{gid}/distances?wait=60", json=BODY)  # warm the kernel
        ids = submit_all(args.url, gid, args.clients, args.jobs)
        jobs = finished_jobs(c, ids, 600)
    states = {s: sum(j["state"] == s for j in jobs) for s in ("succeeded", "failed")}
    for queue, r in order_report(jobs).items():
        print(f"{queue}: {r['jobs']} jobs ({states}), {r['out_of_order_pairs']} out-of-order "
              f"pairs, longest wait {r['longest_wait_s']:.2f} s, median "
              f"{r['median_wait_s']:.2f} s")
    print(f"load before: {load}; after: {Path('/proc/loadavg').read_text().strip()}")


if __name__ == "__main__":
    main()
