"""The schemas an OpenAPI document's parts reference (``$ref``), for tests that walk it."""

from __future__ import annotations


def schema_refs(node):
    """Names of the component schemas ``node`` (any part of the document) references
    directly, in document order."""
    if isinstance(node, dict):
        if "$ref" in node:
            yield node["$ref"].rsplit("/", 1)[-1]
        for value in node.values():
            yield from schema_refs(value)
    elif isinstance(node, list):
        for value in node:
            yield from schema_refs(value)


def referenced(schemas: dict, names: set[str]) -> set[str]:
    """``names`` and every schema they reference, transitively."""
    todo, out = list(names), set(names)
    while todo:
        for name in schema_refs(schemas[todo.pop()]):
            if name not in out:
                out.add(name)
                todo.append(name)
    return out
