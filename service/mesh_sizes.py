"""How many vertices and faces a mesh file holds, read from its header or counted, without
parsing it: a PLY or OFF header, OBJ ``v``/``f`` lines, an STL's facet count, a glTF's
accessor counts. The API decides from these, before any build, whether a file is refused
(413), built in its own process or in the builder process (service.domain_builder).
"""

from __future__ import annotations

import json
import re
import struct

HEADER_BYTES = 64 * 2**10  # a PLY or OFF header ends within this
GLTF_JSON_BYTES = 8 * 2**20  # a .gltf (JSON with data: buffers) beyond this is not read here


def _ply(data: bytes) -> tuple[int, int] | None:
    end = data.find(b"end_header", 0, HEADER_BYTES)
    if not data.startswith(b"ply") or end < 0:
        return None
    counts = dict(re.findall(rb"(?m)^element[ \t]+(\w+)[ \t]+(\d+)", data[:end]))
    if b"vertex" not in counts:
        return None
    return int(counts[b"vertex"]), int(counts.get(b"face", 0))


def _obj(data: bytes) -> tuple[int, int]:
    text = b"\n" + data  # a first line counts too
    vertices = text.count(b"\nv ") + text.count(b"\nv\t")
    faces = text.count(b"\nf ") + text.count(b"\nf\t")  # polygons count once: a lower bound
    return vertices, faces


def _off(data: bytes) -> tuple[int, int] | None:
    lines = (line.split(b"#")[0].split() for line in data[:HEADER_BYTES].splitlines())
    words = [w for line in lines for w in line][:3]  # "OFF", vertices, faces (any lines)
    if not words or not words[0].endswith(b"OFF"):
        return None
    try:
        return int(words[1]), int(words[2])
    except (IndexError, ValueError):
        return None


def _stl(data: bytes) -> tuple[int, int]:
    if len(data) >= 84:
        (faces,) = struct.unpack_from("<I", data, 80)
        if len(data) == 84 + 50 * faces:  # binary
            return faces // 2, faces
    faces = data.count(b"facet normal")  # ASCII
    # STL stores three corners per facet; welded, a closed surface has about F/2 vertices
    return faces // 2, faces


def _gltf(data: bytes, ext: str) -> tuple[int, int] | None:
    if ext == "glb":
        if len(data) < 20:
            return None
        chunk_len = struct.unpack_from("<I", data, 12)[0]
        text = data[20:20 + chunk_len]
    elif len(data) <= GLTF_JSON_BYTES:
        text = data
    else:
        return None
    try:
        doc = json.loads(text)
        accessors, vertices, faces = doc.get("accessors", []), 0, 0
        for mesh in doc.get("meshes", []):
            for prim in mesh.get("primitives", []):
                n = int(accessors[prim["attributes"]["POSITION"]]["count"])
                index = prim.get("indices")
                vertices += n
                faces += (int(accessors[index]["count"]) if index is not None else n) // 3
    except (ValueError, RecursionError, TypeError, KeyError, IndexError, AttributeError):
        return None  # malformed: the parser says what is wrong
    return vertices, faces


def mesh_file_counts(data: bytes, ext: str) -> tuple[int, int] | None:
    """``(vertices, faces)`` that the file of format ``ext`` declares (an STL's vertices
    after welding: about half its facets), or None when its header cannot tell."""
    if ext == "ply":
        return _ply(data)
    if ext == "obj":
        return _obj(data)
    if ext == "off":
        return _off(data)
    if ext == "stl":
        return _stl(data)
    return _gltf(data, ext)
