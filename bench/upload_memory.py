"""Memory of the API process and /healthz latency during domain uploads (issues 31, 44).

Starts ``otgeo serve`` with no workers and sends, one scenario after another, the uploads of
issue 44 item 13: a JSON point cloud of ``--points`` random points (100k), four concurrent
binary PLYs of about 7.8 MB, and a 2.1M-vertex binary PLY (80 MB), while another client polls
/healthz every 20 ms. Prints the answers, the API's resident memory (idle, highest sampled,
after), its children's (the parser and builder processes of service.api.bodies and
service.domain_builder) and the /healthz latencies (max, p99, p50), with /proc/loadavg.

Run: ``.venv/bin/python bench/upload_memory.py [--points 100000]``.
"""

from __future__ import annotations

import argparse
import multiprocessing
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


def grid_ply(side: int, seed: int) -> bytes:
    """A binary PLY of a ``side`` x ``side`` grid of vertices (two triangles per cell)."""
    import trimesh

    y, x = np.mgrid[0:side, 0:side].astype(float)
    z = np.random.default_rng(seed).random(side * side) * 0.1
    idx = (np.arange(side - 1)[:, None] * side + np.arange(side - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([idx, idx + 1, idx + side], 1),
                            np.stack([idx + 1, idx + side + 1, idx + side], 1)])
    mesh = trimesh.Trimesh(np.stack([x.ravel(), y.ravel(), z], 1), faces, process=False)
    return mesh.export(file_type="ply")


def _send(url: str, path: str, kwargs: dict, results) -> None:
    start = time.monotonic()
    r = httpx.post(url + path, timeout=900, **kwargs)
    results.put(f"{r.status_code} in {time.monotonic() - start:.1f} s "
                f"{r.text[:120] if r.status_code >= 400 else ''}")


def run_uploads(api: API, uploads: list) -> None:
    """Send ``uploads`` (``(path, kwargs)`` for httpx.post) at once while /healthz is polled
    and the API's and its children's resident memory sampled; print the figures. Each upload
    is sent from its own (forked) process: in this one, building and sending an 80 MB body
    would hold the GIL against the poller and count the client's own waits as the server's."""
    from upload_latency import p99

    idle, rss, child_rss = status_kib(api.pid, "VmRSS"), [], {}
    fork = multiprocessing.get_context("fork")
    queue = fork.Queue()
    senders = [fork.Process(target=_send, args=(api.url, path, kwargs, queue))
               for path, kwargs in uploads]
    for proc in senders:
        proc.start()
    lat = []
    with httpx.Client(timeout=120) as client:
        while any(proc.is_alive() for proc in senders):
            start = time.monotonic()
            client.get(api.url + "/healthz")
            lat.append(time.monotonic() - start)
            rss.append(status_kib(api.pid, "VmRSS") or 0)
            for c in children(api.pid):
                child_rss[c] = max(child_rss.get(c, 0), status_kib(c, "VmRSS") or 0)
            time.sleep(0.02)
    results = [queue.get() for _ in senders]
    for proc in senders:
        proc.join()
    time.sleep(2)  # a retired builder child exits once its queue is done
    after = {c: status_kib(c, "VmRSS") for c in children(api.pid)}
    print("  answers: " + "; ".join(results))
    print(f"  API RSS: idle {idle / 2**20:.2f} GiB, highest sampled {max(rss) / 2**20:.2f} "
          f"GiB, after {status_kib(api.pid, 'VmRSS') / 2**20:.2f} GiB")
    print("  children: highest " + ", ".join(f"{c} {v / 2**20:.2f} GiB"
                                             for c, v in child_rss.items())
          + "; after " + ", ".join(f"{c} {(v or 0) / 2**20:.2f} GiB" for c, v in after.items()))
    print(f"  {len(lat)} /healthz: max {max(lat) * 1000:.0f} ms, p99 {p99(lat) * 1000:.0f} ms, "
          f"p50 {statistics.median(lat) * 1000:.1f} ms; load {loadavg()}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--points", type=int, default=100_000,
                        help="points of the JSON cloud (issue 31 used 1.9 million)")
    parser.add_argument("--ply-side", type=int, default=453,
                        help="side of the grid of each of the four PLYs (453: 7.8 MB)")
    parser.add_argument("--big-side", type=int, default=1450,
                        help="side of the grid of the big PLY (1450: 2.1M vertices, 80 MB)")
    parser.add_argument("--only", default="cloud,plies,big",
                        help="scenarios to run, comma-separated")
    args = parser.parse_args()
    t0 = time.monotonic()
    cloud = cloud_body(args.points)
    plies = [grid_ply(args.ply_side, seed) for seed in range(4)]
    big = grid_ply(args.big_side, 9)
    print(f"bodies built in {time.monotonic() - t0:.1f} s; load before {loadavg()}")
    json_header = {"content-type": "application/json"}
    scenarios = [
        ("cloud", f"JSON cloud, {args.points} points, {len(cloud) / 1e6:.1f} MB",
         [("/v1/domains", {"content": cloud, "headers": json_header})]),
        ("plies", f"4 concurrent PLYs of {args.ply_side ** 2} vertices, "
         f"{len(plies[0]) / 1e6:.1f} MB",
         [("/v1/domains/upload", {"files": {"file": (f"g{i}.ply", p)}})
          for i, p in enumerate(plies)]),
        ("big", f"binary PLY of {args.big_side ** 2} vertices, {len(big) / 1e6:.1f} MB",
         [("/v1/domains/upload", {"files": {"file": ("big.ply", big)}})]),
    ]
    with tempfile.TemporaryDirectory() as tmp:
        api = API({"OTGEO_DATA_DIR": tmp, "OTGEO_WORKERS": "0"}, Path(tmp))
        try:
            api.wait_healthy(60)
            for name, title, uploads in scenarios:
                if name not in args.only.split(","):
                    continue
                print(title, flush=True)
                run_uploads(api, uploads)
        finally:
            api.stop()


if __name__ == "__main__":
    main()
