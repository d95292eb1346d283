"""Warm-up of compiled kernels (service.warm): a worker warms at start in the background; a
first job of an operation with a warm-up waits for it and says so in its progress; the
color transfer's warm-up compiles everything a job then runs."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

from liveserver import Worker, stop_all, wait_for

from service.job_service import JobService
from service.operations.base import Operation, OperationOutput, OperationRequest
from service.warm import WARM_STAGE

ROOT = Path(__file__).resolve().parents[2]


class QuickRequest(OperationRequest):
    pass


def _quick(domain, req, progress, should_cancel):
    progress(1, 0.5)
    return OperationOutput({"iterations": 1}, {})


def test_a_first_job_says_it_waits_for_its_kernels(make_client):
    warming, release, calls = threading.Event(), threading.Event(), []

    def slow_warm():
        calls.append(1)
        warming.set()
        release.wait(30)

    op = Operation("test-warm", "createTestWarmJob", "test", QuickRequest, _quick,
                   lambda view, req: [], warm=slow_warm)
    client = make_client(queue="sqlite", heartbeat_interval=0.05)  # no consumer: run below
    rt = client.app.state.runtime
    rt.operations[op.name] = op
    gid = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4]}).json()["id"]
    first, second = (JobService(rt).create(op.name, gid, QuickRequest()) for _ in range(2))
    worker = threading.Thread(target=rt.runner.run, args=(first.id,))
    worker.start()
    try:
        assert warming.wait(30)
        running = client.get(f"/v1/jobs/{first.id}").json()
        assert running["state"] == "running"
        assert running["progress"]["stage"] == WARM_STAGE  # not a silent iteration 0
        assert running["progress"]["iteration"] is None
    finally:
        release.set()
        worker.join(30)
    done = client.get(f"/v1/jobs/{first.id}").json()
    assert done["state"] == "succeeded", done
    assert done["progress"]["stage"] is None and done["progress"]["iteration"] == 1
    rt.runner.run(second.id)  # warmed once per process
    assert client.get(f"/v1/jobs/{second.id}").json()["state"] == "succeeded"
    assert calls == [1]


COVERAGE = """
import sys
import numpy as np
from numba.core.dispatcher import Dispatcher
from service.operations import color

def compiled():
    return {f"{name}.{attr}": len(obj.signatures) for name, mod in list(sys.modules.items())
            if name.startswith("solvers") for attr, obj in vars(mod).items()
            if isinstance(obj, Dispatcher)}

color.warm()
before = compiled()
rng = np.random.default_rng(1)
# noise, unlike warm()'s smooth pictures; small: kernels are compiled per pixel type, not
# size (12 x 17 still shows a warm-up without its 16-bit or barycentric runs), and 30 x 41
# cost ~5 CPU-s more in the LPs and iterations
rgb = [rng.integers(0, 255, (12 + 5 * i, 17, 3), dtype=np.uint8) for i in range(2)]
inputs = {"8-bit RGB": [color.write_image(x) for x in rgb],
          "8-bit RGBA": [color.write_image(np.dstack([x, x[..., :1]])) for x in rgb],
          "16-bit RGB": [color.write_image(x.astype(np.uint16) * 257, "tiff") for x in rgb]}
for files in inputs.values():
    ctx = color._WarmContext({f"{i:032x}": data for i, data in enumerate(files)})
    for mode in ("split", "barycentric"):  # the request's defaults otherwise (bins: small)
        req = color.ColorTransferRequest(images=list(ctx.blobs), mode=mode,
                                         bins=24 if mode == "barycentric" else None)
        color.run(ctx, req, lambda *a: None, lambda: False)
after = compiled()
print({k: v - before.get(k, 0) for k, v in after.items() if v != before.get(k, 0)})
"""


def test_color_warm_up_compiles_what_a_job_runs():
    """After ``warm()`` a color transfer of other images (8 or 16 bits, with or without
    alpha), in either mode, compiles no kernel (a fresh process: nothing compiled by other
    tests)."""
    out = subprocess.run([sys.executable, "-c", COVERAGE], cwd=ROOT, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "{}", out.stdout


def test_a_worker_warms_at_start_in_the_background(tmp_path):
    """``otgeo worker`` takes jobs at once and warms meanwhile (its log says when)."""
    env = {"OTGEO_DATA_DIR": str(tmp_path / "data"), "OTGEO_QUEUE": "sqlite",
           "OTGEO_WARM_AT_START": "true"}  # the default, which other tests' servers turn off
    worker = Worker(env, tmp_path)
    try:
        wait_for(lambda: "color-transfers kernels ready" in worker.log(10**7), 900,
                 interval=0.1, what="warm-up logged")  # reads a small log file
        log = worker.log(10**7)
        assert log.index(" ready (queue ") < log.index("color-transfers kernels ready")
    finally:
        stop_all([worker])


def test_a_worker_told_not_to_warm_at_start_says_so(tmp_path):
    """``OTGEO_WARM_AT_START=false`` (the test servers' setting): no background warm-up; the
    worker's log says that first jobs warm their kernels instead."""
    env = {"OTGEO_DATA_DIR": str(tmp_path / "data"), "OTGEO_QUEUE": "sqlite",
           "OTGEO_WARM_AT_START": "false"}
    worker = Worker(env, tmp_path)
    try:
        wait_for(lambda: "no warm-up at start" in worker.log(10**7), 120, interval=0.1,
                 what="the worker's start")
        assert "kernels ready" not in worker.log(10**7)
    finally:
        stop_all([worker])
