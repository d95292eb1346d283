"""Malformed bodies on the operation routes get the ``invalid_json`` error naming ``body``
(as on /v1/domains), and large bodies are parsed off the event loop."""

from __future__ import annotations

import pytest
from service_testing import assert_error

from service.api import bodies


@pytest.fixture
def grid(client) -> str:
    return client.post("/v1/domains", json={"kind": "grid", "shape": [9, 9]}).json()["id"]


def _routes(client, grid):
    """Every operation route of the app (domain-scoped ones on ``grid``)."""
    paths = []
    for op in client.app.state.runtime.operations.values():
        if op.route:
            paths.append(f"/v1/domains/{grid}/{op.name}" if op.scope == "domain"
                         else f"/v1/{op.name}")
    assert len(paths) >= 11
    return paths


BAD = [
    (b'{"mu0": "\xff\xfe"}', "application/json", 422, "invalid_json"),  # invalid UTF-8
    (b"[" * 100_000 + b"]" * 100_000, "application/json", 400, "invalid_json"),  # 100k deep
    (b'{"mu0": [1, 2,', "application/json", 422, "invalid_json"),  # truncated
    (b"", "application/json", 422, "invalid_input"),  # empty (as on /v1/domains)
    (b'--x\r\nContent-Disposition: form-data; name="mu0"\r\n\r\n1\r\n--x--\r\n',
     "multipart/form-data; boundary=x", 422, "invalid_json"),
]


@pytest.mark.parametrize("body,ctype,status,code", BAD)
def test_malformed_bodies_are_invalid_json_on_every_operation_route(client, grid, body, ctype,
                                                                    status, code):
    for path in _routes(client, grid):
        r = client.post(path, content=body, headers={"content-type": ctype})
        assert_error(r, status, "body", code)


def test_large_operation_body_is_parsed_in_a_child_process(client, grid, monkeypatch):
    """Above ``IN_PROCESS_BYTES`` the JSON is parsed in the parser process; the job sees the
    same numbers (ints and floats) as when parsed in place."""
    monkeypatch.setattr(bodies, "IN_PROCESS_BYTES", 64)
    bodies._discard_pool()
    body = {"mu0": [1.0] * 81, "mu1": [0] * 80 + [3], "method": "exact"}
    r = client.post(f"/v1/domains/{grid}/distances", json=body)
    assert r.status_code == 200, r.text
    assert bodies.PARSER.active  # the parser process was used
    status, obj = bodies.compact_json(r.request.content)
    assert status == "ok" and bodies.expand_json(obj) == body
    assert [type(x) for x in bodies.expand_json(obj)["mu1"][-2:]] == [int, int]
    job = client.get(f"/v1/jobs/{r.json()['id']}").json()
    assert job["state"] == "succeeded", job
    bad = client.post(f"/v1/domains/{grid}/distances", content=b'{"mu0": [' + b"1," * 100,
                      headers={"content-type": "application/json"})
    assert_error(bad, 422, "body", "invalid_json")
