"""Triangle meshes: loading, welding, diagnostics and differential operators."""

from __future__ import annotations

import io
import logging
import os
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import robust_laplacian
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from solvers import geodesics
from solvers.domains.base import Domain, ExportGeometry, check_laplacian_name
from solvers.errors import DomainError, InputError, MeshFormatError
from solvers.geodesics import geodesic_distances, mmp_solve_seconds
from solvers.heat_geodesics import all_pairs_heat_distances
from solvers.kernels import (
    GEODESIC_KERNEL_VERTICES,
    GeodesicGaussianKernel,
    ImplicitEulerHeatKernel,
    morton_order,
)
from solvers.linalg import Backend

log = logging.getLogger("otgeo.solvers")

MESH_FORMATS = ("obj", "ply", "stl", "off", "glb", "gltf")
# Formats whose files may store one vertex per (position, attribute) pair or none at all
# (PLY and OFF exports split vertices along UV seams too), so coincident positions are
# welded by default to recover the surface (``weld=False`` keeps the file's vertices).
# OBJ faces keep their position indices (``v`` lines), which already weld UV/normal seams;
# welding OBJ by position as well (``weld=True``) would also fuse separate parts that only
# touch (e.g. suzanne's eyes), so it is not the default there.
POSITION_WELD_FORMATS = ("ply", "off", "stl", "glb", "gltf")

# Relative area below which a face counts as degenerate (fraction of mean face area).
DEGENERATE_AREA_FRACTION = 1e-12
# Meshes up to this many vertices keep their all-pairs exact geodesic matrix (at most
# 128 MB) in the operator store when asked for it (stored_ground_distances: the exact
# distance matrices ask when their supports cover at least half of the vertices), so the
# next matrix on the domain reuses it.
STORED_GEODESICS_VERTICES = 4096
# Key of the all-pairs exact (MMP) geodesics in a domain's artifact store, kept as float32
# (the LP's costs need no more: bench/results/geodesic_artifacts.md measures the change)
GEODESICS_ARTIFACT = "geodesics-mmp-float32"
# n-vectors of one exact geodesic solve's work (MMP frontier and distances, measured ~8 on
# a 642-vertex sphere beside the n x n matrix: tests/service/test_distance_matrices.py)
GEODESIC_WORK_VECTORS = 16
# The worker-process pool of the all-pairs geodesics in the parent (its queues, threads and
# buffers: measured 150 KB warm, 230 KB with the first call's imports, on woody and a
# 642-vertex sphere; solvers.geodesics.all_pairs_geodesics)
ALL_PAIRS_POOL_BYTES = 512 * 1024


@dataclass
class MeshDiagnostics:
    """What was found (and repaired) when the mesh was loaded.

    Attributes
    ----------
    welded_vertices : int
        Vertices merged into others by position.
    removed_unreferenced_vertices, removed_degenerate_faces, removed_duplicate_faces : int
        What was removed.
    nonmanifold_edges, nonmanifold_vertices, boundary_edges : int
        What was found.
    warnings : list of str
        Messages for the user.
    """

    welded_vertices: int = 0
    removed_unreferenced_vertices: int = 0
    removed_degenerate_faces: int = 0
    removed_duplicate_faces: int = 0
    nonmanifold_edges: int = 0
    nonmanifold_vertices: int = 0
    boundary_edges: int = 0
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _validate_arrays(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise DomainError("vertices must be a numeric (n, 3) array", field="vertices") from exc
    try:
        f_raw = np.asarray(faces)
    except (TypeError, ValueError) as exc:  # ragged lists
        raise DomainError("faces must be an (m, 3) array of vertex indices", field="faces") from exc
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise DomainError(f"vertices must have shape (n, 3) with n > 0, got {v.shape}",
                          field="vertices")
    if not np.all(np.isfinite(v)):
        bad = int(np.argwhere(~np.isfinite(v))[0, 0])
        raise DomainError(f"vertex {bad} has a NaN or infinite coordinate", field="vertices")
    if f_raw.ndim != 2 or f_raw.shape[1] != 3 or len(f_raw) == 0:
        raise DomainError(f"faces must have shape (m, 3) with m > 0 (triangles), got "
                          f"{f_raw.shape}", field="faces")
    if not np.issubdtype(f_raw.dtype, np.integer):
        if not np.all(np.isfinite(f_raw)) or np.any(np.mod(f_raw, 1) != 0):
            raise DomainError("face indices must be integers", field="faces")
    f = f_raw.astype(np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise DomainError(
            f"face indices must lie in [0, {len(v) - 1}], found range [{f.min()}, {f.max()}]",
            field="faces",
        )
    return v, f


def _unit_box(v: np.ndarray) -> tuple[np.ndarray, float]:
    """``v`` centered and scaled into ``[-1, 1]^3`` and the scale, so products of
    coordinates (areas, normals) cannot overflow whatever the input units."""
    center = 0.5 * (v.max(axis=0) + v.min(axis=0))
    with np.errstate(over="ignore"):
        box = float(np.max(np.abs(v - center)))
    if not np.isfinite(box):
        raise DomainError("vertex coordinates span a range too large to represent (beyond "
                          "about 1e308): rescale the mesh", field="vertices")
    if box <= 0:
        raise DomainError("all vertices coincide", field="vertices")
    return (v - center) / box, box


def _clean(v: np.ndarray, f: np.ndarray, weld: bool, diag: MeshDiagnostics):
    """Weld coincident vertices, drop degenerate/duplicate faces and unused vertices.

    Returns ``(kept, faces)``: indices into ``v`` of the vertices kept and the faces over
    them (so callers can take the kept rows of any per-vertex array)."""
    kept = np.arange(len(v))
    if weld:
        # Seams (UV / normal splits) store one surface point several times.
        scale = max(float(np.ptp(v, axis=0).max()), 1e-300)
        key = np.round(v / scale, 10)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        # Keep the file's vertex order (each merged point at its first occurrence): a mesh
        # without duplicates keeps its indices, so landmarks and vertex picks still match.
        order = np.argsort(first)
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        diag.welded_vertices = int(len(v) - len(first))
        v = v[first[order]]
        kept = kept[first[order]]
        f = rank[inverse.reshape(-1)][f]
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area2 = np.linalg.norm(cross, axis=1)
    positive = area2[~repeated]
    tiny = DEGENERATE_AREA_FRACTION * (positive.mean() if positive.size else 0.0)
    degenerate = repeated | (area2 <= tiny)
    diag.removed_degenerate_faces = int(degenerate.sum())
    if len(f) >= 16 and degenerate.sum() > 0.5 * len(f) and degenerate.sum() < len(f):
        raise DomainError(f"{int(degenerate.sum())} of {len(f)} faces are degenerate (zero area "
                          "or a repeated vertex); if the coordinates span many orders of "
                          "magnitude (an outlier vertex), fix or rescale them", field="faces")
    f = f[~degenerate]
    if len(f) == 0:
        raise DomainError("mesh has no non-degenerate faces", field="faces")
    _, unique_rows = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    diag.removed_duplicate_faces = int(len(f) - len(unique_rows))
    f = f[np.sort(unique_rows)]
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    diag.removed_unreferenced_vertices = int((~used).sum())
    remap = -np.ones(len(v), dtype=np.int64)
    remap[used] = np.arange(used.sum())
    return kept[used], remap[f]


def _as_utf8_text_if_needed(data: bytes, file_type: str) -> bytes:
    """Text formats (OBJ, OFF, ASCII STL) as UTF-8, or a clear error for binary junk.

    trimesh decodes non-UTF-8 text with the optional ``charset_normalizer`` and
    otherwise fails with an unrelated ImportError; legacy 8-bit text is read as
    Latin-1 here instead.
    """
    if file_type == "stl" and len(data) >= 84:
        count = int.from_bytes(data[80:84], "little")
        if len(data) == 84 + 50 * count:
            return data  # binary STL
    if file_type not in ("obj", "off", "stl"):
        return data
    try:
        data.decode("utf-8")
        return data
    except UnicodeDecodeError:
        pass
    if b"\x00" in data:
        detail = " (nor a binary STL matching its header)" if file_type == "stl" else ""
        raise MeshFormatError(
            f"{file_type.upper()} file is binary data, not text{detail}", field="file"
        )
    return data.decode("latin-1").encode("utf-8")


def _check_obj_indices(data: bytes) -> None:
    """OBJ face indices are 1-based (negative: relative to the end): refuse 0 and indices
    beyond the vertices the file defines, naming the line (the parser would drop or wrap
    them silently)."""
    import re

    count = len(re.findall(rb"(?m)^v[ \t]", data))
    faces = re.findall(rb"(?m)^f[ \t]+([^\r\n#]*)", data)
    refs = re.sub(rb"/[^ \t]*", b"", b" ".join(faces)).split()
    try:
        values = np.array(refs).astype(np.int64) if refs else np.zeros(0, dtype=np.int64)
        if np.all((values != 0) & (np.abs(values) <= count)):
            return  # all valid (the common case: no per-line scan)
    except (ValueError, OverflowError):
        pass
    for match in re.finditer(rb"(?m)^f[ \t]+([^\r\n#]*)", data):
        refs = [t.split(b"/", 1)[0] for t in match.group(1).split()]
        try:
            values = [int(r) for r in refs]
        except ValueError:
            values = None
        if values is not None and all(0 < v <= count or 0 < -v <= count for v in values):
            continue
        number = data.count(b"\n", 0, match.start()) + 1
        if values is None:
            raise MeshFormatError(f"OBJ line {number}: a face vertex is not an index",
                                  field="file")
        bad = next(v for v in values if not (0 < v <= count or 0 < -v <= count))
        if bad == 0:
            raise MeshFormatError(f"OBJ line {number}: face vertex index 0 (OBJ indices start "
                                  "at 1)", field="file")
        raise MeshFormatError(f"OBJ line {number}: face vertex index {bad} is out of bounds "
                              f"(the file defines {count} vertices)", field="file")


GLB_MAGIC = b"glTF"


def _gltf_problem(data: bytes, file_type: str) -> str | None:
    """What is structurally wrong with a glTF 2.0 file (GLB or JSON), or None: header,
    JSON, meshes with triangle primitives whose accessors, buffer views and buffers exist
    (a .gltf may only embed its buffers as data: URIs; upload a GLB otherwise)."""
    import json
    import struct

    if file_type == "glb":
        if len(data) < 20 or data[:4] != GLB_MAGIC:
            return "it does not start with the GLB header ('glTF' magic)"
        version, length = struct.unpack_from("<II", data, 4)
        if version != 2:
            return f"GLB version {version} (only glTF 2.0 is supported)"
        if length > len(data):
            return f"the header declares {length} bytes but the file has {len(data)}"
        chunk_len, chunk_type = struct.unpack_from("<II", data, 12)
        if chunk_type != 0x4E4F534A or 20 + chunk_len > len(data):
            return "its first chunk is not a complete JSON chunk"
        text = data[20:20 + chunk_len]
    else:
        if data[:4] == GLB_MAGIC:
            return "this is a binary GLB file: upload it with format 'glb'"
        text = data
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError):
        return "its JSON part is not valid JSON"
    if not isinstance(doc, dict):
        return "its JSON part is not an object"

    def items(name):
        value = doc.get(name, [])
        return value if isinstance(value, list) else None

    meshes, accessors = items("meshes"), items("accessors")
    views, buffers = items("bufferViews"), items("buffers")
    for name, value in (("meshes", meshes), ("accessors", accessors), ("bufferViews", views),
                        ("buffers", buffers)):
        if value is None:
            return f"'{name}' is not a list"
    if not meshes:
        return "it has no meshes"

    def check_accessor(index, where):
        if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(
                accessors):
            return f"{where} refers to accessor {index!r}, but there are {len(accessors)}"
        acc = accessors[index]
        if not isinstance(acc, dict):
            return f"accessor {index} is not an object"
        view = acc.get("bufferView")
        if view is None:
            return None
        if not isinstance(view, int) or isinstance(view, bool) or not 0 <= view < len(views):
            return f"accessor {index} refers to bufferView {view!r}, but there are {len(views)}"
        bv = views[view]
        buf = bv.get("buffer") if isinstance(bv, dict) else None
        if not isinstance(buf, int) or isinstance(buf, bool) or not 0 <= buf < len(buffers):
            return f"bufferView {view} refers to buffer {buf!r}, but there are {len(buffers)}"
        uri = buffers[buf].get("uri") if isinstance(buffers[buf], dict) else None
        if file_type == "gltf" and not (isinstance(uri, str) and uri.startswith("data:")):
            return (f"buffer {buf} is not embedded (an external file or none): upload a GLB, "
                    "or embed buffers as data: URIs")
        return None

    for m, mesh in enumerate(meshes):
        prims = mesh.get("primitives") if isinstance(mesh, dict) else None
        if not isinstance(prims, list) or not prims:
            return f"mesh {m} has no primitives"
        for p, prim in enumerate(prims):
            where = f"mesh {m} primitive {p}"
            attrs = prim.get("attributes") if isinstance(prim, dict) else None
            if not isinstance(attrs, dict) or "POSITION" not in attrs:
                return f"{where} has no POSITION attribute"
            problem = check_accessor(attrs["POSITION"], f"{where} POSITION")
            if problem is None and prim.get("indices") is not None:
                problem = check_accessor(prim["indices"], f"{where} indices")
            if problem:
                return problem
    return None


def _nonmanifold_vertex_count(f, nv, edges, counts, face_adj) -> int:
    """Vertices whose faces do not form one fan: the corners of a vertex joined across its
    interior (two-face) edges, counted in connected pieces per vertex."""
    nf = len(f)
    corner = np.arange(3 * nf).reshape(3, nf).T  # corner id of (face, local vertex)
    pairs = []
    interior = np.flatnonzero(counts == 2)
    edge_faces = face_adj.T.tocsr()
    fa = edge_faces.indices.reshape(-1)
    starts = edge_faces.indptr
    f1 = fa[starts[interior]]
    f2 = fa[starts[interior] + 1]
    for endpoint in (0, 1):
        vert = edges[interior, endpoint]
        c1 = corner[f1, np.argmax(f[f1] == vert[:, None], axis=1)]
        c2 = corner[f2, np.argmax(f[f2] == vert[:, None], axis=1)]
        pairs.append(np.stack([c1, c2], axis=1))
    pairs = np.concatenate(pairs) if pairs else np.zeros((0, 2), dtype=np.int64)
    corner_graph = sp.coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(3 * nf, 3 * nf)
    )
    _, fan = connected_components(corner_graph, directed=False)
    corner_vertex = f.T.reshape(-1)  # corner id k = local*nf + face
    fans = np.unique(np.stack([corner_vertex, fan[np.arange(3 * nf)]], axis=1), axis=0)
    fans_per_vertex = np.bincount(fans[:, 0], minlength=nv)
    return int((fans_per_vertex > 1).sum())


class TriangleMesh(Domain):
    r"""A triangle mesh rescaled to unit total area, with its operators.

    Vertices are stored at unit total surface area (``vertices``); multiply
    lengths by ``length_scale`` (and areas by its square) to return to input
    units.  Mass lives on vertices with lumped (barycentric) areas ``areas``
    summing to 1.

    Parameters
    ----------
    vertices : (V, 3) array
        Vertex positions, in input units.
    faces : (F, 3) int array
        Triangles (vertex indices).
    weld : bool
        Merge vertices at the same position.
    laplacian : {"robust", "cotan"}
        The Laplacian of heat kernels (see ``laplacian`` below).

    Attributes
    ----------
    ``cotan_laplacian``
        weak cotangent Laplacian :math:`L_{ij} = -\tfrac12(\cot\alpha_{ij}+\cot\beta_{ij})`,
        PSD with ``L·1 = 0``; equals :math:`G^\top \operatorname{diag}(A_f) G`.
    ``laplacian``
        the Laplacian used by heat kernels: the intrinsic-Delaunay ("robust")
        Laplacian of Sharp & Crane 2020 by default, whose off-diagonals are
        non-positive so :math:`(D_a + tL)^{-1}` is entrywise non-negative even on
        meshes with obtuse triangles; ``laplacian="cotan"`` selects the plain one.
    ``gradient``
        :math:`G`, ``(3F, V)``: row ``3f + c`` is component ``c`` of the
        (constant) gradient on face ``f`` of a piecewise-linear function.
    ``divergence``
        :math:`-G^\top \operatorname{diag}(A_f)`, ``(V, 3F)``: weak divergence of a
        per-face vector field, so ``divergence @ gradient == -cotan_laplacian``.
    """

    kind = "mesh"
    capabilities = frozenset({"faces", "exact_transport", "geodesic_solves", "edge_lengths",
                              "histogram_propagation"})

    def __init__(
        self,
        vertices,
        faces,
        *,
        weld: bool = False,
        laplacian: str = "robust",
        _diagnostics: MeshDiagnostics | None = None,
    ):
        super().__init__()
        if laplacian not in ("robust", "cotan"):
            raise DomainError(f"laplacian must be 'robust' or 'cotan', got {laplacian!r}",
                              field="laplacian")
        v, f = _validate_arrays(vertices, faces)
        self.diagnostics = _diagnostics or MeshDiagnostics()
        unit, box = _unit_box(v)
        kept, f = _clean(unit, f, weld, self.diagnostics)
        v, unit = v[kept], unit[kept]
        unit_area = 0.5 * np.linalg.norm(
            np.cross(unit[f[:, 1]] - unit[f[:, 0]], unit[f[:, 2]] - unit[f[:, 0]]), axis=1
        ).sum()
        self.length_scale = float(np.sqrt(unit_area)) * box
        if not (np.isfinite(self.length_scale) and self.length_scale > 0):
            raise DomainError("the mesh has no measurable area at its coordinates' scale",
                              field="vertices")
        self._input_vertices = v
        self.vertices = v / self.length_scale
        if not np.all(np.isfinite(self.vertices)):
            raise DomainError("vertex coordinates cannot be rescaled to unit area (they span "
                              "too many orders of magnitude)", field="vertices")
        self._check_geometry(f)
        self.faces = f
        self.laplacian_kind = laplacian
        self._analyze_topology()

    def _check_geometry(self, f: np.ndarray) -> None:
        """Refuse geometry whose derived quantities are not finite and positive (vertex
        areas, edge lengths): every operator is built from them."""
        v = self.vertices
        cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        face_area = 0.5 * np.linalg.norm(cross, axis=1)
        vertex_area = np.bincount(f.ravel(), weights=np.repeat(face_area / 3.0, 3),
                                  minlength=len(v))
        bad = np.flatnonzero(~(np.isfinite(vertex_area) & (vertex_area > 0)))
        if len(bad):
            raise DomainError(f"vertex {int(bad[0])} gets area {vertex_area[bad[0]]:g} at unit "
                              f"total area ({len(bad)} such vertices): the coordinates span "
                              "too many orders of magnitude", field="vertices")

    # -- construction -------------------------------------------------------
    @classmethod
    def from_file(cls, source, file_type: str | None = None, **kwargs) -> TriangleMesh:
        """Load OBJ, PLY, STL, OFF or glTF/GLB from a path, bytes or a binary file object.

        Scenes with several meshes are concatenated. Seams are welded: OBJ faces
        keep their position indices (``v`` lines), and PLY/OFF/STL/glTF vertices are
        merged by position; ``weld=True`` merges by position for OBJ too, ``weld=False``
        never (``weld=None``: the format's default, ``POSITION_WELD_FORMATS``).

        Parameters
        ----------
        source : str, path, bytes or binary file
            The mesh file.
        file_type : str, optional
            One of ``MESH_FORMATS`` (default: the path's extension; needed for bytes).
        **kwargs
            ``weld`` and the keywords of :class:`TriangleMesh` (``laplacian``).
        """
        import trimesh

        if isinstance(source, (str, os.PathLike)):
            path = os.fspath(source)
            file_type = file_type or os.path.splitext(path)[1].lstrip(".")
            if not os.path.exists(path):
                raise MeshFormatError(f"no such file: {path}", field="file")
            with open(path, "rb") as fh:
                data = fh.read()
        elif isinstance(source, (bytes, bytearray)):
            data = bytes(source)
        elif hasattr(source, "read"):
            data = source.read()
            if isinstance(data, str):  # text-mode file object
                data = data.encode("utf-8")
        else:
            raise MeshFormatError(
                f"expected a path, bytes or a file object, got {type(source).__name__}",
                field="file",
            )
        file_type = (file_type or "").lower().lstrip(".")
        if file_type not in MESH_FORMATS:
            raise MeshFormatError(
                f"unsupported mesh format {file_type!r}; expected one of {', '.join(MESH_FORMATS)}",
                field="file",
            )
        if len(data) == 0:
            raise MeshFormatError("mesh file is empty", field="file")
        data = _as_utf8_text_if_needed(data, file_type)
        if kwargs.get("weld") is None:
            kwargs["weld"] = file_type in POSITION_WELD_FORMATS
        if file_type == "obj":
            _check_obj_indices(data)
        if file_type in ("glb", "gltf"):
            problem = _gltf_problem(data, file_type)
            if problem:
                raise MeshFormatError(f"could not read the {file_type.upper()} file: {problem}",
                                      field="file")
        options = {"maintain_order": True, "skip_materials": True} if file_type == "obj" else {}
        try:
            loaded = trimesh.load(
                io.BytesIO(data), file_type=file_type, force="mesh", process=False, **options
            )
        except Exception as exc:  # trimesh raises many types on bad input
            # The parser's own text is not shown (it names internals, not the file's problem).
            log.info("%s parse error: %s: %s", file_type, type(exc).__name__, exc)
            raise MeshFormatError(f"could not parse the {file_type.upper()} file: it is "
                                  f"malformed or not a {file_type.upper()} file",
                                  field="file") from exc
        vertices = np.asarray(getattr(loaded, "vertices", np.empty((0, 3))))
        faces = np.asarray(getattr(loaded, "faces", np.empty((0, 3))))
        if len(vertices) == 0 or len(faces) == 0:
            raise MeshFormatError(f"{file_type.upper()} file contains no triangles", field="file")
        return cls(vertices, faces, **kwargs)

    # -- topology -----------------------------------------------------------
    def _analyze_topology(self) -> None:
        f = self.faces
        nv, nf = len(self.vertices), len(f)
        half = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        undirected = np.sort(half, axis=1)
        edges, edge_of_half, counts = np.unique(
            undirected, axis=0, return_inverse=True, return_counts=True
        )
        edge_of_half = edge_of_half.reshape(-1)
        self.edges = edges
        self.diagnostics.nonmanifold_edges = int((counts > 2).sum())
        self.diagnostics.boundary_edges = int((counts == 1).sum())
        self._boundary_edges = edges[counts == 1]

        face_adj = sp.coo_matrix(
            (np.ones(3 * nf), (np.tile(np.arange(nf), 3), edge_of_half)), shape=(nf, len(edges))
        ).tocsr()
        vertex_graph = sp.coo_matrix(
            (np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(nv, nv)
        )
        n_comp, labels = connected_components(vertex_graph, directed=False)
        self._components = (int(n_comp), labels)

        self.diagnostics.nonmanifold_vertices = _nonmanifold_vertex_count(
            f, nv, edges, counts, face_adj)

        # Boundary loops: connected pieces of the boundary edge graph.
        if len(self._boundary_edges):
            b = self._boundary_edges
            bgraph = sp.coo_matrix((np.ones(len(b)), (b[:, 0], b[:, 1])), shape=(nv, nv))
            _, blabels = connected_components(bgraph, directed=False)
            on_boundary = np.unique(b.ravel())
            loop_labels = blabels[on_boundary]
            self._loop_vertex_sets = [
                on_boundary[loop_labels == lab] for lab in np.unique(loop_labels)
            ]
        else:
            self._loop_vertex_sets = []

        # Per-component Euler characteristic and genus (chi = 2 - 2g - b).
        comp_v = np.bincount(labels, minlength=n_comp)
        comp_f = np.bincount(labels[f[:, 0]], minlength=n_comp)
        comp_e = np.bincount(labels[edges[:, 0]], minlength=n_comp)
        comp_b = np.bincount(
            [labels[s[0]] for s in self._loop_vertex_sets], minlength=n_comp
        ).astype(np.int64)
        self.component_euler = comp_v - comp_e + comp_f
        self.component_genus = (2 - self.component_euler - comp_b) // 2
        self.component_boundary_loops = comp_b
        self._warn_about_topology(n_comp)

    def _warn_about_topology(self, n_comp: int) -> None:
        """Add a warning to the diagnostics for each topological defect found."""
        d = self.diagnostics
        if n_comp > 1:
            d.warnings.append(
                f"mesh has {n_comp} connected components: mass cannot move between them"
            )
        if d.nonmanifold_edges:
            d.warnings.append(f"{d.nonmanifold_edges} non-manifold edges (more than two faces)")
        if d.nonmanifold_vertices:
            d.warnings.append(f"{d.nonmanifold_vertices} non-manifold vertices")
        if d.removed_degenerate_faces:
            d.warnings.append(f"removed {d.removed_degenerate_faces} degenerate faces")
        if d.removed_duplicate_faces:
            d.warnings.append(f"removed {d.removed_duplicate_faces} duplicate faces")

    @property
    def n(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def laplacian_variant(self, laplacian: str = "auto") -> sp.csr_matrix:
        """``"cotan"``: :attr:`cotan_laplacian`; ``"robust"``: :attr:`robust_laplacian`;
        ``"auto"``: :attr:`laplacian` (the one chosen at construction).
        """
        check_laplacian_name(laplacian)
        if laplacian == "cotan":
            return self.cotan_laplacian
        if laplacian == "robust":
            return self.robust_laplacian
        return self.laplacian

    def export_geometry(self) -> ExportGeometry:
        """The vertices in input units and the faces."""
        return ExportGeometry(self.to_arrays()["vertices"], faces=self.faces)

    @classmethod
    def stored_geometry(cls, arrays: dict, summary: dict, points) -> dict:
        """The unit-area vertices and the faces."""
        return {"points": points, "faces": arrays["faces"]}

    @property
    def coordinates(self) -> np.ndarray:
        """The vertices at unit area."""
        return self.vertices

    @property
    def euler_characteristic(self) -> int:
        return int(self.n - len(self.edges) + self.n_faces)

    @property
    def genus(self) -> int | None:
        """Sum of the component genera (the genus, for one component); None if non-manifold.

        Why cow.obj has none: one of its vertices is an "hourglass" (two fans of faces that
        share only that vertex), so the closed surface has chi = 1, which no closed manifold
        has. Split into one vertex per fan (what :mod:`solvers.geodesics` does) it is a
        closed genus-0 surface."""
        if not self.is_manifold:
            return None
        return int(self.component_genus.sum())

    @property
    def boundary_loops(self) -> list[np.ndarray]:
        """Vertex indices of each boundary loop (one array per loop)."""
        return list(self._loop_vertex_sets)

    @property
    def is_closed(self) -> bool:
        return self.diagnostics.boundary_edges == 0

    @property
    def is_manifold(self) -> bool:
        d = self.diagnostics
        return d.nonmanifold_edges == 0 and d.nonmanifold_vertices == 0

    # -- geometry -----------------------------------------------------------
    @cached_property
    def _face_cross(self) -> np.ndarray:
        v, f = self.vertices, self.faces
        return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])

    @cached_property
    def face_areas(self) -> np.ndarray:
        """(F,) triangle areas at unit total area."""
        return 0.5 * np.linalg.norm(self._face_cross, axis=1)

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(F, 3) unit normals."""
        return self._face_cross / (2.0 * self.face_areas[:, None])

    @cached_property
    def areas(self) -> np.ndarray:
        """(V,) lumped (barycentric) vertex areas; they sum to 1."""
        a = np.bincount(self.faces.ravel(), weights=np.repeat(self.face_areas / 3.0, 3),
                        minlength=self.n)
        return a / a.sum()

    @cached_property
    def mean_edge_length(self) -> float:
        e = self.edges
        return float(np.linalg.norm(self.vertices[e[:, 0]] - self.vertices[e[:, 1]], axis=1).mean())

    # -- operators ----------------------------------------------------------
    @cached_property
    def cotan_laplacian(self) -> sp.csr_matrix:
        v, f = self.vertices, self.faces
        rows, cols, vals = [], [], []
        for k in range(3):
            i, j, o = f[:, (k + 1) % 3], f[:, (k + 2) % 3], f[:, k]
            u, w = v[i] - v[o], v[j] - v[o]
            cot = np.einsum("ij,ij->i", u, w) / np.linalg.norm(np.cross(u, w), axis=1)
            rows += [i, j]
            cols += [j, i]
            vals += [-0.5 * cot, -0.5 * cot]
        off = sp.coo_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(self.n, self.n),
        ).tocsr()
        return (off - sp.diags(np.asarray(off.sum(axis=1)).ravel())).tocsr()

    @cached_property
    def robust_laplacian(self) -> sp.csr_matrix:
        try:
            lap, _ = robust_laplacian.mesh_laplacian(
                np.ascontiguousarray(self.vertices), np.ascontiguousarray(self.faces)
            )
        except (RuntimeError, ValueError) as exc:
            log.info("robust Laplacian failed: %s", exc)
            raise DomainError("could not build the intrinsic-Delaunay Laplacian of this mesh "
                              "(degenerate geometry); try laplacian='cotan'",
                              field="laplacian") from exc
        lap = sp.csr_matrix(lap)
        if not np.all(np.isfinite(lap.data)):
            raise DomainError("the intrinsic-Delaunay Laplacian of this mesh is not finite "
                              "(degenerate geometry); try laplacian='cotan'", field="laplacian")
        return lap

    @property
    def laplacian(self) -> sp.csr_matrix:
        return self.robust_laplacian if self.laplacian_kind == "robust" else self.cotan_laplacian

    @cached_property
    def gradient(self) -> sp.csr_matrix:
        v, f = self.vertices, self.faces
        nf = self.n_faces
        normals = self.face_normals
        rows, cols, vals = [], [], []
        for k in range(3):
            # grad phi_k = N x (p_{k+2} - p_{k+1}) / (2A)
            opposite = v[f[:, (k + 2) % 3]] - v[f[:, (k + 1) % 3]]
            g = np.cross(normals, opposite) / (2.0 * self.face_areas[:, None])
            for c in range(3):
                rows.append(3 * np.arange(nf) + c)
                cols.append(f[:, k])
                vals.append(g[:, c])
        return sp.coo_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(3 * nf, self.n),
        ).tocsr()

    @cached_property
    def divergence(self) -> sp.csr_matrix:
        return (-self.gradient.T @ sp.diags(np.repeat(self.face_areas, 3))).tocsr()

    def _build_heat_kernel(self, t: float, substeps: int, backend: Backend):
        return ImplicitEulerHeatKernel(self.areas, self.laplacian, t, substeps, backend)

    @classmethod
    def offers_geodesic_kernel(cls, n: int, n_components: int) -> bool:
        """One connected surface (the heat method gives no distance between components, and
        the kernel must not couple them) of at most :data:`GEODESIC_KERNEL_VERTICES` vertices.

        Parameters
        ----------
        n : int
            Number of vertices.
        n_components : int
            Number of connected components.

        Returns
        -------
        bool
        """
        return n <= GEODESIC_KERNEL_VERTICES and n_components == 1

    @classmethod
    def geodesic_kernel_bytes(cls, n: int) -> int:
        """Memory of :meth:`geodesic_kernel` on ``n`` vertices: the all-pairs distances and
        the kernel's scaled blocks (``n x n`` float64 each), plus one transient copy.
        """
        return 3 * 8 * n * n

    def geodesic_kernel(self, t: float) -> GeodesicGaussianKernel:
        """The Gibbs kernel of squared heat-method geodesics at heat time ``t``
        (:class:`~solvers.kernels.GeodesicGaussianKernel`), kept in the operator store.
        """
        if not self.geodesic_kernel_available:
            raise InputError(f"method 'geodesic' needs one connected surface of at most "
                             f"{GEODESIC_KERNEL_VERTICES} vertices (this mesh: {self.n} "
                             f"vertices, {self.n_components} components)", field="method")

        def build():
            d = all_pairs_heat_distances(self)
            return GeodesicGaussianKernel(self.areas, d * d, t, morton_order(self.vertices))

        return self.operators.get(("geodesic_kernel", float(t)), build)

    def ground_distances(self, src, dst, *, should_cancel=None) -> tuple[np.ndarray, bool]:
        """Exact polyhedral geodesics (not squared): one MMP solve per point of the smaller
        side (:func:`solvers.geodesics.geodesic_distances`).
        """
        return geodesic_distances(self, src, dst, should_cancel=should_cancel), False

    def stored_ground_distances(self, should_cancel=None) -> tuple[np.ndarray, bool] | None:
        """All-pairs exact geodesics, kept up to :data:`STORED_GEODESICS_VERTICES`.

        Read from the domain's :attr:`artifacts` where it has them (float32, memory-mapped),
        else computed in parallel over the sources
        (:func:`~solvers.geodesics.all_pairs_geodesics`) and, with an artifact store, stored
        there as float32."""
        if self.n > STORED_GEODESICS_VERTICES:
            return None
        def build():
            if self.artifacts is None:
                return geodesics.all_pairs_geodesics(self, should_cancel=should_cancel)
            stored = self.artifacts.get(GEODESICS_ARTIFACT)
            if stored is not None:
                return stored
            d = geodesics.all_pairs_geodesics(self, dtype=np.float32,
                                              should_cancel=should_cancel)
            try:
                self.artifacts.put(GEODESICS_ARTIFACT, d)
            except OSError:  # not storable (disk full, read-only): this process keeps them
                return d
            stored = self.artifacts.get(GEODESICS_ARTIFACT)  # memory-mapped: d is freed
            return d if stored is None else stored

        return self.operators.get(("exact_geodesics",), build), False

    @classmethod
    def stored_ground_distance_seconds(cls, n: int) -> float:
        """One modelled MMP solve per vertex (:func:`solvers.geodesics.mmp_solve_seconds`),
        up to :data:`STORED_GEODESICS_VERTICES`."""
        return 0.0 if n > STORED_GEODESICS_VERTICES else float(n) * mmp_solve_seconds(n)

    def has_stored_geodesics(self) -> bool:
        """Whether the all-pairs geodesics are stored data (in :attr:`artifacts`), so that
        :meth:`stored_ground_distances` reads them rather than computing them: the same
        answer in every process that loads the stored domain."""
        return self.artifacts is not None and self.artifacts.has(GEODESICS_ARTIFACT)

    @classmethod
    def ground_distance_bytes(cls, n: int, entries: int, dim: int) -> int:
        """The geodesics between the supports or, on a mesh small enough to keep them, the
        stored all-pairs ones instead (``entries`` of either, never both), plus a geodesic
        solve's work vectors and the pool of processes solving the stored ones.
        """
        return 8 * entries + GEODESIC_WORK_VECTORS * 8 * n + ALL_PAIRS_POOL_BYTES

    # -- storage / reporting -----------------------------------------------
    def to_arrays(self) -> dict[str, np.ndarray]:
        return {
            "vertices": self._input_vertices,
            "faces": self.faces,
        }

    def parameters(self) -> dict:
        return {"laplacian": self.laplacian_kind}

    def summary(self) -> dict:
        return {
            "kind": self.kind,
            "n": int(self.n),
            "vertices": int(self.n),
            "faces": int(self.n_faces),
            "edges": int(len(self.edges)),
            "components": self.n_components,
            "genus": self.genus,
            "euler_characteristic": self.euler_characteristic,
            "boundary_loops": len(self.boundary_loops),
            "closed": self.is_closed,
            "manifold": self.is_manifold,
            "length_scale": self.length_scale,
            "diagnostics": self.diagnostics.as_dict(),
        }
