"""Real ids for fuzzed requests (import as ``from fuzz_ids import ...``): the fuzzers
(tests/service/test_fuzz.py in process, tests/service/test_schemathesis.py through
``st run`` and its hooks, schemathesis_hooks.py) generate well-formed but unknown domain
ids in the bodies of the global operations (soft maps, soft-map analyses, shape
interpolations), which stop at 404 before validation. These helpers put stored meshes in
their place, so the cases reach the operations' validation and solvers."""

from __future__ import annotations

import re

import numpy as np

DOMAIN_ID = re.compile(r"^[0-9a-f]{16,64}$")  # service.store: a content hash
# body fields naming a stored mesh, and the list fields of them
MESH_FIELDS = ("source_id", "target_id")
MESH_LIST_FIELDS = ("shapes",)


def meshes() -> list[dict]:
    """Two small closed meshes of one component (soft maps need two meshes, shape
    interpolations closed ones): an icosphere and a box, as JSON domain bodies."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=1)
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4)).subdivide().subdivide()
    return [{"kind": "mesh", "vertices": m.vertices.tolist(), "faces": m.faces.tolist()}
            for m in (sphere, box)]


def domain_bodies() -> dict[str, dict]:
    """A small domain of every kind (and a second mesh), as JSON bodies by name."""
    sphere, box = meshes()
    pts = np.random.default_rng(0).normal(size=(40, 3))
    return {
        "mesh": sphere,
        "box": box,
        "grid": {"kind": "grid", "shape": [6, 6]},
        "graph": {"kind": "graph", "n_nodes": 8, "edges": [[i, i + 1] for i in range(7)]},
        "pointcloud": {"kind": "pointcloud", "n_neighbors": 8,
                       "points": (pts / np.linalg.norm(pts, axis=1)[:, None]).tolist()},
    }


# A quick BRDF interpolation (coarse hemisphere, loose tolerance: well within a 2 s time limit
# on a loaded machine), the finished job with files and 2-D arrays the fuzzers read
QUICK_BRDF = {"materials": [{"model": "blinn-phong", "exponent": 20.0},
                            {"model": "blinn-phong", "exponent": 5.0, "ks": 0.6, "kd": 0.4}],
              "rows": 1, "cols": 3, "incoming_theta": [30.0], "n_theta": 6, "n_phi": 16,
              "tol": 1e-2}


def with_mesh_ids(body, mesh_ids: list[str], salt: int = 0):
    """``body`` with every well-formed domain id of a mesh field (``source_id``,
    ``target_id``, the items of ``shapes``, in nested objects too: ``maps[i].source_id``)
    replaced by one of ``mesh_ids`` (chosen by position and ``salt``). A malformed value
    stays, so a case generated to break the schema still breaks it."""
    if isinstance(body, list):  # scalars as they are: no call per number of a mesh's array
        return [with_mesh_ids(v, mesh_ids, salt + i) if isinstance(v, (dict, list)) else v
                for i, v in enumerate(body)]
    if not isinstance(body, dict):
        return body
    out = {}
    for i, (key, value) in enumerate(body.items()):
        if key in MESH_FIELDS and _well_formed(value):
            out[key] = mesh_ids[(salt + i) % len(mesh_ids)]
        elif key in MESH_LIST_FIELDS and isinstance(value, list):
            out[key] = [mesh_ids[(salt + j) % len(mesh_ids)] if _well_formed(v) else v
                        for j, v in enumerate(value)]
        else:
            out[key] = with_mesh_ids(value, mesh_ids, salt + i)
    return out


def _well_formed(value) -> bool:
    return isinstance(value, str) and DOMAIN_ID.match(value) is not None
