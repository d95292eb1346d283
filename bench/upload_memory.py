"""Peak memory of the API process during a large JSON point-cloud upload (issue 31).

Starts ``otgeo serve`` with no workers, posts a point cloud of ``--points`` random points
(1.9 million by default: a body of about 106 MB, as in the issue) while another client
polls /healthz every 20 ms, and prints the answer, the upload time, the /healthz latencies
and the peak resident memory (``VmHWM``) of the API process and of its domain-builder child
(service.domain_builder). Records /proc/loadavg before and after.

Run: ``.venv/bin/python bench/upload_memory.py [--points 1900000]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "service"))
from liveserver import API  # noqa: E402


def cloud_body(points: int) -> bytes:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(points, 3))
    rows = ",".join(f"[{x!r},{y!r},{z!r}]" for x, y, z in pts.tolist())
    return f'{{"kind": "pointcloud", "points": [{rows}]}}'.encode()


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split(" ")[:3])


def status_kib(pid: int, key: str) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--points", type=int, default=1_900_000)
    args = parser.parse_args()
    t0 = time.monotonic()
    body = cloud_body(args.points)
    print(f"{args.points} points, body {len(body) / 1e6:.1f} MB (built in "
          f"{time.monotonic() - t0:.1f} s); load before {loadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        api = API({"OTGEO_DATA_DIR": tmp, "OTGEO_WORKERS": "0"}, Path(tmp))
        try:
            api.wait_healthy(60)
            idle = status_kib(api.pid, "VmRSS")
            done: dict = {}

            def upload():
                start = time.monotonic()
                r = httpx.post(api.url + "/v1/domains", content=body, timeout=900,
                               headers={"content-type": "application/json"})
                done.update(status=r.status_code, seconds=time.monotonic() - start,
                            body=r.text[:300])

            thread = threading.Thread(target=upload)
            thread.start()
            lat, child_peak = [], {}
            while thread.is_alive():
                start = time.monotonic()
                httpx.get(api.url + "/healthz", timeout=120)
                lat.append(time.monotonic() - start)
                for c in children(api.pid):
                    peak = status_kib(c, "VmHWM")
                    if peak is not None:
                        child_peak[c] = max(child_peak.get(c, 0), peak)
                time.sleep(0.02)
            thread.join()
            api_peak = status_kib(api.pid, "VmHWM")
            print(f"upload: {done['status']} in {done['seconds']:.1f} s: {done['body']}")
            print(f"API process: RSS idle {idle / 2**20:.2f} GiB, peak (VmHWM) "
                  f"{api_peak / 2**20:.2f} GiB")
            for c, peak in child_peak.items():
                print(f"child {c}: peak (VmHWM, last seen) {peak / 2**20:.2f} GiB")
            print(f"{len(lat)} /healthz during the upload: max {max(lat) * 1000:.0f} ms, "
                  f"p50 {statistics.median(lat) * 1000:.1f} ms, over 1 s: "
                  f"{sum(x > 1 for x in lat)}")
            print(f"load after {loadavg()}")
        finally:
            api.stop()


if __name__ == "__main__":
    main()
