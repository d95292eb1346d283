"""Container stack vs `otgeo serve` on the host: image size, cold start to healthy, job latency.

    .venv/bin/python bench/docker.py [--repeats 15]

Builds the images like the test does (docker/local/build-images.sh; reused layers make a rerun
fast), brings the compose stack up on fresh volumes (api, two workers, redis, postgres; the
test override) and times it to healthy, twice; then runs the same job (a Sinkhorn distance
on woody.obj and on spot.obj, ``?wait=60``) through the stack's published port and through
`otgeo serve` on the host (embedded SQLite queue, one worker), alternating the two, and prints
the latencies with
/proc/loadavg before and after each figure. Only 127.0.0.1 is contacted once images are built.
Results: bench/results/docker.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "service"))
sys.path.insert(0, str(ROOT / "tests"))

import httpx  # noqa: E402
from dockerstack import (  # noqa: E402
    ComposeStack,
    build_images,
    engine_problem,
    image_size,
)
from liveserver import API  # noqa: E402

MESHES = ROOT.parent / "shared" / "meshes"
# woody (694 vertices): a job of a few ms, the latency is the stack's overhead;
# spot (2,930 vertices after welding): a job of ~0.2 s, the compute shows too
CASES = ("woody.obj", "spot.obj")
JOB = {"mu0": {"vertex": 0, "radius": 0.15}, "mu1": {"vertex": 600, "radius": 0.15}}


def load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def upload(url: str, name: str) -> str:
    r = httpx.post(url + "/v1/domains", files={"file": (name, (MESHES / name).read_bytes())},
                   timeout=120)
    r.raise_for_status()
    return r.json()["id"]


OVERHEAD: dict[str, list[float]] = {"stack": [], "host": []}


def one_job(url: str, domain: str, kind: str | None = None) -> float:
    """Client-side latency; with ``kind``, also record latency minus the job's own run time
    (``duration_seconds`` measured by the worker): what the queue, job table and HTTP cost."""
    t0 = time.perf_counter()
    r = httpx.post(f"{url}/v1/domains/{domain}/distances?wait=60", json=JOB, timeout=90)
    dt = time.perf_counter() - t0
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    if kind is not None:
        OVERHEAD[kind].append(dt - r.json()["duration_seconds"])
    return dt


def summary(xs: list[float]) -> str:
    xs = sorted(xs)
    p90 = xs[min(len(xs) - 1, int(round(0.9 * (len(xs) - 1))))]
    return f"median {1e3 * statistics.median(xs):.1f} ms, p90 {1e3 * p90:.1f} ms, " \
           f"min {1e3 * xs[0]:.1f} ms (n={len(xs)})"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args()
    problem = engine_problem()
    if problem:
        raise SystemExit(f"the compose stack cannot run here: {problem}")
    tmp = Path(tempfile.mkdtemp(prefix="otgeo-bench-docker-"))
    la = load()
    built = build_images(tmp / "build.log")
    print(f"images built/checked: {built:.1f} s (load {la} -> {load()})")
    print(f"image otgeo:test: {image_size()} bytes ({image_size() / 2**20:.0f} MiB)")

    for i in (1, 2):  # cold start on fresh volumes (postgres initdb included)
        s = ComposeStack(workers=2)
        la = load()
        try:
            up = s.up()
            print(f"cold start to healthy #{i}: {up:.1f} s (load {la} -> {load()})")
        finally:
            if i == 1:
                s.down()
    host_env = {"OTGEO_DATA_DIR": str(tmp / "host-data"), "OTGEO_WORKERS": "1",
                "OTGEO_BLAS_THREADS": "1"}
    host = API(host_env, tmp, name="host-api")
    try:
        host.wait_healthy(timeout=120)
        urls = {"stack": s.url, "host": host.url}
        for name in CASES:
            dom = {k: upload(urls[k], name) for k in ("stack", "host")}
            la = load()
            first = {k: one_job(urls[k], dom[k]) for k in ("stack", "host")}
            print(f"{name}: first job after upload (domain built in the worker): stack "
                  f"{1e3 * first['stack']:.0f} ms, host {1e3 * first['host']:.0f} ms "
                  f"(load {la} -> {load()})")
            for _ in range(4):  # both workers of the stack have the domain cached
                one_job(s.url, dom["stack"])
            times = {"stack": [], "host": []}
            for k in OVERHEAD:
                OVERHEAD[k].clear()
            la = load()
            for _ in range(args.repeats):
                for k in ("stack", "host"):
                    times[k].append(one_job(urls[k], dom[k], k))
            print(f"{name}: warm job latency (Sinkhorn distance, ?wait=60), alternating, "
                  f"load {la} -> {load()}:")
            for k in ("stack", "host"):
                print(f"  {k:5s}: {summary(times[k])}")
                print(f"  {k:5s} latency - job duration: {summary(OVERHEAD[k])}")
            ratio = statistics.median(times["stack"]) / statistics.median(times["host"])
            print(f"  stack / host (medians): {ratio:.2f}")
    finally:
        host.stop()
        s.down()


if __name__ == "__main__":
    main()
