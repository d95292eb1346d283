"""Result arrays as files: the store reads an .npz member by member (index from the headers,
a row without the rest, the .npy bytes as stored), the JSON result inlines arrays within its
budget (smallest first, exact byte accounting), the routes' errors, and Retry-After on 202."""

from __future__ import annotations

import io

import numpy as np
import pytest
from service_testing import assert_error

from service.export import json_bytes, result_document, to_jsonable
from service.job_service import JobService
from service.operations.base import (
    BumpDistribution,
    Operation,
    OperationOutput,
    OperationRequest,
)
from service.store import Store

ARRAYS = {
    "vector": np.linspace(0.0, 1.0, 7),
    "matrix": np.arange(60, dtype=np.float32).reshape(12, 5) / 7,
    "labels": np.arange(9, dtype=np.int64) - 4,
    "flags": np.array([True, False, True]),
    "fortran": np.asfortranarray(np.arange(12.0).reshape(3, 4)),
    "holes": np.array([1.0, np.inf, np.nan, -np.inf]),
}


@pytest.fixture
def store(tmp_path):
    store = Store(tmp_path)
    store.put_result("job", {"job_id": "job", "operation": "t", "domain_id": "", "values": {}},
                     ARRAYS)
    return store


def test_index_lists_shape_dtype_and_file_size(store):
    index = store.result_array_index("job")
    assert set(index) == set(ARRAYS)
    for name, array in ARRAYS.items():
        buf = io.BytesIO()
        np.save(buf, array)
        assert index[name].shape == array.shape and index[name].dtype == array.dtype
        assert index[name].npy_bytes == len(buf.getvalue())
    assert index["fortran"].data_offset is None  # rows of it go through np.load
    assert index["matrix"].data_offset is not None
    assert store.result_array_index("missing") == {}


def test_npy_file_is_the_stored_array(store):
    for name, array in ARRAYS.items():
        chunks, size = store.result_array_npy("job", name, chunk=64)
        data = b"".join(chunks)
        assert len(data) == size
        expected = io.BytesIO()
        np.save(expected, array)
        assert data == expected.getvalue()


def test_rows_are_read_alone_and_exact(store, monkeypatch):
    monkeypatch.setattr(Store, "get_result_array", lambda *a: pytest.fail("whole array read"))
    for i in range(12):
        row = store.get_result_row("job", "matrix", i)
        assert row.dtype == np.float32
        np.testing.assert_array_equal(row, ARRAYS["matrix"][i])
    monkeypatch.undo()
    np.testing.assert_array_equal(store.get_result_row("job", "fortran", 2), ARRAYS["fortran"][2])


def document(store, budget, include_arrays=True):
    index = store.result_array_index("job")
    return result_document("job", store.get_result("job"), index,
                           lambda name: store.get_result_array("job", name), budget,
                           include_arrays)


def test_budget_inlines_smallest_first_within_the_bytes(store):
    sizes = {name: len(json_bytes(to_jsonable(a))) for name, a in ARRAYS.items()}
    links_only = len(json_bytes(document(store, 0)))
    assert document(store, 0)["arrays"] == {}
    everything = document(store, 10**9)
    assert everything["arrays"] == {k: to_jsonable(a) for k, a in ARRAYS.items()}
    assert everything["arrays"]["holes"] == [1.0, None, None, None]  # no NaN in JSON
    total = len(json_bytes(everything))
    for budget in range(links_only, total + 1, 7):
        doc = document(store, budget)
        assert len(json_bytes(doc)) <= budget
        inline = set(doc["arrays"])
        order = sorted(ARRAYS, key=lambda k: (ARRAYS[k].size, k))
        for k in inline:
            assert doc["arrays"][k] == to_jsonable(ARRAYS[k])
        left = [k for k in order if k not in inline]
        if left:  # smallest first: the smallest array left out did not fit
            first = left[0]
            extra = len(json_bytes(first)) + 1 + bool(inline) + sizes[first]
            assert len(json_bytes(doc)) + extra > budget
    assert document(store, total)["arrays"].keys() == set(ARRAYS)
    assert document(store, 10**9, include_arrays=False)["arrays"] == {}


def test_links_name_each_file(store):
    files = document(store, 0)["array_files"]
    assert files["matrix"] == {"href": "/v1/jobs/job/arrays/matrix.npy",
                               "media_type": "application/x-npy",
                               "bytes": store.result_array_index("job")["matrix"].npy_bytes,
                               "shape": [12, 5], "dtype": "float32"}


# -- through the API ------------------------------------------------------------------------
class MatrixRequest(OperationRequest):
    rows: int = 3


def _matrix(domain, req, progress, should_cancel):
    return OperationOutput({"iterations": 1}, {"m": np.arange(req.rows * 4.0).reshape(-1, 4),
                                               "v": np.ones(2)})


MATRIX_OP = Operation("matrices", "createMatrixJob", "test", MatrixRequest, _matrix,
                      lambda view, req: [])


def test_array_routes(client):
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4]}).json()["id"]
    rt = client.app.state.runtime
    rt.operations[MATRIX_OP.name] = MATRIX_OP  # test-only operation, no HTTP route
    job = JobService(rt).create("matrices", grid, MatrixRequest(rows=5))
    assert job.state == "succeeded"
    base = f"/v1/jobs/{job.id}"
    npy = client.get(f"{base}/arrays/m.npy")
    assert npy.status_code == 200 and npy.headers["content-type"] == "application/x-npy"
    assert 'filename="' in npy.headers["content-disposition"]
    np.testing.assert_array_equal(np.load(io.BytesIO(npy.content)), np.arange(20.0).reshape(5, 4))
    row = client.get(f"{base}/arrays/m/rows/4").json()
    assert row == {"name": "m", "row": 4, "values": [16.0, 17.0, 18.0, 19.0]}
    assert_error(client.get(f"{base}/arrays/nope.npy"), 404, "name")
    assert_error(client.get(f"{base}/arrays/nope/rows/0"), 404, "name")
    assert_error(client.get(f"{base}/arrays/v/rows/0"), 422, "name")
    assert_error(client.get(f"{base}/arrays/m/rows/5"), 422, "row")
    assert_error(client.get(f"/v1/jobs/{'0' * 32}/arrays/m.npy"), 404, "job_id")


def test_retry_after_on_202_only(make_client, tmp_path):
    body = {"mu0": BumpDistribution(vertex=0, radius=0.3).model_dump(),
            "mu1": BumpDistribution(vertex=35, radius=0.3).model_dump()}
    client = make_client(queue="sqlite")  # no worker consumes: the job stays queued
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [6, 6]}).json()["id"]
    queued = client.post(f"/v1/domains/{grid}/distances?wait=0.05", json=body)
    assert queued.status_code == 202
    assert queued.headers["Retry-After"] == "1"  # short queue, no estimate yet
    assert queued.headers["Location"] == f"/v1/jobs/{queued.json()['id']}"
    assert_error(client.get(f"/v1/jobs/{queued.json()['id']}/arrays/m.npy"), 409, "job_id")
    done = make_client(data_dir=tmp_path / "immediate")
    grid = done.post("/v1/domains", json={"kind": "grid", "shape": [6, 6]}).json()["id"]
    finished = done.post(f"/v1/domains/{grid}/distances", json=body)
    assert finished.status_code == 200 and "Retry-After" not in finished.headers


def test_retry_after_follows_the_estimate():
    from service.schemas import RETRY_AFTER_MAX, JobOut, JobProgress, retry_after

    def job(queue="short", eta=None):
        return JobOut.model_construct(queue=queue, progress=JobProgress(eta_seconds=eta))

    assert retry_after(job()) == 1 and retry_after(job("long")) == 5
    assert retry_after(job(eta=0.2)) == 1 and retry_after(job(eta=7.1)) == 8
    assert retry_after(job("long", eta=1e4)) == RETRY_AFTER_MAX
