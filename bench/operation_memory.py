"""Every operation's working memory and run time against the service's estimates (issue 31:
"the cost and memory estimates cover every operation's size parameters, and are checked
against measured peaks").

For each operation of the registry, at two sizes (a 2,903-vertex and a 6,002-vertex closed
mesh, or the operation's own size parameter where no mesh enters: image pixels, hemisphere
cells; a 642-vertex sphere and the cow for the operations listed in ``SMALLER_OPERATIONS``),
one fresh process:

1. starts the service in-process (``queue="immediate"``: a job runs inside its submission,
   through the worker's code path), stores the meshes / images, and submits the
   operation's OpenAPI example (ids substituted, sizes adjusted) once, cold: domain
   operators are built, numba compiles;
2. resets the peak-memory counter (``/proc/self/clear_refs``), submits the same request
   again (operators cached, as on a warm worker) and reads the peak resident memory
   (``VmHWM``) minus the resident memory before: the job's working memory.

Printed per run: the service's memory estimate (``service.operations.base.
job_memory_estimate``: what ``OTGEO_JOB_MEMORY_BYTES`` is checked against at submission),
the measured working memory (warm), estimate / measured, the cold peak increase (operators
and compilation included: bounded by the operator cache), the seconds of both runs, the
estimated cost, the queue it picks, and cost per warm second.

    cpu bench env OPENBLAS_NUM_THREADS=1 .venv/bin/python -P bench/operation_memory.py
    .venv/bin/python -P bench/operation_memory.py --one distances small   # one run, JSON
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
ROOT = Path(__file__).resolve().parents[1]
MESHES = Path("/work/shared/meshes")
MESH_OF_SIZE = {"small": "cow.obj", "medium": "homer.obj"}
# operations whose exact solvers take at most 5,000 vertices, or that run minutes on the
# meshes above: a 642-vertex icosphere and the cow
SMALLER = {"small": "sphere", "medium": "cow.obj"}
SMALLER_OPERATIONS = ("volumetric-distances", "volumetric-paths", "w1-barycenters",
                      "distance-matrices")
SIZES = tuple(MESH_OF_SIZE)
TIMEOUT = 300  # seconds per child process


def status_kib(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def reset_peak() -> None:
    """Resets ``VmHWM`` to the current resident memory (Linux >= 4.0)."""
    Path("/proc/self/clear_refs").write_text("5")


def png(width: int, height: int, seed: int) -> bytes:
    import io

    import numpy as np
    from PIL import Image

    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width]
    img = np.stack([(x * 255 // width), (y * 255 // height), rng.integers(0, 255, x.shape)],
                   -1).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG")
    return buf.getvalue()


def body_for(name: str, size: str, example: dict, info) -> dict:
    """The operation's example (ids substituted), adjusted to ``size`` where its size is its
    own parameter, and to the mesh ``info`` (a point map's length, skeleton positions)."""
    import numpy as np

    big = size == "medium"
    body = dict(example)
    if name == "color-transfers":
        body["mode"] = "split"
    elif name == "brdf-interpolations":
        body.update(rows=2 if big else 1, cols=3, n_theta=16 if big else 12,
                    n_phi=64 if big else 48)
    elif name == "shape-interpolations":
        body["resolution"] = 32 if big else 16
    elif name == "soft-map-analyses":
        body["maps"] = [{**m, "correspondence": list(range(info.n))} for m in body["maps"]]
    elif name == "skeleton-layouts":  # fixed nodes inside the surface: beside its innermost
        pts = np.asarray(info.points)  # vertex, along the longest axis of the bounding box
        inner = pts[np.argmin(np.linalg.norm(pts - pts.mean(0), axis=1))]
        center = 0.5 * (inner + pts.mean(0))
        axis = np.eye(3)[np.argmax(np.ptp(pts, axis=0))] * 0.02
        body["fixed"] = [{"node": 0, "position": (center - axis).tolist()},
                         {"node": 2, "position": (center + axis).tolist()}]
    elif name == "barycenter-batches":  # a grid of alphas between the example's two inputs
        problems = 64 if big else 16
        body["weights"] = [[b / (problems - 1), 1 - b / (problems - 1)]
                           for b in range(problems)]
    elif name == "volumetric-distances":  # the mesh sets the size: a coarse slice
        body["slice"] = {**body["slice"], "resolution": 8}
    return body


def one(name: str, size: str) -> dict:
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "tests" / "service"))
    from example_inputs import schema_example, sphere_obj, substitute_ids
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.job_service import JobService
    from service.operations.base import SubmitContext, job_memory_estimate, view_of_info
    from service.settings import Settings

    data = Path(tempfile.mkdtemp(prefix="opmem-"))
    with TestClient(create_app(Settings(data_dir=data, queue="immediate"))) as client:
        rt = client.app.state.runtime
        mesh_name = (SMALLER if name in SMALLER_OPERATIONS else MESH_OF_SIZE)[size]
        content = sphere_obj() if mesh_name == "sphere" else (MESHES / mesh_name).read_bytes()
        r = client.post("/v1/domains/upload",
                        files={"file": (f"{mesh_name.removesuffix('.obj')}.obj", content)})
        assert r.status_code == 201, r.text
        mesh = r.json()["id"]
        side = 256 if size == "medium" else 64
        blobs = [rt.store.put_blob(png(side, side, s), "image/png")[0]["id"] for s in (0, 1)]
        op = rt.operations[name]
        info = rt.store.domain_info(mesh)
        example = substitute_ids(schema_example(op.request_model.model_json_schema()), mesh,
                                 blobs)
        body = body_for(name, size, example, info)
        request = op.request_model.model_validate(body)
        target = (view_of_info(rt.store.domain_info(mesh)) if op.scope == "domain"
                  else SubmitContext(rt.store, rt.settings))
        estimate = job_memory_estimate(op, target, request)
        domain_id = mesh if op.scope == "domain" else None
        runs = []
        for _ in range(2):
            reset_peak()
            before = status_kib("VmRSS")
            t0 = time.perf_counter()
            job = JobService(rt).create(name, domain_id, request)
            seconds = time.perf_counter() - t0
            assert job.state == "succeeded", (job.state, job.error)
            runs.append({"seconds": seconds, "peak_mib": (status_kib("VmHWM") - before) / 1024})
    decided = (job.decision or {}).get("estimated_seconds")
    return {"operation": name, "size": size, "n": info.n, "decision_seconds": decided,
            "estimate_mib": None if estimate is None else estimate / 2**20,
            "cold": runs[0], "warm": runs[1], "cost": job.cost, "queue": job.queue}


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def table_row(r: dict) -> str:
    est, warm, cold = r["estimate_mib"], r["warm"], r["cold"]
    ratio = "–" if est is None else f"{est / max(warm['peak_mib'], 1.0):.2f}"
    est_s = "none" if est is None else f"{est:.0f}"
    decided = "" if r.get("decision_seconds") is None else f"{r['decision_seconds']:.3g}"
    return (f"| {r['operation']} | {r['size']} ({r['n']}) | {est_s} | {warm['peak_mib']:.0f} | "
            f"{ratio} | {cold['peak_mib']:.0f} | {cold['seconds']:.2f} | "
            f"{warm['seconds']:.2f} | {r['cost']:.3g} | {r['queue']} | "
            f"{r['cost'] / max(warm['seconds'], 1e-3):.3g} | {decided} |")


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--one":
        print(json.dumps(one(sys.argv[2], sys.argv[3])))
        return
    sys.path.insert(0, str(ROOT))
    from service.operations import build_registry

    names = sys.argv[1:] or sorted(build_registry())
    print(f"load before: {loadavg()}")
    print("| operation | size (points) | estimate MiB | measured MiB (warm) | estimate / "
          "measured | cold peak MiB | cold s | warm s | cost | queue | cost / warm s | decided s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    results = []
    for name in names:
        for size in SIZES:
            try:
                out = subprocess.run([sys.executable, "-P", __file__, "--one", name, size],
                                     capture_output=True, text=True, cwd=ROOT,
                                     timeout=TIMEOUT)
            except subprocess.TimeoutExpired:
                print(f"| {name} | {size} | timed out after {TIMEOUT} s |", flush=True)
                continue
            if out.returncode != 0:
                print(f"| {name} | {size} | failed: "
                      f"{out.stderr.strip().splitlines()[-1][:200]} |", flush=True)
                continue
            r = json.loads(out.stdout.strip().splitlines()[-1])
            results.append(r)
            print(table_row(r), flush=True)
    print(f"load after: {loadavg()}")
    if len(sys.argv) == 1:  # the full run
        (ROOT / "bench" / "results" / "operation_memory.json").write_text(
            json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
