"""Every operation of the service's OpenAPI document through a Python client generated from
it (openapi-python-client, default configuration, nothing patched), against a live
``otgeo serve`` (embedded: Huey on SQLite, a worker process, an API key).

Driven by the document, so operations added later are covered without editing this file:

- the generator must print no warning (a warning means a model or an endpoint was dropped);
- every job-creating operation submits its request model's OpenAPI example, placeholder ids
  (``EXAMPLE_ID``) replaced by an uploaded mesh (or blobs); file fields get small real
  files; JSON domains are created from each domain kind's example;
- the job routes take their path parameters from the jobs so created (a job with files for
  ``/files/{name}``, a 2-D array for ``/rows/{row}``), cancel a long job, delete a domain;
- the test fails if an operation of the document has no example, has parameters it cannot
  fill, or was not called.

The client is generated from ``openapi_document()`` (what ``otgeo openapi`` writes and
tests/service/test_openapi.py compares with the checked-in openapi/openapi.json).

The documentation's examples of a keyed server (tests/doc_examples.py ``KEYED``: the
generated client of docs/getting_started.rst) run here too, against this server with its key
in ``OTGEO_API_KEY``, as tests/service/test_readme_examples.py runs the others against an
open one (a keyed server there would be a second server start for one example)."""

from __future__ import annotations

import importlib
import io
import json
import os
import re
import subprocess
import sys
import time
import typing
from pathlib import Path
from types import UnionType

import numpy as np
import pytest
from doc_examples import KEYED, checkout, documents, environment, extract, matching
from example_inputs import png_images, schema_example, sphere_obj, substitute_ids
from liveserver import API
from spec_refs import referenced

from service.cli import openapi_document
from service.export import parse_glb

API_KEY = "sdk-test-key"
PACKAGE = "otgeo_sdk_test_client"
WAIT = 60.0  # ?wait= of job submissions (the server's default wait_max)
FILES = {  # multipart file fields -> (file name, bytes) of the files to send
    "file": lambda: [("sphere.obj", sphere_obj())],
    "images": lambda: [(f"image-{i}.png", png) for i, png in enumerate(png_images())],
}
# Generator output that means something was dropped or not generated as specified.
PROBLEMS = re.compile(r"warning|error|unable|cannot|could not|skipp|unsupported", re.I)


def generate(spec: Path, out: Path) -> str:
    bin_dir = str(Path(sys.executable).parent)
    exe = Path(bin_dir) / "openapi-python-client"
    assert exe.exists(), "openapi-python-client is in the dev extra (pyproject.toml)"
    env = {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", "")}
    proc = subprocess.run(
        [str(exe), "generate", "--path", str(spec), "--meta", "none", "--output-path",
         str(out)], cwd=out.parent, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout + proc.stderr


@pytest.fixture(scope="module")
def doc():
    return json.loads(openapi_document())


@pytest.fixture(scope="module")
def sdk(tmp_path_factory, doc):
    """Generate the client into a temporary directory and import it, unmodified."""
    out = tmp_path_factory.mktemp("sdk")
    spec = out / "openapi.json"
    spec.write_text(json.dumps(doc))
    output = generate(spec, out / PACKAGE)
    problems = [line for line in output.splitlines() if PROBLEMS.search(line)]
    assert problems == [], output
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


def test_generator_reports_duplicate_models(tmp_path, doc):
    """The warning check above can fail: two schemas titled alike make the generator warn.
    The document holds only those two schemas and what they reference (the generator's run
    on the whole document, about 2 CPU-s, is the fixture's)."""
    schemas = doc["components"]["schemas"]
    keep = referenced(schemas, {"FixedPosition", "FixedDistribution"})
    broken = {"openapi": doc["openapi"], "info": doc["info"], "paths": {},
              "components": {"schemas": json.loads(json.dumps(
                  {name: schemas[name] for name in sorted(keep)}))}}
    broken["components"]["schemas"]["FixedPosition"]["title"] = "FixedDistribution"
    (tmp_path / "spec.json").write_text(json.dumps(broken))
    output = generate(tmp_path / "spec.json", tmp_path / "client")
    assert PROBLEMS.search(output) and "FixedDistribution" in output, output


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("data")
    # one worker process (the default is one per core): a second would add its start-up
    # (imports, kernel warm-up: about 2 CPU-s) and nothing this test checks needs two
    api = API({"OTGEO_DATA_DIR": str(data), "OTGEO_API_KEYS": API_KEY, "OTGEO_WORKERS": "1"},
              data)
    try:
        api.wait_healthy(timeout=60)
        yield api
    finally:
        api.stop()


# -- the document -> the generated client ------------------------------------------------
class Spec:
    """The document's operations and the generated function of each (``sync_detailed``)."""

    def __init__(self, doc: dict, sdk):
        from openapi_python_client.strings import snake_case

        self.doc, self.snake = doc, snake_case
        self.ops = {op["operationId"]: {**op, "method": method, "path": path}
                    for path, methods in doc["paths"].items()
                    for method, op in methods.items()}
        self.package = sdk.__name__
        self.models = importlib.import_module(f"{self.package}.models")
        self.types = importlib.import_module(f"{self.package}.types")

    def function(self, op_id: str):
        op = self.ops[op_id]
        module = importlib.import_module(
            f"{self.package}.api.{self.snake(op['tags'][0])}.{self.snake(op_id)}")
        return module.sync_detailed

    def schema(self, ref_or_schema: dict) -> dict:
        if "$ref" in ref_or_schema:
            return self.doc["components"]["schemas"][ref_or_schema["$ref"].split("/")[-1]]
        return ref_or_schema

    def body(self, op_id: str) -> tuple[str, dict] | None:
        """``(media type, schema)`` of the operation's request body, if it has one."""
        content = self.ops[op_id].get("requestBody", {}).get("content", {})
        for media, item in content.items():
            return media, self.schema(item["schema"])
        return None

    def creates_job(self, op_id: str) -> bool:
        """A POST answering with the job (202, or 200 when finished within ?wait=)."""
        if self.ops[op_id]["method"] != "post":
            return False
        responses = self.ops[op_id]["responses"]
        ok = responses.get("202") or responses.get("200", {})
        schema = ok.get("content", {}).get("application/json", {}).get("schema", {})
        return schema.get("$ref", "").endswith("/JobOut")


class Calls:
    """Calls every operation through the client, recording the status of each."""

    def __init__(self, spec: Spec, client):
        self.spec, self.client = spec, client
        self.statuses: dict[str, list[int]] = {}

    def __call__(self, op_id: str, *, expect: int | tuple = (200, 201, 202, 204), body=None,
                 **params):
        fn = self.spec.function(op_id)
        kwargs = {self.spec.snake(k): v for k, v in params.items()}
        if body is not None:
            kwargs["body"] = body
        resp = fn(client=self.client, **kwargs)
        self.statuses.setdefault(op_id, []).append(resp.status_code)
        expected = (expect,) if isinstance(expect, int) else expect
        assert resp.status_code in expected, (op_id, resp.status_code, resp.content[:500])
        return resp

    def json_body(self, op_id: str, example: dict):
        """The generated model of ``op_id``'s JSON body holding ``example``: for a union body
        (one model per domain kind), the member that reproduces the example."""
        fn = self.spec.function(op_id)
        annotation = typing.get_type_hints(fn)["body"]
        members = typing.get_args(annotation) if isinstance(annotation, UnionType) \
            else (annotation,)
        for cls in members:
            try:
                body = cls.from_dict(example)
            except (KeyError, TypeError, ValueError):
                continue
            if body.to_dict() == example:
                return body
        raise AssertionError(f"{op_id}: no generated model reproduces {example}")

    def multipart_body(self, op_id: str, schema: dict):
        """The multipart body: every file field from FILES, other fields at their defaults."""
        fn = self.spec.function(op_id)
        cls = typing.get_type_hints(fn)["body"]
        kwargs = {}
        for name, prop in schema["properties"].items():
            binary = prop.get("format") == "binary" or prop.get("items", {}).get(
                "format") == "binary"
            if not binary:
                assert name not in schema.get("required", []), f"{op_id}: {name} needs a value"
                continue
            assert name in FILES, f"{op_id}: no test file for the file field {name!r}"
            files = [self.spec.types.File(payload=io.BytesIO(data), file_name=file_name)
                     for file_name, data in FILES[name]()]
            kwargs[self.spec.snake(name)] = files if prop.get("type") == "array" else files[0]
        return cls(**kwargs)

    def body_for(self, op_id: str, mesh_id: str, example: dict | None = None):
        media, schema = self.spec.body(op_id)
        if media == "multipart/form-data":
            return self.multipart_body(op_id, schema)
        assert media == "application/json", (op_id, media)
        return self.json_body(op_id, substitute_ids(example or schema_example(schema), mesh_id))


def wait_finished(calls: Calls, job_id: str, timeout: float = 120.0):
    deadline = time.monotonic() + timeout
    while True:
        job = calls("getJob", job_id=job_id).parsed
        if job.state.value in ("succeeded", "failed", "cancelled"):
            return job
        assert time.monotonic() < deadline, f"job {job_id} still {job.state.value}"
        time.sleep(0.2)


def result_model_names(spec: Spec) -> dict[str, str]:
    """operation name -> title of its typed result schema (``...Result``)."""
    out = {}
    for key, schema in spec.doc["components"]["schemas"].items():
        const = schema.get("properties", {}).get("operation", {}).get("const")
        if const:
            out[const] = schema.get("title", key)
    return out


# -- the test -----------------------------------------------------------------------------
def test_every_operation_through_the_generated_client(sdk, server, doc):
    spec = Spec(doc, sdk)
    client_mod = importlib.import_module(f"{sdk.__name__}.client")
    client = client_mod.AuthenticatedClient(base_url=server.url, token=API_KEY, prefix="",
                                            auth_header_name="X-API-Key", timeout=120)
    calls = Calls(spec, client)

    # authentication is enforced when keys are configured: a keyless client gets 401
    anonymous = Calls(spec, client_mod.Client(base_url=server.url))
    anonymous("uploadDomain", expect=401, body=calls.body_for("uploadDomain", ""))

    # domains: the sphere every domain operation runs on, and each JSON kind's example
    upload = calls("uploadDomain", expect=201, body=calls.body_for("uploadDomain", ""))
    mesh = upload.parsed
    assert type(mesh).__name__ == "DomainOut" and mesh.kind == "mesh" and mesh.n == 642
    again = calls("uploadDomain", expect=200, body=calls.body_for("uploadDomain", ""))
    assert again.parsed.id == mesh.id  # content addressed
    created = []
    for member in spec.schema(spec.body("createDomain")[1]).get("oneOf", []):
        example = schema_example(spec.schema(member))
        domain = calls("createDomain", body=calls.json_body("createDomain", example)).parsed
        assert domain.kind == example["kind"], (domain, example)
        created.append(domain.id)
    assert len(created) == 4

    # every job-creating operation from its example, waited for
    jobs = {}
    for op_id in sorted(o for o in spec.ops if spec.creates_job(o)):
        params = {"domain_id": mesh.id} if "{domain_id}" in spec.ops[op_id]["path"] else {}
        resp = calls(op_id, body=calls.body_for(op_id, mesh.id), wait=WAIT, **params)
        job = resp.parsed
        if job.state.value not in ("succeeded", "failed", "cancelled"):
            assert resp.headers["retry-after"].isdigit()
            job = wait_finished(calls, job.id)
        assert job.state.value == "succeeded", (op_id, job.error)
        jobs[op_id] = job

    # results, typed per operation; arrays as .npy files equal to the inline values
    typed = result_model_names(spec)
    results = {}
    for op_id, job in jobs.items():
        result = calls("getJobResult", job_id=job.id).parsed
        assert type(result).__name__ == typed[job.operation], (op_id, type(result))
        results[op_id] = result
        for name, info in result.array_files.additional_properties.items():
            npy = calls("getJobResultArray", job_id=job.id, name=name)
            assert npy.headers["content-type"] == "application/x-npy"
            array = np.load(io.BytesIO(npy.content), allow_pickle=False)
            assert list(array.shape) == info.shape and array.dtype.name == info.dtype
            inline = result.arrays.additional_properties.get(name)
            if inline is not None:
                np.testing.assert_array_equal(
                    np.asarray(inline, dtype=np.float64), array.astype(np.float64))

    bary = jobs["createBarycenterJob"]
    masses = np.asarray(results["createBarycenterJob"].arrays["masses"], dtype=np.float64)
    assert masses.shape == (mesh.n,) and masses.sum() == pytest.approx(1.0, abs=1e-6)
    assert results["createBarycenterJob"].values.to_dict()["iterations"] >= 1

    # the remaining routes of jobs and domains, their parameters taken from what exists
    def job_with(need) -> tuple:
        for op_id, result in results.items():
            found = need(result)
            if found is not None:
                return jobs[op_id].id, found
        raise AssertionError(f"no job has what {need.__doc__} needs")

    def a_file(result):
        """/files/{name}"""
        names = list(result.files.additional_properties)
        return names[0] if names else None

    def a_matrix(result):
        """/arrays/{name}/rows/{row}"""
        return next((n for n, info in result.array_files.additional_properties.items()
                     if len(info.shape) == 2), None)

    done = {"uploadDomain", "createDomain", "getJobResult", "getJobResultArray", "getJob",
            *jobs}
    for op_id, op in sorted(spec.ops.items()):
        if op_id in done or op["method"] != "get":
            continue
        names = [p["name"] for p in op.get("parameters", []) if p["in"] == "path"]
        if "job_id" in names:
            need = a_file if "/files/{name}" in op["path"] else a_matrix if "/rows/" in op["path"] \
                else (lambda result: True)
            job_id, found = job_with(need)
            params = {"job_id": job_id, **({"name": found} if "name" in names else {}),
                      **({"row": 0} if "row" in names else {})}
        elif names == ["domain_id"]:
            params = {"domain_id": mesh.id}
        else:
            assert names == [], f"{op_id}: no test value for the path parameters {names}"
            params = {}
        resp = calls(op_id, expect=200, **params)
        assert resp.parsed is not None or op_id in ("streamJobEvents",), op_id

    glb = calls("getJobResultGlb", job_id=bary.id)
    assert glb.headers["content-type"] == "model/gltf-binary"
    gltf, binary = parse_glb(glb.parsed.payload.read())
    acc = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["_MASSES"]]
    view = gltf["bufferViews"][acc["bufferView"]]
    stored = np.frombuffer(binary, np.float32, acc["count"], view["byteOffset"])
    np.testing.assert_array_equal(stored, masses.astype(np.float32))
    events = calls("streamJobEvents", job_id=bary.id)
    assert b"event: end" in events.content

    # cancel: a job asked for an unreachable tolerance, cancelled while it runs (candidates
    # in turn: one that ends before the cancel arrives does not count)
    cancelled = None
    for op_id in sorted(jobs):
        media, schema = spec.body(op_id)
        props = schema.get("properties", {})
        if media != "application/json" or not {"tol", "max_iter"} <= set(props):
            continue
        example = {**schema_example(schema), "tol": 1e-15, "max_iter": 10_000}
        params = {"domain_id": mesh.id} if "{domain_id}" in spec.ops[op_id]["path"] else {}
        running = calls(op_id, expect=202, body=calls.body_for(op_id, mesh.id, example),
                        **params)
        assert int(running.headers["retry-after"]) >= 1
        calls("cancelJob", expect=(200, 409), job_id=running.parsed.id)
        if wait_finished(calls, running.parsed.id).state.value == "cancelled":
            cancelled = op_id
            break
    assert cancelled is not None, "no job could be cancelled while running"
    assert 200 in calls.statuses["cancelJob"]

    # delete a JSON domain: gone afterwards; errors come back parsed, naming the field
    calls("deleteDomain", domain_id=created[0])
    missing = calls("getDomain", expect=404, domain_id=created[0])
    assert missing.parsed.error.field == "domain_id"
    missing = calls("getJob", expect=404, job_id="0" * 32)
    assert missing.parsed.error.field == "job_id"

    not_called = sorted(set(spec.ops) - set(calls.statuses))
    assert not_called == [], f"operations of the document never called: {not_called}"


KEYED_EXAMPLES = [e for doc in documents() for e in extract(doc)
                  if e.runnable and matching(KEYED, e) is not None]


@pytest.mark.parametrize("example", KEYED_EXAMPLES, ids=[e.id for e in KEYED_EXAMPLES])
def test_documented_keyed_example(example, server, tmp_path):
    """Runs as tests/service/test_readme_examples.py runs an example (a scratch checkout,
    ``bash -e -o pipefail`` or this interpreter, exit status 0), with the key."""
    assert example.language in ("shell", "python"), example.id
    argv = [sys.executable, "-c", example.code] if example.language == "python" else \
        ["bash", "-e", "-o", "pipefail", "-c", example.code]
    out = subprocess.run(argv, cwd=checkout(tmp_path), env=environment(server.url, API_KEY),
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, f"{example.id} exited {out.returncode}:\n" \
                                f"{out.stdout[-2000:]}\n{out.stderr[-3000:]}\n{server.log()}"
