"""Results to JSON and GLB: structure per the glTF 2.0 spec, exact round trip of raw values,
and loading by an independent reader (trimesh)."""

from __future__ import annotations

import dataclasses
import io
import json
import struct

import numpy as np
import pytest
import trimesh

from service.export import (
    attribute_name,
    colormap,
    domain_glb,
    mesh_glb,
    parse_glb,
    points_glb,
    to_jsonable,
)
from solvers import Graph, Grid, PointCloud, TriangleMesh
from solvers.errors import InputError, UnsupportedDomainError

_NP = {5126: np.float32, 5125: np.uint32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def read_accessor(doc: dict, binary: bytes, index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    dtype = np.dtype(_NP[acc["componentType"]])
    width = _WIDTH[acc["type"]]
    start = view["byteOffset"] + acc.get("byteOffset", 0)
    arr = np.frombuffer(binary, dtype=dtype, count=acc["count"] * width, offset=start)
    return arr.reshape(acc["count"], width) if width > 1 else arr


def check_container(data: bytes) -> tuple[dict, bytes]:
    """Byte-level checks of glTF 2.0 §4.4 (GLB) and the accessor/bufferView rules."""
    magic, version, total = struct.unpack_from("<III", data, 0)
    assert (magic, version, total) == (0x46546C67, 2, len(data))
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_len % 4 == 0
    doc, binary = parse_glb(data)
    bin_len, bin_type = struct.unpack_from("<II", data, 20 + json_len)
    assert bin_type == 0x004E4942 and bin_len % 4 == 0
    assert 20 + json_len + 8 + bin_len == len(data)
    assert doc["asset"]["version"] == "2.0"
    assert doc["buffers"] == [{"byteLength": bin_len}]
    for view in doc["bufferViews"]:
        assert view["byteOffset"] % 4 == 0
        assert view["byteOffset"] + view["byteLength"] <= bin_len
    for acc in doc["accessors"]:
        view = doc["bufferViews"][acc["bufferView"]]
        assert acc["count"] * _WIDTH[acc["type"]] * 4 == view["byteLength"]
    for mesh in doc["meshes"]:
        for prim in mesh["primitives"]:
            counts = {doc["accessors"][a]["count"] for a in prim["attributes"].values()}
            assert len(counts) == 1, "all attributes of a primitive have the same count"
            pos = doc["accessors"][prim["attributes"]["POSITION"]]
            assert "min" in pos and "max" in pos
            values = read_accessor(doc, binary, prim["attributes"]["POSITION"])
            assert pos["min"] == values.min(axis=0).tolist()
            assert pos["max"] == values.max(axis=0).tolist()
            for key in prim["attributes"]:
                assert key in ("POSITION", "NORMAL", "COLOR_0") or key.startswith("_")
    return doc, binary


def attrs(doc, binary, mesh=0) -> dict[str, np.ndarray]:
    prim = doc["meshes"][mesh]["primitives"][0]
    return {k: read_accessor(doc, binary, i) for k, i in prim["attributes"].items()}


@pytest.fixture(scope="module")
def spot(shared_mesh):
    return shared_mesh("spot.obj", weld=True)


def test_mesh_glb_round_trips_raw_values_in_input_units(spot):
    rng = np.random.default_rng(0)
    density = rng.random(spot.n) * 1e3 + 1e-7
    distance = rng.random(spot.n)
    data = domain_glb(spot, fields={"density": density, "distance": distance},
                      metadata={"job": "abc"})
    doc, binary = check_container(data)
    assert doc["extras"] == {"job": "abc"}
    prim = doc["meshes"][0]["primitives"][0]
    assert prim["mode"] == 4
    a = attrs(doc, binary)
    # exact float32 round trip of the raw values
    np.testing.assert_array_equal(a["_DENSITY"], density.astype(np.float32))
    np.testing.assert_array_equal(a["_DISTANCE"], distance.astype(np.float32))
    # geometry in input units (the solver's copy is rescaled to unit area)
    raw = spot.to_arrays()["vertices"]
    assert spot.length_scale != pytest.approx(1.0)
    np.testing.assert_array_equal(a["POSITION"], raw.astype(np.float32))
    faces = read_accessor(doc, binary, prim["indices"]).reshape(-1, 3)
    np.testing.assert_array_equal(faces, spot.faces)
    np.testing.assert_allclose(np.linalg.norm(a["NORMAL"], axis=1), 1.0, atol=1e-6)
    # colors: by the first field, ends of the ramp at its min and max
    np.testing.assert_array_equal(a["COLOR_0"], colormap(density))
    np.testing.assert_array_equal(a["COLOR_0"][np.argmin(density)], colormap([0.0, 1.0])[0])
    np.testing.assert_array_equal(a["COLOR_0"][np.argmax(density)], colormap([0.0, 1.0])[1])


def test_trimesh_reads_geometry_colors_and_custom_attributes(spot):
    values = np.linspace(-1.0, 2.0, spot.n)
    data = domain_glb(spot, fields={"distance": values}, color="distance")
    scene = trimesh.load(io.BytesIO(data), file_type="glb", process=False)
    (geom,) = scene.geometry.values()
    np.testing.assert_array_equal(geom.vertices, spot.to_arrays()["vertices"].astype(np.float32))
    np.testing.assert_array_equal(geom.faces, spot.faces)
    np.testing.assert_array_equal(np.ravel(geom.vertex_attributes["_DISTANCE"]),
                                  values.astype(np.float32))
    colors = geom.visual.vertex_attributes["color"]  # material present: kept as an attribute
    expected = colormap(values)
    np.testing.assert_allclose(np.asarray(colors, dtype=float) / 255.0 if colors.dtype == np.uint8
                               else colors, expected, atol=1 / 255 + 1e-6)


def test_colormap_is_viridis_like_and_monotone_in_luminance():
    x = np.linspace(0.0, 1.0, 257)
    rgba = colormap(x)
    assert rgba.dtype == np.float32 and rgba.shape == (257, 4)
    np.testing.assert_array_equal(rgba[:, 3], 1.0)
    # linear-RGB luminance strictly increases along viridis
    lum = rgba[:, :3] @ np.array([0.2126, 0.7152, 0.0722])
    assert np.all(np.diff(lum) > 0)
    # ends: sRGB #440154 and #FDE725 converted to linear
    def lin(c):
        c = np.asarray(c) / 255.0
        return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(rgba[0, :3], lin([0x44, 0x01, 0x54]), rtol=1e-6)
    np.testing.assert_allclose(rgba[-1, :3], lin([0xFD, 0xE7, 0x25]), rtol=1e-6)
    # invariance to affine rescaling of the data; explicit range clips; NaN is grey
    np.testing.assert_array_equal(colormap(3 * x + 7), rgba)
    clipped = colormap([-5.0, 0.5, 9.0], value_range=(0.0, 1.0))
    np.testing.assert_array_equal(clipped[[0, 2]], rgba[[0, -1]])
    grey = colormap([np.nan, 0.0, 1.0])[0]
    assert grey[0] == grey[1] == grey[2]
    np.testing.assert_array_equal(colormap(np.full(4, 2.0)), np.repeat(rgba[:1], 4, axis=0))


def test_face_fields_deindex_the_surface(spot):
    rng = np.random.default_rng(1)
    per_face = rng.random(spot.n_faces)
    per_vertex = rng.random(spot.n)
    doc, binary = check_container(domain_glb(
        spot, fields={"potential": per_vertex, "flow_magnitude": per_face},
        color="flow_magnitude"))
    prim = doc["meshes"][0]["primitives"][0]
    assert "indices" not in prim
    a = attrs(doc, binary)
    raw = spot.to_arrays()["vertices"]
    F = spot.n_faces
    assert len(a["POSITION"]) == 3 * F
    np.testing.assert_array_equal(a["POSITION"], raw[spot.faces.ravel()].astype(np.float32))
    np.testing.assert_array_equal(a["_FLOW_MAGNITUDE"], np.repeat(per_face, 3).astype(np.float32))
    np.testing.assert_array_equal(a["_POTENTIAL"],
                                  per_vertex[spot.faces.ravel()].astype(np.float32))
    np.testing.assert_array_equal(a["COLOR_0"], np.repeat(colormap(per_face), 3, axis=0))
    # flat normals: each corner's normal is orthogonal to its triangle's edges
    tri = a["POSITION"].reshape(F, 3, 3).astype(np.float64)
    n = a["NORMAL"].reshape(F, 3, 3)[:, 0].astype(np.float64)
    edge = tri[:, 1] - tri[:, 0]
    good = spot.face_areas > 1e-8
    cos = np.abs(np.einsum("ij,ij->i", n, edge)) / np.linalg.norm(edge, axis=1)
    assert cos[good].max() < 1e-4


def test_flow_is_written_as_segments_from_face_centroids(spot):
    rng = np.random.default_rng(2)
    J = rng.normal(size=(spot.n_faces, 3))
    J -= np.einsum("ij,ij->i", J, spot.face_normals)[:, None] * spot.face_normals  # tangent
    doc, binary = check_container(domain_glb(spot, fields={"potential": rng.random(spot.n)},
                                             flow=J))
    names = [m["name"] for m in doc["meshes"]]
    assert names == ["surface", "flow"]
    prim = doc["meshes"][1]["primitives"][0]
    assert prim["mode"] == 1
    a = attrs(doc, binary, mesh=1)
    F = spot.n_faces
    assert len(a["POSITION"]) == 2 * F
    np.testing.assert_array_equal(a["_FLOW"], np.repeat(J, 2, axis=0).astype(np.float32))
    raw = spot.to_arrays()["vertices"]
    start, end = a["POSITION"][0::2].astype(float), a["POSITION"][1::2].astype(float)
    np.testing.assert_allclose(start, raw[spot.faces].mean(axis=1), rtol=1e-6, atol=1e-6)
    seg = end - start
    # parallel to J, the longest segment is twice the mean edge length (input units)
    cross = np.linalg.norm(np.cross(seg, J), axis=1) / np.linalg.norm(J, axis=1)
    assert cross.max() < 1e-4 * np.linalg.norm(seg, axis=1).max()
    edges = np.concatenate([raw[spot.faces[:, i]] - raw[spot.faces[:, (i + 1) % 3]]
                            for i in range(3)])
    longest = np.linalg.norm(seg, axis=1).max()
    assert longest == pytest.approx(2 * np.linalg.norm(edges, axis=1).mean(), rel=1e-5)
    # trimesh reads the line primitive with its custom attribute
    scene = trimesh.load(io.BytesIO(domain_glb(spot, flow=J)), file_type="glb", process=False)
    path = scene.geometry["flow"]
    np.testing.assert_array_equal(path.vertex_attributes["_FLOW"], a["_FLOW"])


def test_frames_share_geometry_and_keep_each_columns_values(spot):
    rng = np.random.default_rng(3)
    masses = rng.random((spot.n, 3))
    doc, binary = check_container(domain_glb(spot, fields={"density": masses},
                                             frames=[0.0, 0.5, 1.0]))
    assert [n["extras"]["frame"] for n in doc["nodes"]] == [0.0, 0.5, 1.0]
    xs = [n.get("translation", [0, 0, 0])[0] for n in doc["nodes"]]
    assert xs[0] == 0 and 0 < xs[1] < xs[2]
    prims = [m["primitives"][0] for m in doc["meshes"]]
    assert len({p["attributes"]["POSITION"] for p in prims}) == 1
    assert len({p["indices"] for p in prims}) == 1
    for k in range(3):
        np.testing.assert_array_equal(attrs(doc, binary, mesh=k)["_DENSITY"],
                                      masses[:, k].astype(np.float32))
    # one color range across frames: global min maps to the ramp start
    lo = np.unravel_index(np.argmin(masses), masses.shape)
    np.testing.assert_array_equal(attrs(doc, binary, mesh=lo[1])["COLOR_0"][lo[0]],
                                  colormap([0.0, 1.0])[0])
    with pytest.raises(InputError) as err:
        domain_glb(spot, fields={"density": masses}, frames=[0.0, 1.0])
    assert err.value.field == "density"


def test_other_domains():
    grid = Grid((4, 5))
    values = np.arange(20.0)
    doc, binary = check_container(domain_glb(grid, fields={"density": values}))
    a = attrs(doc, binary)
    assert doc["meshes"][0]["primitives"][0]["mode"] == 4
    np.testing.assert_array_equal(a["POSITION"][:, :2], grid.points.astype(np.float32))
    np.testing.assert_array_equal(a["_DENSITY"], values.astype(np.float32))
    faces = read_accessor(doc, binary, doc["meshes"][0]["primitives"][0]["indices"]).reshape(-1, 3)
    tri = a["POSITION"][faces].astype(float)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    assert len(faces) == 2 * 3 * 4 and area.sum() == pytest.approx(1.0)

    cube = Grid((3, 3, 3))
    doc, _ = check_container(domain_glb(cube, fields={"density": np.ones(27)}))
    assert doc["meshes"][0]["primitives"][0]["mode"] == 0

    pts = np.random.default_rng(4).normal(size=(40, 3))
    cloud = PointCloud(pts, n_neighbors=8)
    doc, binary = check_container(domain_glb(cloud, fields={"density": cloud.areas}))
    np.testing.assert_array_equal(attrs(doc, binary)["POSITION"], pts.astype(np.float32))

    edges = [[0, 1], [1, 2], [2, 3]]
    graph = Graph(4, edges, positions=[[0, 0], [1, 0], [1, 1], [0, 1]])
    doc, binary = check_container(domain_glb(graph, fields={"mass": [0.1, 0.2, 0.3, 0.4]}))
    prim = doc["meshes"][0]["primitives"][0]
    assert prim["mode"] == 1
    np.testing.assert_array_equal(read_accessor(doc, binary, prim["indices"]),
                                  np.ravel(edges))
    with pytest.raises(UnsupportedDomainError) as err:
        domain_glb(Graph(4, edges), fields={"mass": np.ones(4)})
    assert err.value.field == "format"
    with pytest.raises(UnsupportedDomainError):
        domain_glb(grid, flow=np.zeros((20, 3)))
    with pytest.raises(InputError) as err:
        points_glb(pts, vertex_fields={"density": np.ones(39)})
    assert err.value.field == "density"


def test_per_face_names_resolve_equal_counts():
    # a tetrahedron: V == F == 4
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    mesh = TriangleMesh(v, f)
    assert mesh.n == mesh.n_faces == 4
    values = np.arange(4.0)
    doc, binary = check_container(domain_glb(mesh, fields={"a": values, "b": values},
                                             per_face=["b"]))
    a = attrs(doc, binary)
    assert len(a["POSITION"]) == 12  # de-indexed because "b" is per face
    np.testing.assert_array_equal(a["_B"], np.repeat(values, 3).astype(np.float32))
    np.testing.assert_array_equal(a["_A"], values[mesh.faces.ravel()].astype(np.float32))


def test_bad_fields_name_the_field(spot):
    with pytest.raises(InputError) as err:
        domain_glb(spot, fields={"distance": np.ones(spot.n + 1)})
    assert err.value.field == "distance"
    with pytest.raises(InputError) as err:
        domain_glb(spot, fields={"distance": np.ones(spot.n)}, color="density")
    assert err.value.field == "color"
    with pytest.raises(InputError) as err:
        domain_glb(spot, flow=np.ones((spot.n_faces, 2)))
    assert err.value.field == "flow"
    with pytest.raises(InputError):
        mesh_glb(np.full((3, 3), np.nan), [[0, 1, 2]])


def test_non_finite_values_keep_a_valid_document(spot):
    d = np.linspace(0.0, 1.0, spot.n)
    d[1:11] = np.inf
    d[11] = -np.inf
    d[12] = np.nan
    doc, binary = check_container(domain_glb(spot, fields={"distance": d}))
    a = attrs(doc, binary)
    big = np.finfo(np.float32).max
    assert np.all(np.isfinite(a["_DISTANCE"]))  # glTF requires finite floats
    assert np.all(a["_DISTANCE"][1:11] == big) and a["_DISTANCE"][11] == -big
    assert a["_DISTANCE"][12] == big
    finite = np.isfinite(d)
    np.testing.assert_array_equal(a["_DISTANCE"][finite], d[finite].astype(np.float32))
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["_DISTANCE"]]
    assert acc["extras"]["nonFinite"] == 12
    assert acc["min"] == [float(-big)] and acc["max"] == [float(big)]
    # colors ignore the non-finite values: the ramp spans the finite ones, which are grey
    assert doc["meshes"][0]["extras"]["value_range"] == [0.0, 1.0]
    grey = a["COLOR_0"][1]
    assert grey[0] == grey[1] == grey[2]


def test_attribute_names():
    assert attribute_name("density") == "_DENSITY"
    assert attribute_name("flow magnitude") == "_FLOW_MAGNITUDE"
    assert attribute_name("w1-distance") == "_W1_DISTANCE"


def test_to_jsonable():
    @dataclasses.dataclass
    class Result:
        value: float
        masses: np.ndarray
        iterations: int
        converged: bool
        extra: dict

    r = Result(np.float64(0.25), np.array([0.5, np.inf, np.nan]), np.int64(7), np.bool_(True),
               {"ids": np.arange(3), "pair": (np.float32(1.5), None)})
    out = to_jsonable(r)
    text = json.dumps(out, allow_nan=False)
    assert json.loads(text) == {"value": 0.25, "masses": [0.5, None, None], "iterations": 7,
                                "converged": True, "extra": {"ids": [0, 1, 2], "pair": [1.5, None]}}
    big = np.random.default_rng(5).random((4, 3))
    assert np.array_equal(np.array(to_jsonable(big)), big)  # float64 exactly
