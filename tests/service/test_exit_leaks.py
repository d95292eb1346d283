"""Nothing compiled is left alive at interpreter exit: a process that factors a matrix with
cholespy (directly, held by a module-level cache or by a daemon thread that is still running,
or through an app whose job builds a domain's heat kernel) exits without nanobind's "leaked
instances" report. Causes found: the docs pages' endpoints closed over the app, and FastAPI
caches endpoint functions in module-level LRU caches, so every app (its runtime, its operator
cache and the factors in it) lived until exit; and factors referenced from threads still
running at exit (solvers.linalg releases every live factor in an atexit hook)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FACTOR = """
import numpy as np, scipy.sparse as sp
from solvers.linalg import factorize_spd
n = 40
lap = sp.diags([-np.ones(n - 1), 2.01 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()
factor = factorize_spd(lap, backend="cholespy")
CACHE = {"factor": factor}  # held by a module-level cache at exit
assert np.allclose(lap @ factor.solve(np.ones(n)), 1)
print(type(factor).__name__)
"""
THREAD = FACTOR + """
import threading, time
ready = threading.Event()

def hold():
    held = factorize_spd(lap, backend="cholespy")  # in a frame that never returns
    ready.set()
    time.sleep(3600)
    print(held)

threading.Thread(target=hold, daemon=True).start()
ready.wait()
"""
APP = """
import gc, tempfile, weakref
from fastapi.testclient import TestClient
from service.app import create_app
from service.settings import Settings

def run():
    app = create_app(Settings(data_dir=tempfile.mkdtemp(), queue="immediate"))
    with TestClient(app) as client:
        n = 12
        graph = client.post("/v1/domains", json={"kind": "graph", "n_nodes": n,
                            "edges": [[i, i + 1] for i in range(n - 1)]}).json()
        job = client.post(f"/v1/domains/{graph['id']}/distances?wait=30", json={
            "mu0": {"indices": [0], "masses": [1]}, "mu1": {"indices": [5], "masses": [1]},
            "method": "convolutional"}).json()
        assert job["state"] == "succeeded", job
        assert len(app.state.runtime.cache) == 1  # the graph, with its factored heat kernel
    return weakref.ref(app)

app = run()
gc.collect()
print("app collected:", app() is None)
"""


def run_python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("code", [FACTOR, THREAD, APP], ids=["factor", "thread", "app-job"])
def test_no_nanobind_leak_report_at_exit(code):
    pytest.importorskip("cholespy")
    out = run_python(code)
    assert out.returncode == 0, out.stderr
    assert "nanobind: leaked" not in out.stderr, out.stderr
    if code is APP:
        assert "app collected: True" in out.stdout, out.stdout
