"""Domain uploads: parse, enforce limits, build, store (content addressed)."""

from __future__ import annotations

import os

import numpy as np

from service.errors import InvalidInput, PayloadTooLarge
from service.runtime import Runtime
from service.schemas import GraphSpec, GridSpec, MeshSpec, PointCloudSpec
from solvers.domains import MESH_FORMATS, Graph, Grid, PointCloud, TriangleMesh, load_mesh


class DomainService:
    def __init__(self, runtime: Runtime):
        self.rt = runtime
        self.settings = runtime.settings

    def _check_points(self, n: int, field: str) -> None:
        if n > self.settings.max_vertices:
            raise PayloadTooLarge(f"{n} points exceed the limit of {self.settings.max_vertices}",
                                  field=field)

    def from_file(self, data: bytes, filename: str | None, file_type: str | None,
                  laplacian: str = "robust") -> tuple[dict, bool]:
        if not data:
            raise InvalidInput("the uploaded file is empty", field="file")
        ext = (file_type or os.path.splitext(filename or "")[1]).lower().lstrip(".")
        if not ext:
            raise InvalidInput("cannot tell the mesh format: give a file name with an extension "
                               f"or a 'format' field ({', '.join(MESH_FORMATS)})", field="format")
        if ext not in MESH_FORMATS:
            raise InvalidInput(f"unsupported mesh format {ext!r}; expected one of "
                               f"{', '.join(MESH_FORMATS)}", field="format")
        if laplacian not in ("robust", "cotan"):
            raise InvalidInput("laplacian must be 'robust' or 'cotan'", field="laplacian")
        mesh = load_mesh(data, file_type=ext, laplacian=laplacian)
        self._check_points(mesh.n, "file")
        source = {"filename": filename, "format": ext, "bytes": len(data)}
        return self.rt.store.put_domain(mesh, source)

    def from_spec(self, spec) -> tuple[dict, bool]:
        if isinstance(spec, GridSpec):
            self._check_points(int(np.prod([max(s, 0) for s in spec.shape])), "shape")
            domain = Grid(spec.shape, spec.bounds, spec.periodic)
        elif isinstance(spec, GraphSpec):
            self._check_points(spec.n_nodes, "n_nodes")
            domain = Graph(spec.n_nodes, _array(spec.edges, "edges", np.int64),
                           spec.weights, spec.positions)
        elif isinstance(spec, PointCloudSpec):
            self._check_points(len(spec.points), "points")
            domain = PointCloud(_array(spec.points, "points"), n_neighbors=spec.n_neighbors)
        elif isinstance(spec, MeshSpec):
            self._check_points(len(spec.vertices), "vertices")
            domain = TriangleMesh(_array(spec.vertices, "vertices"),
                                  _array(spec.faces, "faces", np.int64), laplacian=spec.laplacian)
        else:  # pragma: no cover - the request model is a closed union
            raise InvalidInput("unknown domain kind", field="kind")
        return self.rt.store.put_domain(domain, {"format": "json"})

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
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f"{field} must be a rectangular numeric array: {exc}",
                           field=field) from exc
    if arr.ndim != 2:
        raise InvalidInput(f"{field} must be a list of equal-length rows", field=field)
    return arr

