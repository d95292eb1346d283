"""Domain uploads: parse, enforce limits, build, store (content addressed).

Sizes are checked against ``max_vertices`` before anything is allocated (grid sizes as
Python integers, so a shape whose product wraps int64 cannot slip through), and every
array goes through the library's own validators (``solvers.validation``), so a hostile
upload gets a 4xx naming its field, never a server error.
"""

from __future__ import annotations

import os

import numpy as np

from service.errors import InvalidInput, PayloadTooLarge
from service.runtime import Runtime
from service.schemas import GraphSpec, GridSpec, MeshSpec, PointCloudSpec
from solvers.domains import MESH_FORMATS, Graph, Grid, PointCloud, TriangleMesh, load_mesh
from solvers.errors import InputError
from solvers.validation import check_size

WELD_VALUES = {"true": True, "1": True, "yes": True, "false": False, "0": False, "no": False,
               "auto": None, "": None}


def parse_weld(value) -> bool | None:
    """The ``weld`` form field of a mesh upload: true/false, or auto (the format's default:
    PLY/OFF/STL/glTF welded by position, OBJ by its position indices)."""
    if value is None or isinstance(value, bool):
        return value
    key = str(value).strip().lower()
    if key not in WELD_VALUES:
        raise InvalidInput(f"weld must be true, false or auto, got {str(value)[:20]!r}",
                           field="weld")
    return WELD_VALUES[key]


class DomainService:
    def __init__(self, runtime: Runtime):
        self.rt = runtime
        self.settings = runtime.settings

    def _check_points(self, n: int, field: str) -> None:
        if n > self.settings.max_vertices:
            raise PayloadTooLarge(f"{n} points exceed the limit of {self.settings.max_vertices}",
                                  field=field)

    def from_file(self, data: bytes, filename: str | None, file_type: str | None,
                  laplacian: str = "robust", weld: bool | str | None = None
                  ) -> tuple[dict, bool]:
        """Store an uploaded mesh file. ``weld``: merge vertices at equal positions (seams);
        None/"auto": the format's default (see ``solvers.domains.mesh``)."""
        if not data:
            raise InvalidInput("the uploaded file is empty", field="file")
        ext = (file_type or os.path.splitext(filename or "")[1]).lower().lstrip(".")
        if not ext:
            raise InvalidInput("cannot tell the mesh format: give a file name with an extension "
                               f"or a 'format' field ({', '.join(MESH_FORMATS)})", field="format")
        if ext not in MESH_FORMATS:
            raise InvalidInput(f"unsupported mesh format {ext[:20]!r}; expected one of "
                               f"{', '.join(MESH_FORMATS)}", field="format")
        if laplacian not in ("robust", "cotan"):
            raise InvalidInput("laplacian must be 'robust' or 'cotan'", field="laplacian")
        weld = parse_weld(weld)
        mesh = load_mesh(data, file_type=ext, laplacian=laplacian, weld=weld)
        self._check_points(mesh.n, "file")
        source = {"filename": filename, "format": ext, "bytes": len(data)}
        if weld is not None:
            source["weld"] = weld
        return self._put(mesh, source)

    def from_spec(self, spec) -> tuple[dict, bool]:
        if isinstance(spec, GridSpec):
            try:
                check_size(spec.shape, self.settings.max_vertices, "shape")
            except InputError as exc:
                raise PayloadTooLarge(exc.message, field="shape") from exc
            domain = Grid(spec.shape, spec.bounds, spec.periodic)
        elif isinstance(spec, GraphSpec):
            self._check_points(spec.n_nodes, "n_nodes")
            domain = Graph(spec.n_nodes, spec.edges, spec.weights, spec.positions)
        elif isinstance(spec, PointCloudSpec):
            self._check_points(len(spec.points), "points")
            domain = PointCloud(_array(spec.points, "points"), n_neighbors=spec.n_neighbors)
        elif isinstance(spec, MeshSpec):
            self._check_points(len(spec.vertices), "vertices")
            domain = TriangleMesh(_array(spec.vertices, "vertices"),
                                  _array(spec.faces, "faces", np.int64),
                                  laplacian=spec.laplacian, weld=spec.weld)
        else:  # pragma: no cover - the request model is a closed union
            raise InvalidInput("unknown domain kind", field="kind")
        return self._put(domain, {"format": "json"})

    def _put(self, domain, source: dict) -> tuple[dict, bool]:
        meta, created = self.rt.store.put_domain(domain, source)
        if not created:  # say so, and from which upload the stored domain came
            meta = {**meta, "already_existed": True, "upload": source}
        return meta, created

    def get(self, domain_id: str) -> dict:
        return self.rt.store.get_domain_meta(domain_id)

    def list(self) -> list[dict]:
        return self.rt.store.list_domains()

    def delete(self, domain_id: str) -> None:
        self.rt.store.delete_domain(domain_id)
        self.rt.cache.discard(("domain", domain_id))


def _array(values, field: str, dtype=np.float64) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=dtype)
    except (TypeError, ValueError, OverflowError) as exc:
        kind = "integers" if dtype is np.int64 else "numbers"
        raise InvalidInput(f"{field} must be a list of equal-length rows of {kind} (within "
                           "int64 for indices)", field=field) from exc
    if arr.ndim != 2:
        raise InvalidInput(f"{field} must be a list of equal-length rows", field=field)
    return arr
