"""Size and time of a soft-map-sized job result over HTTP.

The case of issue 25: a soft map lion -> cat (TOSCA pair, 5 landmarks) with the default 1,024
source samples over all 7,207 cat vertices, whose stored arrays include the (1024, 7207)
float64 soft map. The arrays' sizes do not depend on convergence, so ``setup`` runs only a few
propagation sweeps (``--max-iter``, default 10) to produce a result of the default sizes
without the 60-115 s of a converged run.

Parts (``.venv/bin/python bench/result_size.py PART DATA_DIR``):

setup
    upload lion and cat into DATA_DIR and run the soft map there (in process, queue
    "immediate"); the job id goes to ``DATA_DIR/softmap_job.txt``.
measure
    a live ``otgeo serve`` (1 worker) over DATA_DIR; over a keep-alive HTTP connection, the
    best of ``--repeats`` GETs of ``/v1/jobs/{id}/result`` (bytes, seconds), then, where the
    result links its arrays (``array_files``), every linked ``.npy`` file (bytes, seconds)
    and one soft-map row (``/arrays/{name}/rows/{i}``). Appends one row per run to
    ``bench/results/result_size.md`` with the code's commit and the load average.
viewer
    the same server and Debian's Chromium (Playwright, software WebGL): the viewer page opens,
    then the seconds from a click on the soft-map job in its job list until the soft-map view
    is ready (both meshes drawn, "hover the source" shown), and the bytes of the job routes it
    downloaded meanwhile (Resource Timing), in a fresh browser context each of ``--repeats``
    times; the best time is recorded.

Run each part under ``cpu run`` / ``cpu bench`` (2 shared cores). To compare with older code,
run this file from an export of that commit (``git archive``) with ``PYTHONPATH`` pointing at
it, ``--label`` naming it and ``--out`` this checkout's results file.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "service"))
sys.path.append(str(ROOT / "bench"))  # after the project: bench/service.py

import httpx  # noqa: E402
import numpy as np  # noqa: E402
from _common import load1  # noqa: E402

PAIRS = ROOT.parent / "shared" / "meshes" / "pairs"
OUT = ROOT / "bench" / "results" / "result_size.md"
JOB_FILE = "softmap_job.txt"


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def setup(data_dir: Path, max_iter: int) -> str:
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    app = create_app(Settings(data_dir=data_dir, queue="immediate"))
    with TestClient(app) as client:
        ids = {}
        for name in ("lion", "cat"):
            path = PAIRS / f"{name}-00.off"
            with open(path, "rb") as fh:
                resp = client.post("/v1/domains/upload", files={"file": (path.name, fh)},
                                   data={"weld": "false"})
            assert resp.status_code in (200, 201), resp.text
            ids[name] = resp.json()["id"]
        pairs = np.loadtxt(PAIRS / "cat-lion-landmarks.txt", dtype=np.int64)[:5]
        body = {"source_id": ids["lion"], "target_id": ids["cat"], "max_iter": max_iter,
                "landmarks": [{"source": int(lion), "target": int(cat)} for cat, lion in pairs]}
        job = client.post("/v1/soft-maps", json=body).json()
        assert job["state"] == "succeeded", job
    (data_dir / JOB_FILE).write_text(job["id"])
    return job["id"]


def _get(client: httpx.Client, path: str, repeats: int) -> tuple[int, float]:
    best, size = float("inf"), 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        resp = client.get(path)
        body = resp.content
        best = min(best, time.perf_counter() - t0)
        assert resp.status_code == 200, (path, resp.status_code, body[:300])
        size = len(body)
    return size, best


def commit() -> str:
    out = subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
                         capture_output=True, text=True)
    return out.stdout.strip() or "?"


def measure(data_dir: Path, repeats: int, label: str, out: Path) -> str:
    from liveserver import API

    job_id = (data_dir / JOB_FILE).read_text().strip()
    api = API({"OTGEO_DATA_DIR": str(data_dir), "OTGEO_WORKERS": "1"}, data_dir)
    try:
        api.wait_healthy(timeout=60)
        before = loadavg()
        with httpx.Client(base_url=api.url, timeout=120) as client:
            size, seconds = _get(client, f"/v1/jobs/{job_id}/result", repeats)
            result = client.get(f"/v1/jobs/{job_id}/result").json()
            links = result.get("array_files") or {}
            files_bytes, files_seconds = 0, 0.0
            for info in links.values():
                b, s = _get(client, info["href"], repeats)
                files_bytes, files_seconds = files_bytes + b, files_seconds + s
            row_name = (result.get("values") or {}).get("rows", "soft_map")
            row_bytes, row_seconds = _get(client, f"/v1/jobs/{job_id}/arrays/{row_name}/rows/0",
                                          repeats)
        after = loadavg()
    finally:
        api.stop()
    files = (f"{len(links)} files, {files_bytes / 1e6:.1f} MB, {files_seconds:.2f} s"
             if links else "none")
    row = (f"| {datetime.now(UTC):%Y-%m-%d %H:%M} | {label or commit()} | {size / 1e6:.3f} MB | "
           f"{seconds:.3f} | {files} | {row_bytes / 1e3:.0f} kB, {row_seconds * 1e3:.0f} ms | "
           f"{before} | {after} |")
    print(row)
    if not out.exists():
        out.write_text(
            "# Job result size over HTTP (bench/result_size.py)\n\n"
            "Soft map lion -> cat, 1,024 source samples over the 7,207 cat vertices (arrays "
            "of the default sizes; a few sweeps only: sizes do not depend on convergence). "
            "Live `otgeo serve`, 1 worker, one keep-alive connection, best of the repeats. "
            "Load averages (1/5/15 min) before and after.\n\n"
            "| run (UTC) | code | GET /result bytes | seconds | linked .npy files (all) | "
            "one soft-map row | load before | load after |\n"
            "|---|---|---|---|---|---|---|---|\n")
    with out.open("a") as fh:
        fh.write(row + "\n")
    return row


CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--no-first-run",
                 "--disable-background-networking"]  # as tests/browser/conftest.py


def open_in_viewer(browser, url: str, job_id: str) -> tuple[float, int]:
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    try:
        page = context.new_page()
        page.goto(url + "/viewer")
        page.wait_for_selector("body[data-ready='1']", timeout=60_000)
        item = page.locator(f"#jobs li[data-id='{job_id}']")
        item.wait_for(timeout=60_000)
        t0 = time.perf_counter()
        item.click()
        page.wait_for_selector("#hover:not([hidden])", timeout=300_000)
        seconds = time.perf_counter() - t0
        size = page.evaluate("performance.getEntriesByType('resource')"
                             f".filter((e) => e.name.includes('/v1/jobs/{job_id}'))"
                             ".reduce((a, e) => a + e.encodedBodySize, 0)")
        return seconds, int(size)
    finally:
        context.close()


def viewer(data_dir: Path, repeats: int, label: str, out: Path) -> str:
    from liveserver import API
    from playwright.sync_api import sync_playwright

    job_id = (data_dir / JOB_FILE).read_text().strip()
    api = API({"OTGEO_DATA_DIR": str(data_dir), "OTGEO_WORKERS": "1"}, data_dir)
    try:
        api.wait_healthy(timeout=60)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path="/usr/bin/chromium",
                                         args=CHROMIUM_ARGS, headless=True)
            before = loadavg()
            runs = [open_in_viewer(browser, api.url, job_id) for _ in range(repeats)]
            after = loadavg()
            browser.close()
    finally:
        api.stop()
    seconds, size = min(runs)
    row = (f"| {datetime.now(UTC):%Y-%m-%d %H:%M} | {label or commit()} | {seconds:.2f} | "
           f"{size / 1e6:.2f} MB | {', '.join(f'{s:.2f}' for s, _ in runs)} | {before} | "
           f"{after} |")
    print(row)
    text = out.read_text() if out.exists() else ""
    if "## Opening the job in the viewer" not in text:
        text += ("\n## Opening the job in the viewer\n\nSeconds from the click on the job "
                 "until the soft-map view is ready, and the bytes of the job's routes "
                 "downloaded meanwhile (Resource Timing, body sizes); best of the runs, each "
                 "in a fresh browser context (Chromium, software WebGL).\n\n"
                 "| run (UTC) | code | seconds | job bytes | all runs (s) | load before | "
                 "load after |\n|---|---|---|---|---|---|---|\n")
    out.write_text(text + row + "\n")
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("part", choices=["setup", "measure", "viewer"])
    parser.add_argument("data_dir", type=Path)
    parser.add_argument("--max-iter", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--label", default="", help="code label of the row (default: the "
                        "commit of this checkout)")
    parser.add_argument("--out", type=Path, default=OUT, help="markdown file to append to")
    args = parser.parse_args()
    print(f"load {load1():.2f}")
    if args.part == "setup":
        print("job", setup(args.data_dir, args.max_iter))
    elif args.part == "viewer":
        viewer(args.data_dir, args.repeats, args.label, args.out)
    else:
        measure(args.data_dir, args.repeats, args.label, args.out)


if __name__ == "__main__":
    main()
