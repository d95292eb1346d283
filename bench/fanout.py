"""A distance matrix fanned out over the workers (issue 42): spot, 100 x 100 W2, 1 vs 2 workers.

``cpu bench env OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
.venv/bin/python bench/fanout.py`` stores spot once in a new data directory (its all-pairs
geodesic artifact computed by a first matrix, not timed), then for 1 and 2 workers starts a new
``otgeo serve`` on that directory (``OTGEO_RESERVED_SHORT_WORKERS=0``: with the default of one
worker reserved for short jobs, a 2-worker ``otgeo serve`` runs long jobs, and so a long
matrix's blocks, on one worker only), runs a warm-up matrix on other bumps (every worker
loads the domain and its operators), then times the matrix of 100 radius-0.1 bumps (vertices
drawn with seed 0, as in ``bench/geodesic_artifacts.py``; default decision) from submission to
its result. The two matrices must be equal bit for bit (the blocks are fixed by the decision).

``--gamma G --substeps K --count N``: the matrix with gamma given (convolutional pairs, which
fan out; a default matrix on a mesh may take the exact method and runs as one block).

Writes ``bench/results/fanout.md`` (command, load, CPU model).
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "service"))
sys.path.insert(0, str(ROOT))
MESHES = ROOT.parent / "shared" / "meshes"
RESULT = ROOT / "bench" / "results" / "fanout.md"

from liveserver import API, stop_all  # noqa: E402

from bench._common import cpu_model, load1  # noqa: E402

COUNT, RADIUS, SPOT_VERTICES = 100, 0.1, 2930


OPTIONS: dict = {}  # gamma and substeps given on the command line


def _body(seed: int) -> dict:
    idx = np.random.default_rng(seed).choice(SPOT_VERTICES, COUNT, replace=False)
    return {"distributions": [{"vertex": int(i), "radius": RADIUS} for i in idx], **OPTIONS}


def _matrix(client: httpx.Client, domain_id: str, body: dict) -> tuple[float, np.ndarray, dict]:
    start = time.perf_counter()
    job = client.post(f"/v1/domains/{domain_id}/distance-matrices", json=body).json()
    while True:
        state = client.get(f"/v1/jobs/{job['id']}").json()
        if state["state"] in ("succeeded", "failed", "cancelled"):
            break
        time.sleep(0.05)
    seconds = time.perf_counter() - start
    assert state["state"] == "succeeded", state
    matrix = np.load(io.BytesIO(client.get(f"/v1/jobs/{job['id']}/arrays/matrix.npy").content))
    return seconds, matrix, job["decision"]


def _serve(data: Path, logs: Path, workers: int):
    env = {"OTGEO_DATA_DIR": str(data), "OTGEO_WORKERS": str(workers),
           "OTGEO_RESERVED_SHORT_WORKERS": "0", "OMP_NUM_THREADS": "1",
           "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    api = API(env, logs, name=f"api{workers}")
    api.wait_healthy(120)
    return api


def main() -> None:
    start_load = load1()
    rows, matrices = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        data, logs = Path(tmp) / "data", Path(tmp)
        api = _serve(data, logs, 1)
        try:
            with httpx.Client(base_url=api.url, timeout=600) as client, \
                    open(MESHES / "spot.obj", "rb") as fh:
                upload = client.post("/v1/domains", files={"file": ("spot.obj", fh)})
                domain_id = upload.json()["id"]
                _matrix(client, domain_id, _body(7))  # stores the geodesic artifact
        finally:
            stop_all([api])
        for workers in (1, 2):
            api = _serve(data, logs, workers)
            try:
                with httpx.Client(base_url=api.url, timeout=600) as client:
                    warmup, _, _ = _matrix(client, domain_id, _body(1))
                    load = load1()
                    seconds, matrix, decision = _matrix(client, domain_id, _body(0))
            finally:
                stop_all([api])
            matrices[workers] = matrix
            rows.append((workers, warmup, seconds, len(decision.get("blocks") or []), load,
                         load1()))
    same = bool(np.array_equal(matrices[1], matrices[2], equal_nan=True))
    _write(rows, same, start_load)


def _write(rows, same: bool, start_load: float) -> None:
    one = rows[0][2]
    lines = [
        f"# A distance matrix fanned out over the workers (spot, {COUNT} x {COUNT} W2)", "",
        "Command: `cpu bench env OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 "
        f".venv/bin/python bench/fanout.py {' '.join(sys.argv[1:])}`", "",
        f"CPU: {cpu_model()}; 1-minute load at start {start_load:.2f}, at end {load1():.2f}.",
        "", "A new `otgeo serve` per row on one data directory (spot stored, its geodesic "
        "artifact computed beforehand); `OTGEO_RESERVED_SHORT_WORKERS=0`; the warm-up matrix "
        "(other bumps) loads the domain and operators in every worker; the timed matrix: "
        f"{COUNT} radius-0.1 bumps, options {OPTIONS or 'none (default decision)'}, "
        "submission to result.", "",
        "| workers | warm-up matrix s | timed matrix s | ratio to 1 worker | blocks | "
        "load before / after |", "| --- | --- | --- | --- | --- | --- |",
    ]
    for workers, warmup, seconds, blocks, load, after in rows:
        lines.append(f"| {workers} | {warmup:.1f} | {seconds:.2f} | {seconds / one:.2f} | "
                     f"{blocks} | {load:.2f} / {after:.2f} |")
    lines += ["", f"Values with 1 and 2 workers equal bit for bit: {same}.", ""]
    RESULT.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--gamma", type=float)
    parser.add_argument("--substeps", type=int)
    parser.add_argument("--count", type=int, default=COUNT)
    args = parser.parse_args()
    COUNT = args.count
    OPTIONS.update({k: v for k, v in (("gamma", args.gamma), ("substeps", args.substeps))
                    if v is not None})
    main()
