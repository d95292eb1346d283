"""The service's OpenAPI document generates a working Python client (openapi-python-client,
default configuration, nothing patched), which drives a live ``otgeo serve`` (embedded
defaults: Huey on SQLite, worker processes): upload a mesh file and a JSON domain, run a
barycenter job, read its result typed per operation, and the GLB as bytes.

The client is generated from ``openapi_document()`` (what ``otgeo openapi`` writes and
tests/service/test_openapi.py compares with the checked-in openapi/openapi.json)."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from liveserver import API

from service.cli import openapi_document
from service.export import parse_glb

API_KEY = "sdk-test-key"
PACKAGE = "otgeo_sdk_test_client"


@pytest.fixture(scope="module")
def sdk(tmp_path_factory):
    """Generate the client into a temporary directory and import it, unmodified."""
    out = tmp_path_factory.mktemp("sdk")
    spec = out / "openapi.json"
    spec.write_text(openapi_document())
    bin_dir = str(Path(sys.executable).parent)
    exe = Path(bin_dir) / "openapi-python-client"
    assert exe.exists(), "openapi-python-client is in the dev extra (pyproject.toml)"
    env = {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", "")}
    proc = subprocess.run(
        [str(exe), "generate", "--path", str(spec), "--meta", "none", "--output-path",
         str(out / PACKAGE)], cwd=out, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # every endpoint and response is generated (no "Cannot parse response" / skipped pieces)
    assert "Unsupported content_type" not in proc.stdout + proc.stderr, proc.stdout
    assert "Cannot parse" not in proc.stdout + proc.stderr, proc.stdout
    sys.path.insert(0, str(out))
    try:
        package = importlib.import_module(PACKAGE)
        for path in sorted((out / PACKAGE / "api").rglob("*.py")):  # each module imports
            rel = path.relative_to(out).with_suffix("")
            importlib.import_module(".".join(rel.parts).removesuffix(".__init__"))
        yield package
    finally:
        sys.path.remove(str(out))
        for name in [m for m in sys.modules if m == PACKAGE or m.startswith(PACKAGE + ".")]:
            del sys.modules[name]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("data")
    api = API({"OTGEO_DATA_DIR": str(data), "OTGEO_API_KEYS": API_KEY}, data)
    try:
        api.wait_healthy(timeout=60)
        yield api
    finally:
        api.stop()


def test_generated_client_drives_a_live_server(sdk, server, meshes_dir):
    client_mod = importlib.import_module(f"{PACKAGE}.client")
    types = importlib.import_module(f"{PACKAGE}.types")
    models = importlib.import_module(f"{PACKAGE}.models")
    upload_domain = importlib.import_module(f"{PACKAGE}.api.domains.upload_domain")
    create_domain = importlib.import_module(f"{PACKAGE}.api.domains.create_domain")
    create_barycenter = importlib.import_module(
        f"{PACKAGE}.api.operations.create_barycenter_job")
    get_job = importlib.import_module(f"{PACKAGE}.api.jobs.get_job")
    get_result = importlib.import_module(f"{PACKAGE}.api.jobs.get_job_result")
    get_glb = importlib.import_module(f"{PACKAGE}.api.jobs.get_job_result_glb")

    client = client_mod.AuthenticatedClient(base_url=server.url, token=API_KEY, prefix="",
                                            auth_header_name="X-API-Key", timeout=60)
    mesh_bytes = (meshes_dir / "woody.obj").read_bytes()

    def body():
        return models.UploadDomainBody(file=types.File(payload=mesh_bytes,
                                                       file_name="woody.obj"))

    # authentication is enforced when keys are configured: a keyless client gets 401
    anonymous = client_mod.Client(base_url=server.url)
    denied = upload_domain.sync_detailed(client=anonymous, body=body())
    assert denied.status_code == 401

    first = upload_domain.sync_detailed(client=client, body=body())
    assert first.status_code == 201, first.content
    domain = first.parsed
    assert isinstance(domain, models.DomainOut)
    assert domain.kind == "mesh" and domain.sizes["vertices"] == 694
    assert domain.boundary.loops >= 1  # woody is open
    again = upload_domain.sync_detailed(client=client, body=body())
    assert again.status_code == 200 and again.parsed.id == domain.id  # content addressed

    # a JSON domain through its own operation
    grid = create_domain.sync_detailed(client=client,
                                       body=models.GridSpec(kind="grid", shape=[8, 8]))
    assert grid.status_code == 201, grid.content
    assert isinstance(grid.parsed, models.DomainOut) and grid.parsed.n == 64

    n = domain.n
    request = models.BarycenterRequest(
        distributions=[models.BumpDistribution(vertex=0, radius=0.3),
                       models.BumpDistribution(vertex=n - 1, radius=0.3)],
        weights=[0.5, 0.5], max_iter=300, tol=1e-6)
    job = create_barycenter.sync(domain.id, client=client, body=request, wait=20.0)
    assert isinstance(job, models.JobOut), job
    assert job.operation == "barycenters" and job.domain_id == domain.id
    if job.state.value not in ("succeeded", "failed", "cancelled"):
        job = get_job.sync(job.id, client=client)
    assert job.state.value == "succeeded", job.error
    assert job.attempts == 1

    result = get_result.sync(job.id, client=client)
    assert type(result).__name__ == "BarycenterJobResult", type(result)  # typed per operation
    assert result.operation == "barycenters"
    masses = np.asarray(result.arrays["masses"], dtype=np.float64)
    assert masses.shape == (n,)
    assert masses.min() >= 0 and masses.sum() == pytest.approx(1.0, abs=1e-6)
    values = result.values.to_dict()
    assert values["iterations"] >= 1

    glb = get_glb.sync_detailed(job.id, client=client)
    assert glb.status_code == 200 and glb.headers["content-type"] == "model/gltf-binary"
    assert isinstance(glb.parsed, types.File)
    doc, binary = parse_glb(glb.parsed.payload.read())
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    acc = doc["accessors"][attrs["_MASSES"]]
    view = doc["bufferViews"][acc["bufferView"]]
    stored = np.frombuffer(binary, np.float32, acc["count"], view["byteOffset"])
    np.testing.assert_array_equal(stored, masses.astype(np.float32))

    # errors come back parsed, naming the field
    missing = get_job.sync_detailed("0" * 32, client=client)
    assert missing.status_code == 404
    assert missing.parsed.error.field == "job_id"
