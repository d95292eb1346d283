"""Results sized for the web, on every operation of the registry at its default sizes (its
request example reduced to the required fields, on a 642-vertex sphere and two small images):

- ``GET /v1/jobs/{id}/result`` stays within the JSON budget (``OTGEO_RESULT_JSON_BYTES``,
  1 MiB by default; at these sizes a soft map's arrays alone take ~9 MB of JSON and a BRDF
  interpolation's ~1.3 MB);
- every stored array is listed in ``array_files``, and its ``.npy`` link returns exactly the
  stored array; arrays inlined in ``arrays`` are the stored values;
- read with a tight budget, the same result links its arrays instead of inlining them;
- every link the finished job advertises (``links``: result, result_glb, events, domain)
  answers 2xx: a link is given only where it serves.
"""

from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
import pytest
from example_inputs import at_defaults, png_images, sphere_obj, substitute_ids
from fastapi.testclient import TestClient
from pydantic import ValidationError

from service.app import create_app
from service.errors import ApiError
from service.export import NPY_MEDIA_TYPE, to_jsonable
from service.job_service import JobService
from service.operations import build_registry
from service.operations.base import SubmitContext, view_of_info
from service.settings import Settings

BUDGET = Settings.model_fields["result_json_bytes"].default
TIGHT = 4096


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    data = tmp_path_factory.mktemp("budget")
    with TestClient(create_app(Settings(data_dir=data, queue="immediate"))) as client, \
            TestClient(create_app(Settings(data_dir=data, queue="immediate",
                                           result_json_bytes=TIGHT))) as tight:
        rt = client.app.state.runtime
        mesh = client.post("/v1/domains/upload", files={"file": ("sphere.obj", sphere_obj())})
        assert mesh.status_code == 201, mesh.text
        blobs = [rt.store.put_blob(png, "image/png")[0]["id"] for png in png_images()]
        yield SimpleNamespace(client=client, tight=tight, rt=rt, mesh=mesh.json()["id"],
                              blobs=blobs, jobs={})


def accepted(env, op, body: dict) -> bool:
    """Whether ``body`` passes the operation's validation at submission (nothing runs)."""
    try:
        request = op.request_model.model_validate(substitute_ids(body, env.mesh, env.blobs))
        target = (view_of_info(env.rt.store.domain_info(env.mesh)) if op.scope == "domain"
                  else SubmitContext(env.rt.store, env.rt.settings))
        op.validate(target, request)
    except (ValidationError, ApiError):
        return False
    return True


def run_at_defaults(env, name: str) -> str:
    """The id of a succeeded job of operation ``name`` at its defaults (run once per module)."""
    if name in env.jobs:
        return env.jobs[name]
    op = env.rt.operations[name]
    body = substitute_ids(at_defaults(op.request_model.model_json_schema(),
                                      lambda b: accepted(env, op, b)), env.mesh, env.blobs)
    job = JobService(env.rt).create(name, env.mesh if op.scope == "domain" else None,
                                    op.request_model.model_validate(body))
    assert job.state == "succeeded", job.error
    env.jobs[name] = job.id
    return job.id


@pytest.mark.parametrize("name", sorted(build_registry()))
def test_result_within_budget_at_default_sizes(env, name):
    job_id = run_at_defaults(env, name)
    resp = env.client.get(f"/v1/jobs/{job_id}/result")
    assert resp.status_code == 200, resp.text
    assert len(resp.content) <= BUDGET, f"{name}: {len(resp.content)} bytes of JSON"
    doc = resp.json()
    stored = env.rt.store.get_result_arrays(job_id)
    assert set(doc["array_files"]) == set(stored)
    assert set(doc["arrays"]) <= set(stored)
    for key, array in stored.items():
        info = doc["array_files"][key]
        assert info == {"href": f"/v1/jobs/{job_id}/arrays/{key}.npy",
                        "media_type": NPY_MEDIA_TYPE, "bytes": info["bytes"],
                        "shape": list(array.shape), "dtype": array.dtype.name}
        npy = env.client.get(info["href"])
        assert npy.status_code == 200 and npy.headers["content-type"] == NPY_MEDIA_TYPE
        assert int(npy.headers["content-length"]) == len(npy.content) == info["bytes"]
        loaded = np.load(io.BytesIO(npy.content), allow_pickle=False)
        assert loaded.dtype == array.dtype
        np.testing.assert_array_equal(loaded, array)
        if key in doc["arrays"]:
            assert doc["arrays"][key] == to_jsonable(array)

    bare = env.client.get(f"/v1/jobs/{job_id}/result?arrays=false")
    assert bare.json()["arrays"] == {} and bare.json()["array_files"] == doc["array_files"]
    tight = env.tight.get(f"/v1/jobs/{job_id}/result")
    assert len(tight.content) <= max(TIGHT, len(bare.content))
    small = tight.json()["arrays"]
    assert set(small) <= set(doc["arrays"])
    assert all(small[k] == doc["arrays"][k] for k in small)
    if len(resp.content) > TIGHT:  # something had to be left out
        assert set(small) < set(stored)


@pytest.mark.parametrize("name", sorted(build_registry()))
def test_every_advertised_link_serves(env, name):
    job_id = run_at_defaults(env, name)
    job = env.client.get(f"/v1/jobs/{job_id}")
    assert job.status_code == 200, job.text
    links = job.json()["links"]
    assert {"self", "result", "events"} <= set(links), links
    listed = env.client.get(f"/v1/jobs?operation={name}").json()["jobs"]
    assert next(j for j in listed if j["id"] == job_id)["links"] == links
    for key, href in links.items():
        resp = env.client.get(href)
        assert 200 <= resp.status_code < 300, (name, key, href, resp.status_code, resp.text)
    if "result_glb" not in links:  # left out only where there is no glTF
        glb = env.client.get(f"/v1/jobs/{job_id}/result.glb")
        assert glb.status_code == 409 and glb.json()["error"]["code"] == "no_glb", glb.text
