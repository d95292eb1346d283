"""One vocabulary (issue 41): every parameter of a public library signature (the names in
``__all__`` of the ``solvers`` packages: functions, public methods, constructors of classes
that are not result records) and every field of an HTTP request model (the request bodies
of the app's OpenAPI document, nested models included) is a name of the table in
``docs/guide/vocabulary.csv`` (rendered by ``docs/guide/vocabulary.rst``), which says what
it means and where it is used.

The table is the data: a new name fails here until it has a row (and a meaning), a name no
longer used fails until its row goes, and the ``where`` column is checked against the code.
Rewrite that column (meanings kept, new names added with an empty meaning to fill in) with
``python tests/test_vocabulary.py --update``.
"""

from __future__ import annotations

import csv
import dataclasses
import importlib
import inspect
import json
import pkgutil
import sys
from collections import defaultdict
from pathlib import Path

from spec_refs import schema_refs

ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / "docs" / "guide" / "vocabulary.csv"
HEADER = ("name", "meaning", "where")


def _parameters(obj) -> list[str]:
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):
        return []
    return [p.name for p in sig.parameters.values() if p.name not in ("self", "cls")
            and not p.name.startswith("_")  # private keywords of public functions
            and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]


def library_names() -> dict[str, set[str]]:
    """``name -> packages`` of every parameter of a public signature of ``solvers``."""
    import solvers

    names: dict[str, set[str]] = defaultdict(set)
    packages = ["solvers"] + [f"solvers.{m.name}" for m in pkgutil.iter_modules(solvers.__path__)
                              if m.ispkg]
    for package in packages:
        module = importlib.import_module(package)
        for public in getattr(module, "__all__", []):
            obj = getattr(module, public)
            signatures = []
            if inspect.isclass(obj):
                if not dataclasses.is_dataclass(obj):  # result records are outputs
                    signatures.append(obj)
                signatures += [m for n, m in inspect.getmembers(obj, inspect.isfunction)
                               if not n.startswith("_")
                               and m.__qualname__.startswith(obj.__name__ + ".")]
            elif inspect.isfunction(obj):
                signatures.append(obj)
            for sig in signatures:
                for name in _parameters(sig):
                    names[name].add(package)
    return names


def http_names(spec: dict | None = None) -> dict[str, set[str]]:
    """``name -> operations`` (the last segment of the POST path) of every field of a request
    body's model, nested models included."""
    if spec is None:
        from service.cli import openapi_document

        spec = json.loads(openapi_document())
    schemas = spec["components"]["schemas"]
    names: dict[str, set[str]] = defaultdict(set)
    for path, item in spec["paths"].items():
        if "post" not in item:
            continue
        operation = path.rstrip("/").rsplit("/", 1)[-1]
        todo, seen = list(schema_refs(item["post"].get("requestBody", {}))), set()
        while todo:
            model = todo.pop()
            if model in seen:
                continue
            seen.add(model)
            schema = schemas[model]
            for part in [schema, *schema.get("allOf", [])]:
                for field, sub in part.get("properties", {}).items():
                    names[field].add(operation)
                    todo.extend(schema_refs(sub))
    return names


def used_where() -> dict[str, str]:
    """``name -> where`` as the table's ``where`` column states it."""
    lib, http = library_names(), http_names()
    where = {}
    for name in sorted(set(lib) | set(http)):
        parts = []
        if name in lib:
            parts.append("library: " + ", ".join(sorted(lib[name])))
        if name in http:
            parts.append("HTTP: " + ", ".join(sorted(http[name])))
        where[name] = "; ".join(parts)
    return where


def read_table(path: Path = TABLE) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    return rows


def write_table(rows: list[dict[str, str]], path: Path = TABLE) -> None:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, HEADER, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


def test_the_table_has_one_row_per_name_and_every_row_a_meaning():
    rows = read_table()
    assert tuple(rows[0]) == HEADER
    names = [r["name"] for r in rows]
    assert names == sorted(set(names)), "one row per name, sorted"
    assert all(r["meaning"].strip() for r in rows), [r["name"] for r in rows
                                                     if not r["meaning"].strip()]


def test_every_public_parameter_and_request_field_is_in_the_table():
    table = {r["name"] for r in read_table()}
    where = used_where()
    missing = sorted(set(where) - table)
    assert not missing, (f"names outside docs/guide/vocabulary.csv: {missing}; use a name of "
                         "the table, or add a row (python tests/test_vocabulary.py --update)")
    stale = sorted(table - set(where))
    assert not stale, f"rows of names no longer used: {stale}"


def test_the_where_column_is_current():
    where = used_where()
    wrong = {r["name"]: (r["where"], where.get(r["name"])) for r in read_table()
             if r["where"] != where.get(r["name"])}
    assert not wrong, f"stale where column (python tests/test_vocabulary.py --update): {wrong}"


def test_old_names_of_an_algorithm_choice_are_gone():
    """``method`` is the algorithm choice: no ``route``/``algorithm``/``solver`` parameter or
    field (``route`` names HTTP routes only, which are no parameters of these)."""
    where = used_where()
    old = sorted(n for n in where if n in ("route", "algorithm", "solver")
                 or n.endswith(("_route", "_algorithm", "_solver")))
    assert not old, old


def test_the_checks_fail_on_a_name_outside_the_table(tmp_path):
    """The comparison itself: a request model with an unknown field is reported."""
    spec = {"paths": {"/v1/things": {"post": {"requestBody": {"content": {"application/json": {
        "schema": {"$ref": "#/components/schemas/Thing"}}}}}}},
        "components": {"schemas": {"Thing": {"properties": {"route": {}, "gamma": {}}}}}}
    assert dict(http_names(spec)) == {"route": {"things"}, "gamma": {"things"}}
    table = {r["name"] for r in read_table()}
    assert set(http_names(spec)) - table == {"route"}


def _update() -> None:
    where = used_where()
    meanings = {r["name"]: r["meaning"] for r in read_table()} if TABLE.exists() else {}
    write_table([{"name": n, "meaning": meanings.get(n, ""), "where": w}
                 for n, w in where.items()])
    empty = [n for n in where if not meanings.get(n)]
    print(f"wrote {TABLE} ({len(where)} names; without a meaning: {empty})")


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    if sys.argv[1:] == ["--update"]:
        _update()
    else:
        sys.exit("usage: python tests/test_vocabulary.py --update")
