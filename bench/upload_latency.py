"""/healthz latency during a large JSON domain upload on a live ``otgeo serve``.

Uploads a graph of about 12 MB (the size of the report in issue 11) while another client
polls /healthz every 20 ms, and prints the upload time and the health checks' latencies
(max, p50). Run: ``.venv/bin/python bench/upload_latency.py [--mb 12]``. Records
/proc/loadavg before and after.
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


def health_latencies_during(url: str, work, sample=None) -> list[float]:
    """Seconds of each ``GET /healthz`` sent every 20 ms while ``work()`` runs in a thread;
    ``sample()`` (e.g. of the API's memory) is called after each."""
    thread = threading.Thread(target=work)
    thread.start()
    lat = []
    while thread.is_alive():
        t0 = time.monotonic()
        httpx.get(url + "/healthz", timeout=60)
        lat.append(time.monotonic() - t0)
        if sample is not None:
            sample()
        time.sleep(0.02)
    thread.join()
    return lat


def p99(values: list[float]) -> float:
    """The 99th percentile (the largest value below 100 samples)."""
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]


def graph_body(megabytes: float) -> bytes:
    rng = np.random.default_rng(0)
    m = int(megabytes * 2**20 / 16)
    n = max(m // 4, 10)
    chain = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    extra = rng.integers(0, n, (m, 2))
    extra = extra[extra[:, 0] != extra[:, 1]]
    edges = ",".join(f"[{a},{b}]" for a, b in np.concatenate([chain, extra]).tolist())
    return f'{{"kind": "graph", "n_nodes": {n}, "edges": [{edges}]}}'.encode()


def loadavg() -> str:
    return Path("/proc/loadavg").read_text().split(" ")[0]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--mb", type=float, default=12.0)
    parser.add_argument("--runs", type=int, default=2)
    args = parser.parse_args()
    body = graph_body(args.mb)
    print(f"body {len(body) / 2**20:.1f} MiB; load before {loadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        api = API({"OTGEO_DATA_DIR": tmp, "OTGEO_WORKERS": "0"}, Path(tmp))
        try:
            api.wait_healthy(60)
            for run in range(args.runs):
                done: dict = {}

                def upload(done=done):
                    t0 = time.monotonic()
                    r = httpx.post(api.url + "/v1/domains", content=body, timeout=300,
                                   headers={"content-type": "application/json"})
                    done.update(status=r.status_code, seconds=time.monotonic() - t0)

                lat = health_latencies_during(api.url, upload)
                print(f"run {run}: upload {done['status']} in {done['seconds']:.2f} s; "
                      f"{len(lat)} health checks during it: max {max(lat) * 1000:.0f} ms, "
                      f"p50 {statistics.median(lat) * 1000:.1f} ms; load {loadavg()}")
        finally:
            api.stop()


if __name__ == "__main__":
    main()
