"""The built distribution works outside the checkout (issue 44, item 9).

Builds the sdist and the wheel (``python -m build``: the wheel from the sdist), installs the
wheel into a fresh virtualenv in a temporary directory, and from there, away from the sources:

1. the library alone (``pip install otgeo``): ``import solvers`` and a W2 distance work, no
   service package is installed, and ``otgeo serve`` says to install ``otgeo[service]``;
2. with the ``service`` extra: ``otgeo serve`` starts, a grid domain and a distance job run,
   the viewer and every static file of the checkout are served, and ``/guide/`` answers a
   404 saying how to get the guide (or, with ``OTGEO_GUIDE_DIR`` set to a built site, serves
   it).

Only PyPI is reached (pip reuses the wheels in its cache that ``make install`` downloaded).
Run by .ci/run after ``make docs``; ``python .ci/check_wheel.py`` from the repository root.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# the fresh virtualenv's processes see nothing of this checkout or of the caller's paths
CLEAN_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONPATH" and
             not k.startswith("OTGEO_")}
LIBRARY_CHECK = """
import importlib.util, sys
import numpy as np, trimesh
from solvers.domains import TriangleMesh
from solvers.convolutional import wasserstein_distance
service_only = sorted(m for m in {modules!r} if importlib.util.find_spec(m) is not None)
assert not service_only, f"service packages in a library-only install: {{service_only}}"
assert "site-packages" in __import__("solvers").__file__, "solvers imported from the checkout"
sphere = trimesh.creation.icosphere(subdivisions=3)
mesh = TriangleMesh(sphere.vertices, sphere.faces)
z = mesh.vertices[:, 2]  # rescaled to unit area: caps by quantile
mu0 = mesh.areas * (z > np.quantile(z, 0.8))
mu1 = mesh.areas * (z < np.quantile(z, 0.2))
result = wasserstein_distance(mesh, mu0, mu1)
assert np.isfinite(result.value) and result.value > 0, result
print(f"library: W2^2 = {{result.value:.4f}} ({{result.method}}) on {{mesh.n}} vertices")
"""


def run(*args, cwd: Path, **kw) -> subprocess.CompletedProcess:
    print("+", " ".join(map(str, args)), flush=True)
    kw.setdefault("env", CLEAN_ENV)
    return subprocess.run([str(a) for a in args], cwd=cwd, check=True, **kw)


def build(out: Path) -> Path:
    run(sys.executable, "-m", "build", "--outdir", out, ROOT, cwd=ROOT, env=os.environ)
    (wheel,) = out.glob("otgeo-*.whl")
    assert list(out.glob("otgeo-*.tar.gz")), "no sdist built"
    return wheel


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def get(url: str, data: bytes | None = None) -> tuple[int, bytes]:
    headers = {"content-type": "application/json"} if data is not None else {}
    try:
        with urllib.request.urlopen(urllib.request.Request(url, data, headers),
                                    timeout=120) as resp:
            return resp.status, resp.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def wait_healthy(url: str, server: subprocess.Popen, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert server.poll() is None, f"otgeo serve exited with {server.returncode}"
        try:
            if get(url + "/healthz")[0] == 200:
                return
        except OSError:
            pass
        time.sleep(0.2)
    raise TimeoutError(f"otgeo serve not healthy after {timeout} s")


def check_service(url: str) -> None:
    status, body = get(url + "/v1/domains", json.dumps({"kind": "grid",
                                                         "shape": [32, 32]}).encode())
    assert status in (200, 201), body
    domain = json.loads(body)["id"]
    request = {"mu0": {"vertex": 0, "radius": 0.3}, "mu1": {"vertex": 1023, "radius": 0.3}}
    status, body = get(f"{url}/v1/domains/{domain}/distances?wait=60",
                       json.dumps(request).encode())
    assert status in (200, 202), body
    job = json.loads(body)
    deadline = time.monotonic() + 600  # a loaded CI machine
    while job["state"] in ("queued", "running") and time.monotonic() < deadline:
        time.sleep(1)
        job = json.loads(get(f"{url}/v1/jobs/{job['id']}")[1])
    assert job["state"] == "succeeded", job
    status, body = get(f"{url}/v1/jobs/{job['id']}/result")
    assert status == 200 and json.loads(body)["values"]["value"] > 0, body
    print(f"service: job {job['id']} succeeded")
    status, body = get(url + "/viewer")
    assert status == 200 and b"<html" in body.lower(), (status, body[:200])
    shipped = sorted(p.relative_to(ROOT / "service" / "static").as_posix()
                     for p in (ROOT / "service" / "static").rglob("*") if p.is_file())
    for name in shipped:
        status, body = get(f"{url}/static/{name}")
        assert status == 200 and body == (ROOT / "service" / "static" / name).read_bytes(), \
            f"/static/{name}: {status}"
    print(f"service: viewer and its {len(shipped)} static files served")


def check_guide(url: str, built: bool) -> None:
    status, body = get(url + "/guide/")
    if built:
        assert status == 200 and b"<html" in body.lower(), (status, body[:200])
        print("service: /guide/ serves OTGEO_GUIDE_DIR")
    else:
        message = json.loads(body)["error"]["message"]
        assert status == 404 and "OTGEO_GUIDE_DIR" in message, (status, body)
        print(f"service: /guide/ without a built guide: 404 {message!r}")


def serve(venv: Path, work: Path, guide: Path | None) -> None:
    port = free_port()
    env = dict(CLEAN_ENV, OTGEO_DATA_DIR=str(work / f"data-{port}"), OTGEO_WORKERS="1")
    if guide is not None:
        env["OTGEO_GUIDE_DIR"] = str(guide)
    server = subprocess.Popen([venv / "bin" / "otgeo", "serve", "--port", str(port)], cwd=work,
                              env=env, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        wait_healthy(url, server)
        if guide is None:
            check_service(url)
        check_guide(url, built=guide is not None)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        try:
            server.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()


def main() -> None:
    sys.path.insert(0, str(ROOT))
    from service.cli import SERVICE_PACKAGES

    with tempfile.TemporaryDirectory(prefix="otgeo-wheel-") as tmp:
        work = Path(tmp)
        wheel = build(work / "dist")
        venv = work / "venv"
        run(sys.executable, "-m", "venv", venv, cwd=work)
        pip = [venv / "bin" / "python", "-m", "pip", "install", "-q"]
        run(*pip, wheel, cwd=work)
        run(venv / "bin" / "python", "-c", LIBRARY_CHECK.format(modules=sorted(SERVICE_PACKAGES)),
            cwd=work)
        refused = subprocess.run([venv / "bin" / "otgeo", "serve"], cwd=work, text=True,
                                 capture_output=True, env=CLEAN_ENV)
        assert refused.returncode == 2 and "otgeo[service]" in refused.stderr, refused
        print(f"library only: {refused.stderr.strip()}")
        run(*pip, f"{wheel}[service]", cwd=work)
        serve(venv, work, guide=None)
        built = ROOT / "docs" / "_build" / "html"
        if (built / "index.html").is_file():
            serve(venv, work, guide=built)
    print("wheel check: passed")


if __name__ == "__main__":
    main()
