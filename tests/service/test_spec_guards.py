"""Guards on the OpenAPI document that keep generated SDKs whole: schema names and titles are
unique (generators make one class per title: two models named ``FixedNode`` made
openapi-python-client drop ``createPropagationJob``), and every request body has an example
that the operation accepts (the docs show it; tests/service/test_sdk.py runs it)."""

from __future__ import annotations

import json
import re

import pytest
from pydantic import BaseModel, TypeAdapter

from service.cli import openapi_document
from service.operations import build_registry
from service.schemas import DomainSpec


def duplicate_schema_names(doc: dict) -> list[str]:
    """Problems with the document's schema names: module-qualified keys (FastAPI's way out
    when two models share a class name) and keys or titles that collide once reduced to the
    letters and digits a generator keeps (case-insensitive)."""
    problems, owner = [], {}
    for key, schema in doc.get("components", {}).get("schemas", {}).items():
        if "__" in key:
            problems.append(f"{key}: two models share the class name")
        for name in {key, schema.get("title", key)}:
            norm = re.sub(r"[^0-9a-z]", "", name.lower())
            if owner.setdefault(norm, key) != key:
                problems.append(f"{key} and {owner[norm]} are both called {name!r}")
    return problems


@pytest.fixture(scope="module")
def doc():
    return json.loads(openapi_document())


def test_schema_names_and_titles_are_unique(doc):
    assert duplicate_schema_names(doc) == []


def test_the_guard_finds_a_shared_class_name():
    from fastapi import FastAPI

    def node(field: str) -> type[BaseModel]:  # two classes named alike, as in two modules
        return type("FixedNode", (BaseModel,), {"__annotations__": {field: int},
                                                "__module__": f"pkg.{field}"})

    app = FastAPI()
    for field in ("a", "b"):
        def post(body): ...
        post.__annotations__ = {"body": node(field)}  # real types (annotations are strings)
        app.post(f"/{field}")(post)
    assert duplicate_schema_names(app.openapi()) != []
    titled = {"components": {"schemas": {"JobResult": {"title": "Job Result"},
                                         "Other": {"title": "job_result"}}}}
    assert duplicate_schema_names(titled) != []


def _json_bodies(doc):
    for path, methods in doc["paths"].items():
        for method, op in methods.items():
            content = op.get("requestBody", {}).get("content", {})
            if "application/json" in content:
                yield f"{method.upper()} {path}", content["application/json"]["schema"]


def test_every_json_request_body_has_an_example(doc):
    schemas = doc["components"]["schemas"]
    missing = []
    for where, schema in _json_bodies(doc):
        target = schemas[schema["$ref"].split("/")[-1]] if "$ref" in schema else schema
        # a union of models (DomainSpec), or one model (whose oneOf/anyOf, if any, are
        # constraints on its own fields: service.operations.base.given)
        union = [m for m in target.get("oneOf") or target.get("anyOf") or [] if "$ref" in m]
        for member in union or [target]:
            resolved = schemas[member["$ref"].split("/")[-1]] if "$ref" in member else member
            if not resolved.get("examples"):
                missing.append(f"{where}: {resolved.get('title')}")
    assert missing == []


def test_examples_are_valid_requests():
    for op in build_registry().values():
        for example in op.request_model.model_json_schema()["examples"]:
            op.request_model.model_validate(example)  # raises naming the field
    spec = TypeAdapter(DomainSpec)
    for member in DomainSpec.__origin__.__args__:
        for example in member.model_json_schema()["examples"]:
            spec.validate_python(example)


def _form_fields(doc):
    schemas = doc["components"]["schemas"]
    for path, methods in doc["paths"].items():
        for method, op in methods.items():
            for media, content in op.get("requestBody", {}).get("content", {}).items():
                if "form" not in media:
                    continue
                schema = content["schema"]
                schema = schemas[schema["$ref"].split("/")[-1]] if "$ref" in schema else schema
                for name, field in schema.get("properties", {}).items():
                    yield f"{method.upper()} {path} {name}", field


def test_no_form_field_is_nullable(doc):
    """A multipart field is text: a client that sends a spec-valid null writes "null", which
    is not a number (a CI fuzz run sent ``bins=null`` and got a 422). Optional form fields
    are absent, not null."""
    nullable = [where for where, field in _form_fields(doc)
                if field.get("type") == "null"
                or any(m.get("type") == "null" for m in field.get("anyOf", []))]
    assert list(_form_fields(doc)) != []
    assert nullable == []
