"""/healthz latency while an 80 MB operation body is posted (issue 31: an 80 MB
``{"mu0": [...]}`` to /distances stalled every other request for 1.9 s).

Starts ``otgeo serve`` with no workers, creates an 8x8 grid, posts ``{"mu0": [...4.4M
floats...], "mu1": ...}`` to its /distances (the answer is a 422 naming ``mu0``: the length
does not match; the body is parsed first either way) while another client polls /healthz
every 20 ms. Prints the answer, its time, and the health checks' latencies. Records
/proc/loadavg before and after. Run: ``.venv/bin/python bench/operation_body_latency.py``.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "service"))
from liveserver import API  # noqa: E402
from upload_latency import health_latencies_during  # noqa: E402


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def main() -> None:
    values = np.random.default_rng(0).random(4_400_000)
    body = ('{"mu0": [' + ",".join(map(repr, values.tolist())) + '], "mu1": [1, 2]}').encode()
    print(f"body {len(body) / 1e6:.1f} MB; load before {loadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        api = API({"OTGEO_DATA_DIR": tmp, "OTGEO_WORKERS": "0"}, Path(tmp))
        try:
            api.wait_healthy(60)
            gid = httpx.post(api.url + "/v1/domains",
                             json={"kind": "grid", "shape": [8, 8]}).json()["id"]
            for run in range(2):
                done: dict = {}

                def post(done=done):
                    t0 = time.monotonic()
                    r = httpx.post(f"{api.url}/v1/domains/{gid}/distances", content=body,
                                   headers={"content-type": "application/json"}, timeout=300)
                    done.update(status=r.status_code, seconds=time.monotonic() - t0,
                                field=r.json().get("error", {}).get("field"))

                lat = health_latencies_during(api.url, post)
                print(f"run {run}: {done['status']} (field {done['field']}) in "
                      f"{done['seconds']:.2f} s; {len(lat)} /healthz during it: max "
                      f"{max(lat) * 1000:.0f} ms, p50 {statistics.median(lat) * 1000:.1f} ms; "
                      f"load {loadavg()}")
        finally:
            api.stop()


if __name__ == "__main__":
    main()
