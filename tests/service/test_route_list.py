"""The README's route list and the OpenAPI description are generated from the app's route
table (service.api.routelist): every route the app serves is named in both, and the README's
block is the current one (`otgeo routes --update README.md` rewrites it)."""

from __future__ import annotations

import importlib
import importlib.util
import json
import re
from pathlib import Path

from fastapi import APIRouter

from service.api.routelist import block_in, readme_block, route_docs, update_file
from service.app import create_app
from service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = [ROOT / "README.md"]  # files holding the generated block


def make_app(tmp_path, *extra_routers):
    app = create_app(Settings(data_dir=tmp_path, queue="immediate"), start_background=False)
    for router in extra_routers:
        app.include_router(router)
    return app


def schema_operations(schema: dict) -> set[tuple[str, str]]:
    return {(method.upper(), path) for path, methods in schema["paths"].items()
            for method in methods}


def test_readme_route_list_is_current(tmp_path):
    app = make_app(tmp_path)
    for doc in DOCUMENTS:
        assert block_in(doc.read_text()) == readme_block(app), (
            f"{doc.name}'s route list is stale: run `otgeo routes --update {doc.name}`")


def test_every_route_is_listed_in_the_readme_and_the_description(tmp_path):
    app = make_app(tmp_path)
    schema = app.openapi()
    listed = {(r.method, r.path) for r in route_docs(app)}
    assert schema_operations(schema) <= listed
    # pages, docs and static files are served too and listed (outside the OpenAPI paths)
    assert {("GET", "/"), ("GET", "/viewer"), ("GET", "/docs"), ("GET", "/redoc"),
            ("GET", "/openapi.json"), ("GET", "/static/{path}")} <= listed
    readme = block_in((ROOT / "README.md").read_text())
    description = schema["info"]["description"]
    for method, path in listed:
        assert f"`{method} {path}`" in readme, (method, path)
    for method, path in schema_operations(schema):
        assert f"`{method} {path}`" in description, (method, path)
    for ops in schema["paths"].values():
        for op in ops.values():
            assert f"(`{op['operationId']}`)" in description
    # each line of the description says what the route does (never empty)
    assert not re.search(r"`: *$", description, re.M)


def test_every_operation_links_its_guide_page(tmp_path):
    """Each operation names the guide page that explains it (README table, ``x-guide`` in
    the OpenAPI document for the viewer), and that page exists."""
    app = make_app(tmp_path)
    for path, methods in app.openapi()["paths"].items():
        for op in methods.values():
            if "operations" in op.get("tags", []):
                page = op.get("x-guide", "")
                assert page.startswith("/guide/guide/"), (path, page)
                rst = ROOT / "docs" / page.removeprefix("/guide/").replace(".html", ".rst")
                assert rst.exists(), (path, rst)
                assert f"({rst.relative_to(ROOT)})" in block_in((ROOT / "README.md").read_text())
                module, _, name = op["x-function"].rpartition(".")
                assert callable(getattr(importlib.import_module(module), name, None)) or \
                    importlib.util.find_spec(op["x-function"]), op["x-function"]
                assert op["x-thesis"], path


def test_a_new_route_appears_in_both_without_editing_them(tmp_path):
    """A route added to the app is listed at once (the lists are not written by hand)."""
    extra = APIRouter(prefix="/v1", tags=["extras"])

    @extra.get("/extras/{x}", operation_id="getExtra")
    def get_extra(x: str):
        """An extra route for this test. Not more."""
        return {"x": x}

    app = make_app(tmp_path, extra)
    line = "- `GET /v1/extras/{x}` (`getExtra`): An extra route for this test"
    assert line in app.openapi()["info"]["description"]
    doc = tmp_path / "doc.md"
    doc.write_text((ROOT / "README.md").read_text())
    assert update_file(doc, app) and "`GET /v1/extras/{x}`" in block_in(doc.read_text())
    assert not update_file(doc, app)  # idempotent


def test_checked_in_openapi_description_lists_every_operation():
    doc = json.loads((ROOT / "openapi" / "openapi.json").read_text())
    for method, path in schema_operations(doc):
        assert f"`{method} {path}`" in doc["info"]["description"], (method, path)
