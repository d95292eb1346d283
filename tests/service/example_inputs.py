"""Inputs for running every operation from its OpenAPI request example (import as ``from
example_inputs import ...``): a small closed mesh, two small images, and the substitution of
the examples' placeholder ids (``EXAMPLE_ID``) by stored domain and blob ids."""

from __future__ import annotations

import io
from functools import cache

import numpy as np

from service.operations.examples import EXAMPLE_ID


@cache
def sphere_obj() -> bytes:
    """An icosphere (642 vertices, closed, genus 0) as OBJ: every domain operation accepts it
    (skeleton layouts need a closed surface) and it is small enough for quick jobs."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3)
    return trimesh.exchange.obj.export_obj(sphere).encode()


@cache
def png_images() -> tuple[bytes, bytes]:
    """Two 24 x 16 PNG images of different colors (a color transfer's inputs)."""
    from PIL import Image

    y, x = np.mgrid[0:16, 0:24]
    warm = np.stack([200 + 0 * x, 60 + 4 * x, 40 + 6 * y], -1).astype(np.uint8)
    cool = np.stack([30 + 0 * x, 80 + 6 * y, 120 + 4 * x], -1).astype(np.uint8)
    out = []
    for img in (warm, cool):
        buf = io.BytesIO()
        Image.fromarray(img).save(buf, format="PNG")
        out.append(buf.getvalue())
    return tuple(out)


def names_blobs(field: str) -> bool:
    """Fields whose placeholder ids stand for uploaded blobs (images), not domains."""
    return "image" in field or "blob" in field


SPHERE_VERTICES = 642  # of sphere_obj(), the mesh every example runs on


def substitute_ids(example, domain_id: str, blob_ids: list[str] | None = None, field: str = ""):
    """``example`` with every ``EXAMPLE_ID`` replaced: by the i-th of ``blob_ids`` in a list
    field naming blobs (``images``), by ``domain_id`` elsewhere (``source_id``, ...). A point
    map (``correspondence``, one target vertex per source vertex) becomes the identity of the
    sphere the examples run on, since the example's stands for a mesh of its own length."""
    if field == "correspondence" and isinstance(example, list):
        return list(range(SPHERE_VERTICES))
    if isinstance(example, dict):
        return {k: substitute_ids(v, domain_id, blob_ids, k) for k, v in example.items()}
    if isinstance(example, list):
        if names_blobs(field):
            assert blob_ids and len(blob_ids) >= len(example), f"{field} needs uploaded blobs"
            return [blob_ids[i] if v == EXAMPLE_ID else v for i, v in enumerate(example)]
        return [substitute_ids(v, domain_id, blob_ids, field) for v in example]
    if example == EXAMPLE_ID:
        assert not names_blobs(field), f"{field} needs an uploaded blob"
        return domain_id
    return example


def schema_example(schema: dict) -> dict:
    """The first OpenAPI example of a request schema; fails naming the schema without one."""
    examples = schema.get("examples") or []
    assert examples, f"request schema {schema.get('title')!r} has no example (json_schema_extra)"
    return examples[0]


def at_defaults(schema: dict, accepts=None) -> dict:
    """The request's example reduced to its required fields: every size at its default. When
    the required fields alone are refused (one of several fields must be given, e.g.
    ``face_weights`` or ``curvature``), the example's other fields are dropped one at a time
    while ``accepts(body)`` (validation at submission) still holds."""
    example = schema_example(schema)
    required = {k: v for k, v in example.items() if k in schema.get("required", [])}
    if accepts is None or accepts(required):
        return required
    body = dict(example)
    for key in [k for k in example if k not in required]:
        trial = {k: v for k, v in body.items() if k != key}
        if accepts(trial):
            body = trial
    return body
