"""The OpenAPI document as the server behaves: FastAPI's output adjusted where it cannot say
what the app does (one error shape, binary uploads, the API key's actual requirement, bounds
that come from the settings). ``as_served(schema, settings)`` applies them all."""

from __future__ import annotations

from service.settings import Settings


def as_served(schema: dict, settings: Settings) -> None:
    _errors_everywhere(schema)
    _key_requirements(schema, settings)
    _wait_bounds(schema, settings.wait_max)
    _binary_uploads(schema)
    _constraint_names(schema)


def _errors_everywhere(schema: dict) -> None:
    """Request validation errors use the one error shape too (not FastAPI's default)."""
    ref = {"$ref": "#/components/schemas/ErrorResponse"}
    for methods in schema.get("paths", {}).values():
        for op in methods.values():
            resp = op.get("responses", {}).get("422")
            if resp is not None:
                resp["content"] = {"application/json": {"schema": ref}}
                if resp.get("description") == "Validation Error":
                    resp["description"] = "invalid input (the field is named)"
    for name in ("HTTPValidationError", "ValidationError"):
        schema["components"]["schemas"].pop(name, None)


def _key_requirements(schema: dict, settings: Settings) -> None:
    """Declare the ``X-API-Key`` requirement as the server enforces it: required when keys are
    configured, optional (``security: [{}, ...]``) when they are not (the header is then
    ignored), and optional on ``/metrics`` when OTGEO_METRICS_OPEN."""
    for path, methods in schema.get("paths", {}).items():
        open_path = not settings.api_keys or (path == "/metrics" and settings.metrics_open)
        for op in methods.values():
            security = op.get("security")
            if security and open_path and {} not in security:
                op["security"] = [{}, *security]


def _binary_uploads(node) -> None:
    """File fields as ``{"type": "string", "format": "binary"}``, which SDK generators read as
    files (FastAPI writes OpenAPI 3.1's ``contentMediaType``: openapi-python-client then types
    the field as text and sends no file)."""
    if isinstance(node, dict):
        if node.get("type") == "string" and "contentMediaType" in node:
            del node["contentMediaType"]
            node["format"] = "binary"
        for value in node.values():
            _binary_uploads(value)
    elif isinstance(node, list):
        for value in node:
            _binary_uploads(value)


def _wait_bounds(schema: dict, wait_max: float) -> None:
    """``?wait=`` is at most OTGEO_WAIT_MAX seconds (a larger one gets 422 naming it)."""
    for methods in schema.get("paths", {}).values():
        for op in methods.values():
            for param in op.get("parameters", []):
                if param.get("name") == "wait" and param.get("in") == "query":
                    param["schema"]["maximum"] = wait_max


CONSTRAINTS = {"ge": "minimum", "le": "maximum", "gt": "exclusiveMinimum",
               "lt": "exclusiveMaximum"}


def _constraint_names(node) -> None:
    """JSON Schema names for the bounds of an optional request integer: pydantic writes
    ``Field(ge=1)`` on ``Int | None`` (service.schemas.Int, an int with a before-validator)
    as ``{"ge": 1}``, which no client reads."""
    if isinstance(node, dict):
        if node.get("type") == "integer":
            for name, json_name in CONSTRAINTS.items():
                if name in node:
                    node[json_name] = node.pop(name)
        for value in node.values():
            _constraint_names(value)
    elif isinstance(node, list):
        for value in node:
            _constraint_names(value)
