"""Operations not bound to one domain: validation over several stored domains and blobs,
result files, array rows, and the GLB a job produced itself."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import Field
from service_testing import assert_error

from service.errors import NotFound
from service.job_service import JobService
from service.operations import Operation, OperationOutput, ResultFile, build_registry
from service.operations.base import OperationRequest


class PairRequest(OperationRequest):
    first: str = Field(description="domain id")
    second: str = Field(description="domain id")
    note: str | None = Field(None, description="blob id")


def _validate(ctx, req):
    a, b = ctx.view(req.first, "first"), ctx.view(req.second, "second")
    if req.note is not None:
        ctx.blob_meta(req.note, "note")
    return [{"first": a.n, "second": b.n}]


def _run(ctx, req, progress, should_cancel):
    a, b = ctx.domain(req.first, "first"), ctx.domain(req.second, "second")
    progress(1, 0.5)
    outer = np.outer(np.asarray(a.areas), np.asarray(b.areas))  # (n_a, n_b)
    note = ctx.blob(req.note, "note") if req.note is not None else b""
    return OperationOutput({"n_first": a.n, "n_second": b.n}, {"outer": outer},
                           files={"note.txt": ResultFile("text/plain", note + b"!"),
                                  "result.glb": ResultFile("model/gltf-binary", b"glTF-ish")})


PAIR_OP = Operation("test-pair", "createTestPairJob", "two domains", PairRequest, _run,
                    _validate, scope="global", domain_field="first")


def _grid(client, shape):
    return client.post("/v1/domains", json={"kind": "grid", "shape": list(shape)}).json()["id"]


def _submit(client, **body):
    rt = client.app.state.runtime
    rt.operations[PAIR_OP.name] = PAIR_OP
    return JobService(rt).create(PAIR_OP.name, None, PairRequest(**body))


def test_global_operation_files_rows_and_glb(client):
    a, b = _grid(client, (3, 4)), _grid(client, (5, 2))
    blob, created = client.app.state.runtime.store.put_blob(b"hello", "text/plain")
    assert created
    job = _submit(client, first=a, second=b, note=blob["id"])
    assert job.state == "succeeded" and job.domain_id == a
    result = client.get(f"/v1/jobs/{job.id}/result").json()
    assert result["values"] == {"n_first": 12, "n_second": 10}
    assert result["files"]["note.txt"] == {"media_type": "text/plain", "bytes": 6}
    r = client.get(f"/v1/jobs/{job.id}/files/note.txt")
    assert r.status_code == 200 and r.content == b"hello!"
    assert r.headers["content-type"].startswith("text/plain")
    row = client.get(f"/v1/jobs/{job.id}/arrays/outer/rows/2").json()
    np.testing.assert_allclose(row["values"], np.full(10, 1 / 120))
    assert client.get(f"/v1/jobs/{job.id}/result.glb").content == b"glTF-ish"
    assert_error(client.get(f"/v1/jobs/{job.id}/arrays/outer/rows/12"), 422, "row")
    assert_error(client.get(f"/v1/jobs/{job.id}/arrays/nope/rows/0"), 404, "name")
    assert_error(client.get(f"/v1/jobs/{job.id}/files/other.png"), 404, "name")


def test_global_operation_refuses_unknown_inputs_at_submission(client):
    a = _grid(client, (3, 3))
    with pytest.raises(NotFound) as err:
        _submit(client, first=a, second="0" * 64)
    assert err.value.field == "second"
    with pytest.raises(NotFound) as err:
        _submit(client, first=a, second=a, note="f" * 64)
    assert err.value.field == "note"
    assert client.get("/v1/jobs").json()["jobs"] == []  # nothing was recorded


def test_registry_is_built_per_app_and_refuses_duplicates():
    first, second = build_registry(), build_registry()
    assert first is not second and set(first) == set(second)
    first["extra"] = PAIR_OP
    assert "extra" not in build_registry()

    class Family:
        OPERATIONS = [PAIR_OP, PAIR_OP]

    with pytest.raises(ValueError, match="twice"):
        build_registry((Family,))


def test_submission_reports_the_queue_position(make_client):
    client = make_client(queue="sqlite")  # no worker consumes: jobs stay queued
    gid = _grid(client, (6, 6))
    body = {"mu0": {"vertex": 0, "radius": 0.2}, "mu1": {"vertex": 35, "radius": 0.2}}
    first = client.post(f"/v1/domains/{gid}/distances", json=body)
    second = client.post(f"/v1/domains/{gid}/distances", json=body)
    assert first.status_code == second.status_code == 202
    assert first.json()["queue_position"] == 1 and second.json()["queue_position"] == 2
