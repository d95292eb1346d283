"""The OpenAPI document states the constraints the server enforces that JSON Schema can say
(so schemathesis' schema-valid requests are accepted, tests/service/test_schemathesis.py):
rules between fields (``if``/``then``), the form of domain ids in bodies, cursors (any
position of the pattern is a page) and row indices."""

from __future__ import annotations

import pytest
from service_testing import assert_error

from service.api.paging import decode_cursor, encode_cursor
from service.operations import build_registry

jsonschema_rs = pytest.importorskip("jsonschema_rs")

OPERATIONS = build_registry()
GRID = {"kind": "grid", "shape": [6, 6]}
MU = {"mu0": {"vertex": 0, "radius": 0.3}, "mu1": {"vertex": 20, "radius": 0.3}}
MATERIAL = {"model": "blinn-phong", "exponent": 10.0}


def valid(op_name: str, body: dict) -> bool:
    schema = OPERATIONS[op_name].request_model.model_json_schema()
    return jsonschema_rs.validator_for(schema).is_valid(body)


# (operation, a body the spec refuses by a rule, the field the server names, the body
# changed to follow the rule)
RULES = [
    ("brdf-interpolations", {"materials": [MATERIAL] * 3, "rows": 1, "cols": 2}, "weights",
     {"weights": [[0.5, 0.5, 0.0], [0.0, 0.5, 0.5]]}),
    ("anisotropic-distances", {**MU, "curvature": {}, "method": "admm",
                               "basis": "spectral"}, "k", {"k": 4}),
    ("anisotropic-distances", {**MU, "curvature": {}, "method": "ipm", "basis": "full"},
     "basis", {"basis": "flow"}),
]


@pytest.mark.parametrize("op_name, body, field, fix", RULES,
                         ids=[f"{r[0]}-{r[2]}" for r in RULES])
def test_rules_between_fields_are_in_the_spec(client, op_name, body, field, fix):
    assert not valid(op_name, body)
    assert valid(op_name, {**body, **fix})
    op = OPERATIONS[op_name]
    if op.scope == "domain":
        domain = client.post("/v1/domains", json={"kind": "mesh", **_tetrahedron()}).json()
        url = f"/v1/domains/{domain['id']}/{op_name}"
    else:
        url = f"/v1/{op_name}"
    assert_error(client.post(url, json=body), 422, field)


def _tetrahedron() -> dict:
    return {"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
            "faces": [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]}


@pytest.mark.parametrize("op_name, body, field", [
    ("soft-maps", {"source_id": "not-an-id", "target_id": "0" * 32,
                   "landmarks": [{"source": 0, "target": 0}]}, "source_id"),
    ("shape-interpolations", {"shapes": ["0" * 32, "ZZ"]}, "shapes"),
])
def test_domain_ids_in_bodies_have_their_form_in_the_spec(client, op_name, body, field):
    assert not valid(op_name, body)
    assert_error(client.post(f"/v1/{op_name}", json=body), 422, field)
    well_formed = {k: ("0" * 32 if k == "source_id" else ["0" * 32, "1" * 32])
                   if k in ("source_id", "shapes") else v for k, v in body.items()}
    assert valid(op_name, well_formed)
    assert client.post(f"/v1/{op_name}", json=well_formed).status_code == 404


def test_every_cursor_of_the_pattern_is_a_page(client):
    ids = [client.post("/v1/domains", json={"kind": "grid", "shape": [4, 4 + i]}).json()["id"]
           for i in range(3)]
    first = client.get("/v1/domains", params={"limit": 1}).json()
    assert [d["id"] for d in first["domains"]] == ids[:1]
    rest = client.get("/v1/domains", params={"cursor": first["next_cursor"]}).json()
    assert [d["id"] for d in rest["domains"]] == ids[1:]
    for cursor in ("0~0", "99999999999999999999.5~zz_-", "1.25~" + "f" * 64):
        for listing in ("/v1/domains", "/v1/jobs"):
            assert client.get(listing, params={"cursor": cursor}).status_code == 200
    assert client.get("/v1/domains", params={"cursor": "0~0"}).json()["domains"] != []
    for bad in ("nonsense!", "1e5~a", "~a", "1.5~", "1.5~a/b"):
        assert_error(client.get("/v1/jobs", params={"cursor": bad}), 422, "cursor")


@pytest.mark.parametrize("created", [1733580000.1234567, 0.0, 1e-05, 123.0])
def test_cursors_keep_the_exact_sort_key(created):
    assert decode_cursor(encode_cursor(created, "abc")) == (created, "abc")


def test_row_indices_are_non_negative_in_the_spec(client):
    import json

    from service.cli import openapi_document
    doc = json.loads(openapi_document())
    params = doc["paths"]["/v1/jobs/{job_id}/arrays/{name}/rows/{row}"]["get"]["parameters"]
    assert next(p for p in params if p["name"] == "row")["schema"]["minimum"] == 0
    assert_error(client.get("/v1/jobs/abc/arrays/x/rows/-1"), 422, "row")


@pytest.mark.parametrize("material, field", [
    ({"model": "blinn-phong", "ks": 0}, "materials[1]"),
    ({"model": "blinn-phong", "ks": 0.0, "kd": 0}, "materials[1]"),
    ({"model": "ashikhmin-shirley", "rs": 0}, "materials[1]"),
])
def test_a_material_reflecting_no_light_is_outside_the_spec(client, material, field):
    body = {"materials": [MATERIAL, material], "rows": 1, "cols": 2}
    assert not valid("brdf-interpolations", body)
    assert_error(client.post("/v1/brdf-interpolations", json=body), 422, field)
    lit = dict(material, **({"kd": 0.5} if material["model"] == "blinn-phong" else {"rd": 0.5}))
    assert valid("brdf-interpolations", {**body, "materials": [MATERIAL, lit]})


def test_domain_path_ids_are_one_url_segment_in_the_spec(client):
    """'.' and '..' vanish in a client's URL normalization (DELETE /v1/domains/. reached
    /v1/domains/, a 405); any other unknown id stays a 404."""
    import json
    import re

    from service.cli import openapi_document

    doc = json.loads(openapi_document())
    for method in ("get", "delete"):
        params = doc["paths"]["/v1/domains/{domain_id}"][method]["parameters"]
        pattern = next(p for p in params if p["name"] == "domain_id")["schema"]["pattern"]
        assert [v for v in (".", "..", "", "a/b") if re.match(pattern, v)] == []
        assert all(re.match(pattern, v) for v in ("not-an-id", "...", "0" * 32))
    assert_error(client.delete("/v1/domains/not-an-id"), 404, "domain_id")


def test_shape_interpolation_times_take_two_shapes_and_no_weights(client):
    mesh = client.post("/v1/domains", json={"kind": "mesh", **_tetrahedron()}).json()["id"]
    for body, field in (({"shapes": [mesh] * 3, "times": [0.5]}, "times"),
                        ({"shapes": [mesh] * 2, "times": [0.5], "weights": [[1, 1]]},
                         "weights")):
        assert not valid("shape-interpolations", body)
        assert_error(client.post("/v1/shape-interpolations", json=body), 422, field)
    assert valid("shape-interpolations", {"shapes": [mesh] * 3, "weights": [[1, 1, 1]]})
    assert valid("shape-interpolations", {"shapes": [mesh] * 2, "times": [0.5]})
