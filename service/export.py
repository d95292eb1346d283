"""Results to JSON and to glTF 2.0 binary (GLB).

JSON: :func:`to_jsonable` turns result dataclasses, numpy arrays and scalars
into plain JSON values; non-finite floats (an unreachable vertex's ``inf``
distance, say) become ``null`` because JSON has no NaN or infinity.
:func:`result_document` sizes a job's JSON result for the web: every array is
linked as a ``.npy`` file, and those whose JSON fits a byte budget are also
inlined as nested lists (smallest first), so small results stay one request.

GLB: :func:`domain_glb` writes the result fields of one domain as a glTF
scene that any viewer opens:

- a triangle mesh (vertices in the *input* units of the uploaded file, faces,
  smooth normals) with per-vertex colors ``COLOR_0`` from a colormap of one
  scalar field, and every field's raw values as an application-specific
  attribute (glTF 2.0 §3.7.2.1: names start with an underscore), e.g.
  ``_DENSITY`` or ``_DISTANCE`` as FLOAT SCALAR (or VEC3) accessors;
- per-face fields (``(F,)`` or ``(F, 3)`` arrays): the surface is written
  de-indexed (three vertices per face) so each face's value is repeated on its
  corners;
- a flow field ``J`` (``(F, 3)``, one vector per face): line geometry (mode
  LINES), one segment per face starting at the face centroid along ``J``,
  scaled so the longest is twice the mean edge length, colored by ``|J|``,
  with the raw vectors as ``_FLOW`` on both endpoints (segment ``f`` is face ``f``);
- several frames (an interpolation's time samples): one node per frame,
  sharing geometry, laid out side by side along x.

2-D grids are written as a triangulated plane (z = 0), 3-D grids and point
clouds as points (mode POINTS), graphs with positions as edge lines.
glTF stores finite 32-bit floats only: the attributes hold ``float32(values)``
exactly, except non-finite values (an unreachable vertex's ``inf`` distance),
written as -/+ the largest float32 and counted in the accessor's ``extras``;
the JSON result keeps full precision (and ``null`` for non-finite values).

The container is written directly (JSON chunk + BIN chunk, 4-byte aligned,
one buffer view per accessor, POSITION with min/max), no dependency.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import struct
from collections.abc import Mapping, Sequence
from urllib.parse import quote

import numpy as np

from solvers.errors import InputError, UnsupportedDomainError

__all__ = [
    "GLB_MEDIA_TYPE",
    "NPY_MEDIA_TYPE",
    "colormap",
    "domain_glb",
    "mesh_glb",
    "parse_glb",
    "points_glb",
    "result_document",
    "to_jsonable",
]

GLB_MEDIA_TYPE = "model/gltf-binary"
NPY_MEDIA_TYPE = "application/x-npy"  # NumPy's .npy format (a header, then the raw data)

_GLB_MAGIC = 0x46546C67  # b"glTF"
_CHUNK_JSON = 0x4E4F534A  # b"JSON"
_CHUNK_BIN = 0x004E4942  # b"BIN\0"
_FLOAT, _UINT32 = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_POINTS, _LINES, _TRIANGLES = 0, 1, 4
_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}


# --------------------------------------------------------------------------- JSON
def to_jsonable(obj):
    """Plain JSON value for results: dataclasses, arrays, numpy scalars, nested containers.

    Non-finite floats become ``None``. Arrays become nested lists.
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f":
            if np.all(np.isfinite(obj)):
                return obj.tolist()
            return np.where(np.isfinite(obj), obj, None).astype(object).tolist()
        if obj.dtype.kind in "iub":
            return obj.tolist()
        return [to_jsonable(x) for x in obj.tolist()]
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    return obj


def json_bytes(obj) -> bytes:
    """``obj`` as the API sends JSON (Starlette's JSONResponse: compact, UTF-8)."""
    return json.dumps(obj, ensure_ascii=False, allow_nan=False, indent=None,
                      separators=(",", ":")).encode()


def result_document(job_id: str, payload: Mapping, stored: Mapping, load, budget: int,
                    include_arrays: bool = True) -> dict:
    """The JSON result of a job: ``payload`` (values, export, files), ``array_files`` and
    ``arrays``.

    ``stored``: name -> :class:`service.store.StoredArray` (shape, dtype, .npy size) of every
    result array; each is listed in ``array_files`` with the link of its ``.npy`` file.
    ``arrays`` holds, as nested lists, the arrays whose JSON fits ``budget`` bytes with the
    rest of the document, taken smallest first (``load(name)`` reads one): a result whose
    arrays are all small is complete in one response, a large one stays within the budget
    (unless its values alone exceed it). ``include_arrays=False``: none inline.
    """
    files = {name: {"href": f"/v1/jobs/{job_id}/arrays/{quote(name, safe='')}.npy",
                    "media_type": NPY_MEDIA_TYPE, "bytes": int(item.npy_bytes),
                    "shape": list(item.shape), "dtype": item.dtype.name}
             for name, item in sorted(stored.items())}
    doc = {**payload, "arrays": {}, "array_files": files}
    if not include_arrays:
        return doc
    room = budget - len(json_bytes(doc))
    for name in sorted(stored, key=lambda n: (stored[n].size, n)):
        key = len(json_bytes(name)) + 1 + bool(doc["arrays"])  # "name": (after a comma)
        if key + 2 * stored[name].size > room:  # at least a digit and a separator per value
            continue
        values = to_jsonable(load(name))
        cost = key + len(json_bytes(values))
        if cost <= room:
            doc["arrays"][name] = values
            room -= cost
    return doc


# --------------------------------------------------------------------------- colors
# viridis sampled at 9 evenly spaced stops (sRGB), interpolated linearly in sRGB.
_VIRIDIS = np.array(
    [
        [0x44, 0x01, 0x54], [0x47, 0x2D, 0x7B], [0x3B, 0x52, 0x8B], [0x2C, 0x72, 0x8E],
        [0x21, 0x90, 0x8C], [0x27, 0xAD, 0x81], [0x5D, 0xC8, 0x63], [0xAA, 0xDC, 0x32],
        [0xFD, 0xE7, 0x25],
    ],
    dtype=np.float64,
) / 255.0
_NAN_COLOR = np.array([0.5, 0.5, 0.5])


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def colormap(values, value_range: tuple[float, float] | None = None) -> np.ndarray:
    """(n,) values -> (n, 4) float32 RGBA in *linear* RGB (glTF's COLOR_0 space).

    A viridis-like ramp over ``value_range`` (default: min and max of the
    finite values); non-finite values are grey.
    """
    x = np.asarray(values, dtype=np.float64).ravel()
    finite = np.isfinite(x)
    if value_range is None:
        lo, hi = (float(x[finite].min()), float(x[finite].max())) if finite.any() else (0.0, 1.0)
    else:
        lo, hi = (float(v) for v in value_range)
    span = hi - lo
    s = np.zeros_like(x) if span <= 0 else np.clip((np.where(finite, x, lo) - lo) / span, 0, 1)
    pos = s * (len(_VIRIDIS) - 1)
    i = np.minimum(pos.astype(np.int64), len(_VIRIDIS) - 2)
    frac = (pos - i)[:, None]
    srgb = _VIRIDIS[i] * (1 - frac) + _VIRIDIS[i + 1] * frac
    srgb[~finite] = _NAN_COLOR
    rgba = np.ones((len(x), 4), dtype=np.float32)
    rgba[:, :3] = _srgb_to_linear(srgb)
    return rgba


# --------------------------------------------------------------------------- container
class _GLTFWriter:
    """Accumulates accessors, meshes and nodes; ``to_bytes`` writes the GLB."""

    def __init__(self, metadata: Mapping | None = None):
        self.bin = bytearray()
        self.doc: dict = {
            "asset": {"version": "2.0", "generator": "otgeo"},
            "scene": 0,
            "scenes": [{"nodes": []}],
            "nodes": [],
            "meshes": [],
            "materials": [
                {
                    "name": "vertex-colors",
                    "pbrMetallicRoughness": {
                        "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                        "metallicFactor": 0.0,
                        "roughnessFactor": 0.9,
                    },
                    "doubleSided": True,
                }
            ],
            "bufferViews": [],
            "accessors": [],
        }
        if metadata:
            self.doc["extras"] = to_jsonable(dict(metadata))

    def accessor(self, data: np.ndarray, *, indices: bool = False, bounds: bool = True) -> int:
        """Append ``data`` ((n,) or (n, c), cast to float32 or uint32) as one accessor."""
        arr = np.ascontiguousarray(data, dtype=np.uint32 if indices else np.float32)
        comps = 1 if arr.ndim == 1 else arr.shape[1]
        non_finite = 0 if indices else int(arr.size - np.count_nonzero(np.isfinite(arr)))
        if non_finite:  # glTF floats must be finite: NaN/+inf -> +max, -inf -> -max float32
            big = float(np.finfo(np.float32).max)
            arr = np.nan_to_num(arr, nan=big, posinf=big, neginf=-big)
        while len(self.bin) % 4:
            self.bin.append(0)
        offset = len(self.bin)
        self.bin += arr.tobytes()
        view = {"buffer": 0, "byteOffset": offset, "byteLength": arr.nbytes,
                "target": _ELEMENT_ARRAY_BUFFER if indices else _ARRAY_BUFFER}
        self.doc["bufferViews"].append(view)
        acc = {
            "bufferView": len(self.doc["bufferViews"]) - 1,
            "componentType": _UINT32 if indices else _FLOAT,
            "count": int(len(arr)),
            "type": _TYPES[comps],
        }
        flat = arr.reshape(len(arr), comps)
        if bounds and len(arr):
            cast = int if indices else float
            acc["min"] = [cast(v) for v in flat.min(axis=0)]
            acc["max"] = [cast(v) for v in flat.max(axis=0)]
        if non_finite:
            acc["extras"] = {"nonFinite": non_finite,
                             "nonFiniteReplacement": "NaN and +inf: +3.4028235e38 (largest "
                                                     "float32), -inf: -3.4028235e38"}
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def mesh(self, name: str, attributes: dict[str, int], mode: int,
             indices: int | None = None, extras: Mapping | None = None) -> int:
        prim: dict = {"attributes": attributes, "mode": mode, "material": 0}
        if indices is not None:
            prim["indices"] = indices
        mesh: dict = {"name": name, "primitives": [prim]}
        if extras:
            mesh["extras"] = to_jsonable(dict(extras))
        self.doc["meshes"].append(mesh)
        return len(self.doc["meshes"]) - 1

    def node(self, name: str, mesh: int, translation=None, extras: Mapping | None = None) -> None:
        node: dict = {"name": name, "mesh": mesh}
        if translation is not None and np.any(translation):
            node["translation"] = [float(v) for v in translation]
        if extras:
            node["extras"] = to_jsonable(dict(extras))
        self.doc["nodes"].append(node)
        self.doc["scenes"][0]["nodes"].append(len(self.doc["nodes"]) - 1)

    def to_bytes(self) -> bytes:
        while len(self.bin) % 4:
            self.bin.append(0)
        doc = dict(self.doc)
        if self.bin:
            doc["buffers"] = [{"byteLength": len(self.bin)}]
        else:
            del doc["bufferViews"], doc["accessors"]
        text = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()
        text += b" " * (-len(text) % 4)
        total = 12 + 8 + len(text) + (8 + len(self.bin) if self.bin else 0)
        out = bytearray(struct.pack("<III", _GLB_MAGIC, 2, total))
        out += struct.pack("<II", len(text), _CHUNK_JSON) + text
        if self.bin:
            out += struct.pack("<II", len(self.bin), _CHUNK_BIN) + self.bin
        return bytes(out)


def parse_glb(data: bytes) -> tuple[dict, bytes]:
    """Split a GLB into its JSON document and BIN chunk (for tests and clients)."""
    magic, version, total = struct.unpack_from("<III", data, 0)
    if magic != _GLB_MAGIC or version != 2 or total != len(data):
        raise InputError("not a glTF 2.0 binary", field="file")
    length, kind = struct.unpack_from("<II", data, 12)
    if kind != _CHUNK_JSON:
        raise InputError("GLB does not start with a JSON chunk", field="file")
    doc = json.loads(data[20:20 + length])
    rest = 20 + length
    binary = b""
    if rest < len(data):
        blen, kind = struct.unpack_from("<II", data, rest)
        if kind == _CHUNK_BIN:
            binary = data[rest + 8:rest + 8 + blen]
    return doc, binary


# --------------------------------------------------------------------------- fields
def attribute_name(name: str) -> str:
    """Field name -> glTF application-specific attribute name: ``"density"`` -> ``"_DENSITY"``."""
    return "_" + re.sub(r"[^A-Z0-9]+", "_", name.upper()).strip("_")


def _fields(fields: Mapping | None, n: int, what: str) -> dict[str, np.ndarray]:
    out = {}
    for name, values in (fields or {}).items():
        arr = np.asarray(values, dtype=np.float64)
        if arr.ndim == 2 and arr.shape[1] == 1:
            arr = arr[:, 0]
        if len(arr) != n or arr.ndim not in (1, 2) or (arr.ndim == 2 and arr.shape[1] > 4):
            raise InputError(
                f"field {name!r} must have shape ({n},) or ({n}, 2..4) per {what}, "
                f"got {arr.shape}", field=name)
        out[attribute_name(name)] = arr
    return out


def _color_source(color: str | None, *field_dicts: dict[str, np.ndarray]):
    """The scalar array COLOR_0 is computed from: a named field, else the first one."""
    merged = {k: v for d in field_dicts for k, v in d.items()}
    if color is not None:
        key = attribute_name(color)
        if key not in merged:
            raise InputError(f"color field {color!r} is not among the exported fields",
                             field="color")
        arr = merged[key]
    elif merged:
        arr = next(iter(merged.values()))
    else:
        return None
    return arr if arr.ndim == 1 else np.linalg.norm(arr, axis=1)


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # area-weighted
    vn = np.zeros_like(v)
    for c in range(3):
        np.add.at(vn, f[:, c], fn)
    norm = np.linalg.norm(vn, axis=1)
    vn[norm == 0] = (0.0, 0.0, 1.0)
    norm[norm == 0] = 1.0
    return vn / norm[:, None]


def _mean_edge_length(v: np.ndarray, f: np.ndarray) -> float:
    e = np.concatenate([v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 1]],
                        v[f[:, 0]] - v[f[:, 2]]])
    return float(np.linalg.norm(e, axis=1).mean())


def _frame_offsets(points: np.ndarray, count: int) -> np.ndarray:
    extent = np.ptp(points, axis=0) if len(points) else np.zeros(3)
    step = 1.25 * float(extent[0]) or 1.0
    return np.outer(np.arange(count), [step, 0.0, 0.0])


def _as_frames(vertex_fields, frames: Sequence | None):
    """(n, T) fields with T frame labels -> list of per-frame dicts; else one frame."""
    if frames is None:
        return [None], [vertex_fields or {}]
    frames = list(frames)
    out = []
    for k in range(len(frames)):
        d = {}
        for name, values in (vertex_fields or {}).items():
            arr = np.asarray(values)
            if arr.ndim != 2 or arr.shape[1] != len(frames):
                raise InputError(f"field {name!r} needs one column per frame ({len(frames)}), "
                                 f"got shape {arr.shape}", field=name)
            d[name] = arr[:, k]
        out.append(d)
    return frames, out


# --------------------------------------------------------------------------- meshes
def mesh_glb(
    vertices, faces, *, vertex_fields: Mapping | None = None,
    face_fields: Mapping | None = None, flow=None, color: str | None = None,
    value_range: tuple[float, float] | None = None, frames: Sequence | None = None,
    metadata: Mapping | None = None,
) -> bytes:
    """A triangle mesh with result fields as GLB bytes.

    Parameters
    ----------
    vertices : (V, 3) positions, written as given (pass input units).
    faces : (F, 3) vertex indices.
    vertex_fields : name -> (V,) or (V, c) values; with ``frames``, (V, T) (one column per frame).
    face_fields : name -> (F,) or (F, c) values; the surface is then written de-indexed.
    flow : optional (F, 3) per-face vector field, written as LINES from face centroids.
    color : field whose values (norm, if vectors) give ``COLOR_0``; default the first field.
    value_range : (lo, hi) of the colormap; default min/max over all frames.
    frames : labels (e.g. interpolation times) of the columns of ``vertex_fields``.
    metadata : JSON-able dict stored as the document's ``extras``.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        raise InputError("vertices must be a finite (V, 3) array", field="vertices")
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
        raise InputError("faces must be (F, 3) indices into vertices", field="faces")
    labels, frame_fields = _as_frames(vertex_fields, frames)
    per_frame = [_fields(d, len(v), "vertex") for d in frame_fields]
    ffields = _fields(face_fields, len(f), "face")
    if value_range is None:
        value_range = _frames_value_range(color, per_frame, ffields)

    w = _GLTFWriter(metadata)
    deindexed = bool(ffields)
    if deindexed:
        corners = f.ravel()
        geometry = {"POSITION": w.accessor(v[corners]),
                    "NORMAL": w.accessor(_corner_face_normals(v, f))}
        indices = None
        face_acc = {k: w.accessor(np.repeat(a, 3, axis=0)) for k, a in ffields.items()}
    else:
        corners = None
        geometry = {"POSITION": w.accessor(v), "NORMAL": w.accessor(_vertex_normals(v, f))}
        indices = w.accessor(f.ravel(), indices=True)
        face_acc = {}

    offsets = _frame_offsets(v, len(per_frame))
    for k, (label, vf) in enumerate(zip(labels, per_frame, strict=True)):
        attrs = dict(geometry)
        src = _color_source(color, vf, ffields)
        if src is not None:
            rgba = colormap(src, value_range)
            attrs["COLOR_0"] = w.accessor(rgba if len(src) == len(v) and not deindexed
                                          else rgba[corners] if len(src) == len(v)
                                          else np.repeat(rgba, 3, axis=0))
        for key, arr in vf.items():
            attrs[key] = w.accessor(arr[corners] if deindexed else arr)
        attrs.update(face_acc)
        name = "surface" if label is None else f"surface {label}"
        extras = {"value_range": value_range} if value_range is not None else {}
        if label is not None:
            extras["frame"] = label
        mesh = w.mesh(name, attrs, _TRIANGLES, indices, extras)
        w.node(name, mesh, offsets[k], {"frame": label} if label is not None else None)

    if flow is not None:
        _add_flow(w, v, f, flow)
    return w.to_bytes()


def _frames_value_range(color, per_frame, ffields) -> tuple[float, float] | None:
    """``(lo, hi)`` of the colored values over all frames (None when none is finite)."""
    sources = [_color_source(color, pf, ffields) for pf in per_frame]
    finite = [s[np.isfinite(s)] for s in sources if s is not None]
    finite = [s for s in finite if s.size]
    if finite:
        return (min(float(s.min()) for s in finite), max(float(s.max()) for s in finite))
    return None


def _corner_face_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``(3F, 3)`` unit face normals repeated at each face's corners (a degenerate face
    gets +z)."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    norm = np.linalg.norm(fn, axis=1)
    fn[norm == 0] = (0.0, 0.0, 1.0)
    norm[norm == 0] = 1.0
    return np.repeat(fn / norm[:, None], 3, axis=0)


def _add_flow(w: _GLTFWriter, v: np.ndarray, f: np.ndarray, flow) -> None:
    J = np.asarray(flow, dtype=np.float64)
    if J.shape != (len(f), 3):
        raise InputError(f"flow must have shape ({len(f)}, 3), got {J.shape}", field="flow")
    magnitude = np.linalg.norm(J, axis=1)
    finite = np.isfinite(magnitude)
    peak = float(magnitude[finite].max()) if finite.any() else 0.0
    scale = 2.0 * _mean_edge_length(v, f) / peak if peak > 0 else 0.0
    centroids = v[f].mean(axis=1)
    seg = np.where(finite[:, None], J * scale, 0.0)
    pos = np.stack([centroids, centroids + seg], axis=1).reshape(-1, 3)
    attrs = {
        "POSITION": w.accessor(pos),
        "COLOR_0": w.accessor(np.repeat(colormap(magnitude), 2, axis=0)),
        "_FLOW": w.accessor(np.repeat(J, 2, axis=0)),
        "_FLOW_MAGNITUDE": w.accessor(np.repeat(magnitude, 2, axis=0)),
    }
    mesh = w.mesh("flow", attrs, _LINES, extras={"segment_scale": scale, "max_magnitude": peak})
    w.node("flow", mesh)


def meshes_glb(parts: Sequence[Mapping], *, metadata: Mapping | None = None) -> bytes:
    """Several triangle meshes in one GLB (e.g. the two surfaces of a correspondence).

    Each part is a mapping with ``name``, ``vertices`` (V, 3), ``faces`` (F, 3), and
    optionally ``colors`` (V, 3|4) RGB(A) in [0, 1] written as given, or ``field`` (V,)
    values colormapped (``value_range`` optional), ``translation`` (3,) of its node, and
    ``lines`` (S, 2, 3) segments (e.g. vector fields) drawn with the same translation.
    """
    w = _GLTFWriter(metadata)
    for part in parts:
        v = np.asarray(part["vertices"], dtype=np.float64)
        f = np.asarray(part["faces"], dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise InputError("vertices must be a finite (V, 3) array", field="vertices")
        if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
            raise InputError("faces must be (F, 3) indices into vertices", field="faces")
        attrs = {"POSITION": w.accessor(v), "NORMAL": w.accessor(_vertex_normals(v, f))}
        extras = {}
        if part.get("colors") is not None:
            c = np.clip(np.asarray(part["colors"], dtype=np.float64), 0.0, 1.0)
            if c.shape[1] == 3:
                c = np.concatenate([c, np.ones((len(c), 1))], axis=1)
            attrs["COLOR_0"] = w.accessor(c)
        elif part.get("field") is not None:
            values = np.asarray(part["field"], dtype=np.float64)
            attrs["COLOR_0"] = w.accessor(colormap(values, part.get("value_range")))
            attrs[attribute_name(str(part.get("field_name", "value")))] = w.accessor(values)
            extras["value_range"] = part.get("value_range") or (float(values.min()),
                                                                 float(values.max()))
        name = str(part["name"])
        mesh = w.mesh(name, attrs, _TRIANGLES, w.accessor(f.ravel(), indices=True), extras)
        w.node(name, mesh, part.get("translation"))
        if part.get("lines") is not None and len(part["lines"]):
            seg = np.asarray(part["lines"], dtype=np.float64).reshape(-1, 3)
            lines = w.mesh(f"{name} lines", {"POSITION": w.accessor(seg)}, _LINES)
            w.node(f"{name} lines", lines, part.get("translation"))
    return w.to_bytes()


# --------------------------------------------------------------------------- other domains
def points_glb(points, *, vertex_fields: Mapping | None = None, edges=None,
               color: str | None = None, value_range=None, frames: Sequence | None = None,
               metadata: Mapping | None = None) -> bytes:
    """Points (mode POINTS), or graph edges as LINES when ``edges`` (m, 2) is given.

    ``points`` (n, d) with d <= 3 is padded with zeros to 3-D.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or not 1 <= p.shape[1] <= 3 or not np.all(np.isfinite(p)):
        raise InputError("points must be a finite (n, d) array with d <= 3", field="points")
    p = np.pad(p, ((0, 0), (0, 3 - p.shape[1])))
    labels, frame_fields = _as_frames(vertex_fields, frames)
    per_frame = [_fields(d, len(p), "point") for d in frame_fields]
    if value_range is None:
        sources = [s for s in (_color_source(color, pf) for pf in per_frame) if s is not None]
        finite = np.concatenate([s[np.isfinite(s)] for s in sources]) if sources else []
        if len(finite):
            value_range = (float(np.min(finite)), float(np.max(finite)))
    w = _GLTFWriter(metadata)
    geometry = {"POSITION": w.accessor(p)}
    indices, mode = None, _POINTS
    if edges is not None:
        e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        indices, mode = w.accessor(e.ravel(), indices=True), _LINES
    offsets = _frame_offsets(p, len(per_frame))
    for k, (label, vf) in enumerate(zip(labels, per_frame, strict=True)):
        attrs = dict(geometry)
        src = _color_source(color, vf)
        if src is not None:
            attrs["COLOR_0"] = w.accessor(colormap(src, value_range))
        for key, arr in vf.items():
            attrs[key] = w.accessor(arr)
        name = ("edges" if edges is not None else "points") + ("" if label is None
                                                                else f" {label}")
        mesh = w.mesh(name, attrs, mode, indices,
                      {"value_range": value_range} if value_range is not None else None)
        w.node(name, mesh, offsets[k], {"frame": label} if label is not None else None)
    return w.to_bytes()


def domain_glb(domain, *, fields: Mapping | None = None, flow=None, color: str | None = None,
               frames: Sequence | None = None, metadata: Mapping | None = None,
               per_face: Sequence[str] = ()) -> bytes:
    """GLB of result ``fields`` on a domain (the service's ``result.glb``).

    ``fields`` maps names to per-point arrays ``(n,)`` / ``(n, c)`` (or
    ``(n, T)`` with ``frames``); on a mesh, arrays of length ``F`` (faces)
    are per-face fields, as are the names in ``per_face`` (needed only when
    ``F == V``). Meshes keep their input units. Graphs need ``positions``;
    otherwise :class:`UnsupportedDomainError`.
    """
    fields = dict(fields or {})
    common = {"color": color, "frames": frames, "metadata": metadata}
    has_faces = domain.supports("faces")  # per-face fields and flows
    if flow is not None and not has_faces:
        raise UnsupportedDomainError("flows can only be exported on triangle meshes",
                                     field="flow")
    geometry = domain.export_geometry()
    if has_faces:
        vertex_fields, face_fields = _vertex_and_face_fields(fields, domain.n, domain.n_faces,
                                                             per_face)
        return mesh_glb(geometry.positions, geometry.faces, vertex_fields=vertex_fields,
                        face_fields=face_fields, flow=flow, **common)
    if geometry.faces is not None:
        return mesh_glb(geometry.positions, geometry.faces, vertex_fields=fields, **common)
    return points_glb(geometry.positions, vertex_fields=fields, edges=geometry.edges, **common)


def _vertex_and_face_fields(fields: dict, n_v: int, n_f: int, per_face: Sequence[str]
                            ) -> tuple[dict, dict]:
    """Split a mesh's result fields by length into per-vertex and per-face ones (names in
    ``per_face`` are per-face fields); an array of neither length is refused."""
    vertex_fields = {k: a for k, a in fields.items()
                     if k not in per_face and len(np.asarray(a)) == n_v}
    face_fields = {k: a for k, a in fields.items()
                   if k not in vertex_fields and len(np.asarray(a)) == n_f}
    bad = set(fields) - set(vertex_fields) - set(face_fields)
    if bad:
        name = sorted(bad)[0]
        raise InputError(f"field {name!r} has length {len(np.asarray(fields[name]))}, "
                         f"expected {n_v} (vertices) or {n_f} (faces)", field=name)
    return vertex_fields, face_fields
