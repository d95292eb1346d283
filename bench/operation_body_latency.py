"""API memory and /healthz latency while a large operation body is posted (issue 31: an
80 MB ``{"mu0": [...]}`` to /distances stalled every other request for 1.9 s; issue 44: a
38 MB body took the API from 0.40 to 1.04 GB, a 100 MB one stalled /healthz for 7.9 s).

Starts ``otgeo serve`` with no workers, creates an 8x8 grid, and for each ``--floats`` posts
``{"mu0": [...n floats...], "mu1": [1, 2]}`` to its /distances (below the JSON body limit
the answer is a 422 naming ``mu0``, whose length does not match: the body is parsed first
either way; beyond it a 413) while another client polls /healthz every 20 ms and the API's
resident memory is sampled. Prints the answer, its time, the health checks' latencies (max,
p99, p50) and the API's RSS (idle, highest sampled, ``VmHWM``). Records /proc/loadavg.
Then sends a chunked operation body of ``--chunked-mb`` MiB (300) and a chunked colour upload
of twice that on raw sockets, and prints when the answer came and the API's highest RSS.
Run: ``.venv/bin/python bench/operation_body_latency.py [--floats 2000000,800000]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "service"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from liveserver import API  # noqa: E402
from upload_latency import health_latencies_during, p99  # noqa: E402
from upload_memory import status_kib  # noqa: E402


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def post_during_health(api: API, path: str, body: bytes, ctype: str) -> str:
    """Post ``body`` while /healthz is polled and the API's RSS sampled; one result line."""
    done: dict = {}
    rss = [status_kib(api.pid, "VmRSS")]

    def post():
        t0 = time.monotonic()
        r = httpx.post(api.url + path, content=body, headers={"content-type": ctype},
                       timeout=600)
        done.update(status=r.status_code, seconds=time.monotonic() - t0,
                    field=r.json().get("error", {}).get("field"))

    lat = health_latencies_during(api.url, post,
                                  lambda: rss.append(status_kib(api.pid, "VmRSS")))
    rss.append(status_kib(api.pid, "VmRSS"))
    return (f"{done['status']} (field {done['field']}) in {done['seconds']:.2f} s; "
            f"{len(lat)} /healthz: max {max(lat) * 1000:.0f} ms, p99 {p99(lat) * 1000:.0f} ms, "
            f"p50 {statistics.median(lat) * 1000:.1f} ms; API RSS {rss[0] / 2**20:.2f} -> "
            f"max {max(rss) / 2**20:.2f} GiB (VmHWM {status_kib(api.pid, 'VmHWM') / 2**20:.2f})"
            f"; load {loadavg()}")


def send_chunked(api: API, path: str, ctype: str, first: bytes, megabytes: int) -> str:
    """Send a chunked body of ``megabytes`` MiB (``first``, then JSON-like filler) on a raw
    socket, stopping when the server answers or closes; one line: the answer's status, the
    MiB sent, the seconds, and the API's highest sampled RSS."""
    import select
    import socket

    rss, sent, t0 = [status_kib(api.pid, "VmRSS")], 0, time.monotonic()
    filler = b"1," * 2**19  # 1 MiB
    head = (f"POST {path} HTTP/1.1\r\nHost: x\r\nContent-Type: {ctype}\r\n"
            "Transfer-Encoding: chunked\r\n\r\n").encode()
    with socket.create_connection(("127.0.0.1", api.port), timeout=600) as sock:
        sock.sendall(head + f"{len(first):x}\r\n".encode() + first + b"\r\n")
        answer = b""
        try:
            for _ in range(megabytes):
                if select.select([sock], [], [], 0)[0]:  # the server answered (or closed)
                    break
                sock.sendall(f"{len(filler):x}\r\n".encode() + filler + b"\r\n")
                sent += len(filler)
                rss.append(status_kib(api.pid, "VmRSS"))
            else:
                sock.sendall(b"0\r\n\r\n")
        except OSError:  # closed while sending
            pass
        try:
            while b"\r\n\r\n" not in answer and (chunk := sock.recv(65536)):
                answer += chunk
                rss.append(status_kib(api.pid, "VmRSS"))
        except OSError:
            pass
    status = answer.split(b" ", 2)[1].decode() if answer.startswith(b"HTTP/1.1") else "none"
    return (f"{status} after {sent / 2**20:.0f} MiB sent, {time.monotonic() - t0:.1f} s; API "
            f"RSS {rss[0] / 2**20:.2f} -> max {max(rss) / 2**20:.2f} GiB; load {loadavg()}")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--floats", default="2000000,800000")
    parser.add_argument("--chunked-mb", type=int, default=300,
                        help="size of the chunked operation body (the colour upload: twice)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        api = API({"OTGEO_DATA_DIR": tmp, "OTGEO_WORKERS": "0"}, Path(tmp))
        try:
            api.wait_healthy(60)
            gid = httpx.post(api.url + "/v1/domains",
                             json={"kind": "grid", "shape": [8, 8]}).json()["id"]
            for n in (int(x) for x in args.floats.split(",")):
                values = rng.random(n).tolist()
                body = ('{"mu0": [' + ",".join(map(repr, values)) + '], "mu1": [1, 2]}').encode()
                del values
                print(f"{n} floats, body {len(body) / 1e6:.1f} MB; load before {loadavg()}")
                print("  " + post_during_health(api, f"/v1/domains/{gid}/distances", body,
                                                "application/json"), flush=True)
            del body
            print(f"chunked operation body of {args.chunked_mb} MiB: " + send_chunked(
                api, f"/v1/domains/{gid}/distances", "application/json", b'{"mu0": [',
                args.chunked_mb), flush=True)
            part = (b'--b\r\nContent-Disposition: form-data; name="images"; filename="a.png"'
                    b"\r\nContent-Type: image/png\r\n\r\n")
            print(f"chunked colour upload of {2 * args.chunked_mb} MiB: " + send_chunked(
                api, "/v1/color-transfers", "multipart/form-data; boundary=b", part,
                2 * args.chunked_mb), flush=True)
        finally:
            api.stop()


if __name__ == "__main__":
    main()
