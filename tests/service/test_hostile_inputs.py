"""The corrupted-input corpus: every hostile input of issue 11 (and more) gets a 4xx at
submission naming its field — never a 500, never a job that fails later in the worker."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest
import trimesh
from fastapi.testclient import TestClient

from service.app import create_app
from service.settings import Settings

BIG = 2**70  # beyond int64
I64_WRAP = 2**63


def icosphere():
    return trimesh.creation.icosphere(subdivisions=2)  # 162 vertices


@pytest.fixture
def sphere():
    return icosphere()


def upload_sphere(client, sphere):
    """``POST /v1/domains`` of ``sphere`` as a mesh body; the response."""
    return client.post("/v1/domains", json={"kind": "mesh", "vertices": sphere.vertices.tolist(),
                                            "faces": sphere.faces.tolist()})


@pytest.fixture
def mesh_id(client, sphere):
    r = upload_sphere(client, sphere)
    assert r.status_code in (200, 201), r.text
    return r.json()["id"]


@pytest.fixture(scope="module")
def refusing(tmp_path_factory):
    """One app for the tests below that only post inputs refused at submission (nothing is
    stored, no job runs), with the icosphere of ``mesh_id`` uploaded once: an app's start
    costs ~0.14 CPU-s, and ~60 of them ran here. Tests whose outcome depends on what the
    store already holds keep their own ``client``."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("hostile"), queue="immediate")
    with TestClient(create_app(settings)) as client:
        r = upload_sphere(client, icosphere())
        assert r.status_code == 201, r.text
        client.mesh_id = r.json()["id"]
        yield client


@pytest.fixture
def two_spheres_id(client, sphere):
    v = np.concatenate([sphere.vertices, sphere.vertices + [5.0, 0, 0]])
    f = np.concatenate([sphere.faces, sphere.faces + len(sphere.vertices)])
    r = client.post("/v1/domains", json={"kind": "mesh", "vertices": v.tolist(),
                                         "faces": f.tolist()})
    assert r.status_code in (200, 201), r.text
    assert r.json()["components"] == 2
    return r.json()["id"]


@pytest.fixture
def grid_id(client):
    r = client.post("/v1/domains", json={"kind": "grid", "shape": [12, 12]})
    assert r.status_code in (200, 201), r.text
    return r.json()["id"]


def post_raw(client, url, text):
    return client.post(url, content=text.encode(), headers={"content-type": "application/json"})


def assert_4xx(response, field):
    assert 400 <= response.status_code < 500, response.text
    err = response.json()["error"]
    assert err["field"] == field, err
    assert "Traceback" not in err["message"] and "/work/" not in err["message"]
    return err


# -- domain bodies -------------------------------------------------------------------
@pytest.mark.parametrize(("body", "status", "field"), [
    ({"kind": "graph", "n_nodes": 3, "edges": [[0, BIG]]}, 422, "edges"),
    ({"kind": "graph", "n_nodes": 3, "edges": [[0, I64_WRAP]]}, 422, "edges"),
    ({"kind": "graph", "n_nodes": 3, "edges": [[-BIG, 1]]}, 422, "edges"),
    ({"kind": "graph", "n_nodes": 3, "edges": [[0, 1]], "weights": [-1.0]}, 422, "weights"),
    ({"kind": "graph", "n_nodes": 3, "edges": [[0, 1], [1, 2]], "weights": [1e308, 1e308]},
     422, "weights"),
    ({"kind": "graph", "n_nodes": BIG, "edges": [[0, 1]]}, 413, "n_nodes"),
    ({"kind": "graph", "n_nodes": 3, "edges": [[0, 1]], "positions": [[0, 0], [1], [2, 2]]},
     422, "positions"),
    ({"kind": "grid", "shape": [4, 4], "bounds": [[0, 1], [0, 1, 2]]}, 422, "bounds"),
    ({"kind": "grid", "shape": [4294967296, 4294967296]}, 413, "shape"),
    ({"kind": "grid", "shape": [4611686018427387905, 4]}, 413, "shape"),
    ({"kind": "grid", "shape": [BIG, 2]}, 413, "shape"),
    ({"kind": "grid", "shape": [4], "bounds": [[-1e308, 1e308]]}, 422, "bounds"),
    ({"kind": "grid", "shape": [4], "bounds": [[0, 1e-320]]}, 422, "bounds"),
    ({"kind": "pointcloud", "points": [[1.0, 2.0, 3.0]] * 50}, 422, "points"),
    ({"kind": "pointcloud", "points": [[float(i), 0.0, 0.0] for i in range(40)]}, 422,
     "points"),
    ({"kind": "pointcloud", "points": np.random.default_rng(0).random((40, 3)).tolist(),
      "n_neighbors": BIG}, 422, "n_neighbors"),
    ({"kind": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, BIG]]},
     422, "faces"),
])
def test_hostile_domain_bodies(refusing, body, status, field):
    r = refusing.post("/v1/domains", json=body)
    assert r.status_code == status, r.text
    assert_4xx(r, field)


def test_non_finite_numbers_in_domain_bodies(refusing):
    client = refusing
    r = post_raw(client, "/v1/domains", '{"kind": "pointcloud", "points": [[0, 0, Infinity],'
                 '[1, 0, 0], [0, 1, 0], [1, 1, 0]]}')
    assert_4xx(r, "points")
    r = post_raw(client, "/v1/domains", '{"kind": "graph", "n_nodes": 2, "edges": [[0, 1]], '
                 '"weights": [NaN]}')
    assert_4xx(r, "weights")
    r = post_raw(client, "/v1/domains", '{"kind": "grid", "shape": [4], "bounds": [[0, 1e400]]}')
    assert_4xx(r, "bounds")


def test_deeply_nested_json_is_a_4xx(refusing):
    client = refusing
    r = post_raw(client, "/v1/domains", "[" * 100_000 + "]" * 100_000)
    assert 400 <= r.status_code < 500, r.text
    assert r.json()["error"]["field"] == "body"


def test_mesh_with_a_vertex_at_1e308_is_refused(client, sphere):
    v = sphere.vertices.copy()
    v[0] = [0.0, 0.0, 1e308]
    r = client.post("/v1/domains", json={"kind": "mesh", "vertices": v.tolist(),
                                         "faces": sphere.faces.tolist()})
    err = assert_4xx(r, r.json()["error"]["field"])
    assert err["field"] in ("vertices", "faces")
    # large but representable coordinates are rescaled safely: finite unit areas
    r = client.post("/v1/domains", json={"kind": "mesh", "vertices": (sphere.vertices * 1e300)
                                         .tolist(), "faces": sphere.faces.tolist()})
    assert r.status_code in (200, 201), r.text


# -- mesh files ----------------------------------------------------------------------
def upload(client, name, data, **form):
    return client.post("/v1/domains", files={"file": (name, data)}, data=form)


def test_obj_face_index_zero_is_reported(refusing):
    client = refusing
    r = upload(client, "bad.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n")
    err = assert_4xx(r, "file")
    assert "index 0" in err["message"] and "line 4" in err["message"]


def _glb(doc: dict, payload: bytes = b"") -> bytes:
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text
    if payload:
        payload += b"\0" * (-len(payload) % 4)
        body += struct.pack("<II", len(payload), 0x004E4942) + payload
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


@pytest.mark.parametrize(("name", "data", "words"), [
    ("x.gltf", b"hello, not json", "JSON"),
    ("x.gltf", json.dumps({"asset": {"version": "2.0"}}).encode(), "no meshes"),
    ("x.glb", b"hello world, no header here", "header"),
    ("x.glb", _glb({"asset": {"version": "2.0"},
                    "meshes": [{"primitives": [{"attributes": {"POSITION": 5}}]}]}),
     "accessor 5"),
    ("x.gltf", json.dumps({"asset": {"version": "2.0"},
                           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
                           "accessors": [{"bufferView": 0, "count": 3, "type": "VEC3",
                                          "componentType": 5126}],
                           "bufferViews": [{"buffer": 0, "byteLength": 36}],
                           "buffers": [{"uri": "/etc/passwd", "byteLength": 36}]}).encode(),
     "not embedded"),
])
def test_gltf_errors_are_clear(refusing, name, data, words):
    client = refusing
    r = upload(client, name, data)
    err = assert_4xx(r, "file")
    assert words in err["message"]
    assert "NoneType" not in err["message"]



def test_ply_and_off_seams_are_welded(client, sphere):
    for ext in ("ply", "off"):
        v = sphere.vertices[sphere.faces.ravel()]
        f = np.arange(len(v)).reshape(-1, 3)
        data = trimesh.Trimesh(v, f, process=False).export(file_type=ext)
        if isinstance(data, str):
            data = data.encode()
        r = upload(client, f"split.{ext}", data)
        assert r.status_code in (200, 201), r.text
        out = r.json()
        assert out["n"] == len(sphere.vertices) and out["components"] == 1, out
        assert out["boundary"]["closed"]


def test_glb_equal_to_an_earlier_stl_says_it_existed(client, sphere):
    stl = sphere.export(file_type="stl")
    first = upload(client, "sphere.stl", stl)
    assert first.status_code == 201, first.text
    assert first.json()["already_existed"] is False
    # the same surface indexed as the STL's welded form (vertices in order of first use,
    # as the service keeps a file's vertex order)
    soup = trimesh.load(io.BytesIO(stl), file_type="stl", process=False)
    _, seen, inverse = np.unique(soup.vertices, axis=0, return_index=True,
                                 return_inverse=True)
    order = np.argsort(seen)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    indexed = trimesh.Trimesh(soup.vertices[seen[order]], rank[inverse.reshape(-1)][soup.faces],
                              process=False)
    glb = trimesh.Scene(indexed).export(file_type="glb")
    again = upload(client, "sphere.glb", glb)
    assert again.status_code == 200, again.text
    out = again.json()
    assert out["id"] == first.json()["id"]
    assert out["already_existed"] is True
    assert out["source"]["filename"] == "sphere.stl"
    assert out["upload"]["filename"] == "sphere.glb"
    assert "already existed" in out["warnings"][0] and "sphere.stl" in out["warnings"][0]


# -- operations ----------------------------------------------------------------------
def _job(client, domain_id, op, body, text=None):
    url = f"/v1/domains/{domain_id}/{op}"
    return post_raw(client, url, text) if text is not None else client.post(url, json=body)


def test_sparse_indices_beyond_int64(refusing):
    client, mesh_id = refusing, refusing.mesh_id
    r = _job(client, mesh_id, "distances",
             {"mu0": {"indices": [BIG], "masses": [1.0]}, "mu1": {"vertex": 0, "radius": 0.5}})
    assert_4xx(r, "mu0.indices")
    r = _job(client, mesh_id, "distances",
             {"mu0": {"indices": [-1], "masses": [1.0]}, "mu1": {"vertex": 0, "radius": 0.5}})
    assert_4xx(r, "mu0.indices")


PAIR = '"mu0": {"vertex": 0, "radius": 0.5}, "mu1": {"vertex": 5, "radius": 0.5}'


@pytest.mark.parametrize(("op", "text", "field"), [
    ("distances", '{' + PAIR + ', "gamma": Infinity}', "gamma"),
    ("distances", '{' + PAIR + ', "gamma": 1e300}', "gamma"),
    ("distances", '{' + PAIR + ', "gamma": NaN}', "gamma"),
    ("distances", '{' + PAIR + ', "gamma": 5e-324}', "gamma"),  # heat time underflows to 0
    ("propagations", '{"n_nodes": 2, "edges": [[0, 1]], "gamma": 5e-324, "fixed": [{"node": 0, '
     '"distribution": {"vertex": 0, "radius": 0.5}}]}', "gamma"),
    ("distances", '{' + PAIR + ', "tol": NaN}', "tol"),
    ("barycenters", '{"distributions": [{"vertex": 0, "radius": 0.5}], "entropy_bound": NaN}',
     "entropy_bound"),
    ("barycenters", '{"distributions": [{"vertex": 0, "radius": 0.5}], "sharpen": true, '
     '"entropy_bound": -1e308}', "entropy_bound"),
    ("barycenters", '{"distributions": [{"vertex": 0, "radius": 0.5}, {"vertex": 3, '
     '"radius": 0.5}], "weights": [1, NaN]}', "weights"),
    ("barycenters", '{"distributions": [{"vertex": 0, "radius": 0.5}, {"vertex": 3, '
     '"radius": 0.5}], "weights": [1, -1]}', "weights"),
    ("interpolations", '{' + PAIR + ', "times": [0.5, NaN]}', "times"),
    ("flows", '{' + PAIR + ', "basis": "spectral", "k": 1e9}', "k"),
    ("flows", '{' + PAIR + ', "basis": "spectral"}', "k"),
    ("pointwise-distances", '{"source": 0, "k": 1000000000}', "k"),
    ("distances", '{"mu0": {"vertex": 0, "radius": Infinity}, "mu1": {"vertex": 1, '
     '"radius": 1}}', "mu0.radius"),
    ("distances", '{"mu0": {"indices": [0], "masses": [Infinity]}, "mu1": {"vertex": 1, '
     '"radius": 1}}', "mu0.masses"),
])
def test_hostile_scalars(refusing, op, text, field):
    client, mesh_id = refusing, refusing.mesh_id
    assert_4xx(_job(client, mesh_id, op, None, text), field)


FIX = {"distribution": {"vertex": 0, "radius": 0.5}}


@pytest.mark.parametrize(("extra", "field"), [
    ({"edges": [[0, 1]], "edge_weights": [-1.0]}, "edge_weights"),
    ({"edges": [[0, 1]], "edge_weights": [0.0]}, "edge_weights"),
    ({"edges": [[0, 1]], "edge_weights": [1.0, 2.0]}, "edge_weights"),
    ({"edges": [[0, BIG]]}, "edges"),
    ({"edges": [[0, 1]], "n_nodes": 3}, "edges"),  # node 2 reaches no fixed node
    ({"edges": [[0, 0]]}, "edges"),
    ({"edges": []}, "edges"),
    ({"edges": [[0, 1]], "n_nodes": 1}, "n_nodes"),
])
def test_hostile_propagations(refusing, extra, field):
    client, mesh_id = refusing, refusing.mesh_id
    body = {"n_nodes": 2, "fixed": [{"node": 0, **FIX}], **extra}
    assert_4xx(_job(client, mesh_id, "propagations", body), field)


def test_nan_edge_weight_in_propagation(refusing):
    client, mesh_id = refusing, refusing.mesh_id
    text = ('{"n_nodes": 2, "edges": [[0, 1]], "edge_weights": [NaN], "fixed": [{"node": 0, '
            '"distribution": {"vertex": 0, "radius": 0.5}}]}')
    assert_4xx(_job(client, mesh_id, "propagations", None, text), "edge_weights")


def test_component_mismatch_of_1e7_is_refused_at_submission(client, two_spheres_id, sphere):
    n = 2 * len(sphere.vertices)
    half = len(sphere.vertices)
    mu0 = np.zeros(n)
    mu0[0], mu0[half] = 0.5, 0.5
    mu1 = np.zeros(n)
    mu1[1], mu1[half + 1] = 0.5 + 1e-7, 0.5 - 1e-7
    for op in ("distances", "flows"):
        r = _job(client, two_spheres_id, op, {"mu0": mu0.tolist(), "mu1": mu1.tolist()})
        assert_4xx(r, "mu1")
    # equal component masses pass and the job runs
    mu1[1], mu1[half + 1] = 0.5, 0.5
    r = _job(client, two_spheres_id, "distances", {"mu0": mu0.tolist(), "mu1": mu1.tolist()})
    assert r.json()["state"] == "succeeded", r.text


def test_job_memory_bound_is_enforced_at_submission(make_client):
    client = make_client(job_memory_bytes=2**20)
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [40, 40]}).json()["id"]
    dists = [{"vertex": i, "radius": 0.2} for i in range(0, 1600, 50)]
    r = _job(client, grid, "barycenters", {"distributions": dists})
    assert r.status_code == 413, r.text
    assert_4xx(r, "distributions")
    # a small job on the same domain passes
    r = _job(client, grid, "distances", {"mu0": {"vertex": 0, "radius": 0.2},
                                         "mu1": {"vertex": 40, "radius": 0.2}})
    assert r.status_code in (200, 202), r.text


def test_gamma_bound_is_the_librarys(client, grid_id):
    from solvers.domains import Grid
    from solvers.validation import GAMMA_MAX_FACTOR, check_gamma

    extent = Grid([12, 12]).extent
    top = GAMMA_MAX_FACTOR * extent**2
    check_gamma(0.99 * top, extent)
    r = _job(client, grid_id, "distances", {"mu0": {"vertex": 0, "radius": 0.3},
                                            "mu1": {"vertex": 5, "radius": 0.3},
                                            "gamma": 1.01 * top})
    assert_4xx(r, "gamma")


def test_job_errors_carry_no_exception_text():
    from service.errors import error_dict

    err = error_dict(ValueError("secret /srv/otgeo/data/x.npz"))
    assert err["code"] == "internal_error" and "/srv" not in err["message"]
    assert "ValueError" not in err["message"]
    err = error_dict(RuntimeError("Matrix is not positive definite!"))
    assert err["code"] == "numerical_error" and "Matrix" not in err["message"]
    err = error_dict(MemoryError())
    assert err["code"] == "out_of_memory"


def test_log_kernel_work_is_bounded_for_huge_dynamic_ranges(sphere):
    """Sharpening towards an extreme entropy bound gave log-scalings spanning ~1e7 nats:
    the banded log-kernel built ~range/band columns per call (13 GB); now at most
    MAX_BANDS occupied bands per column, with the same result on normal ranges."""
    from solvers.convolutional.common import MAX_BANDS, LogKernel
    from solvers.domains import TriangleMesh

    mesh = TriangleMesh(sphere.vertices, sphere.faces)
    logk = LogKernel(mesh.heat_kernel(0.01))
    rng = np.random.default_rng(1)
    x = rng.uniform(-1e7, 0.0, size=(mesh.n, 2))
    out = logk(x)
    assert logk.columns <= 2 * MAX_BANDS
    assert not np.any(np.isnan(out)) and np.all(out <= x.max(axis=0) + 1.0)
    # moderate range (several bands): equal to the direct log-sum-exp of the kernel
    y = rng.uniform(-2000.0, 0.0, size=mesh.n)
    dense = mesh.heat_kernel(0.01).apply(np.eye(mesh.n))
    top = y.max()
    direct = np.log(dense @ np.exp(y - top)) + top
    np.testing.assert_allclose(logk(y), direct, rtol=1e-10, atol=1e-8)


def test_worker_memory_limit_keeps_solvers_working():
    """RLIMIT_AS at base + cache + one job: numba kernels and cholespy factorizations
    still run (BLAS pinned to one thread), and an allocation beyond it is a MemoryError,
    reported on the job as out_of_memory."""
    import os
    import subprocess
    import sys

    code = """
import numpy as np
from service.limits import limit_worker_memory
from service.settings import Settings
from service.errors import error_dict
limit = limit_worker_memory(Settings(cache_bytes=2**28, job_memory_bytes=2**28))
from solvers.domains import Grid, TriangleMesh
import trimesh
s = trimesh.creation.icosphere(subdivisions=3)
mesh = TriangleMesh(s.vertices, s.faces)
from solvers.emd import pointwise_distances
from solvers.convolutional import wasserstein_distance
d = pointwise_distances(mesh, 0).distances
m0 = np.zeros(mesh.n); m0[0] = 1; m1 = np.zeros(mesh.n); m1[5] = 1
v = wasserstein_distance(mesh, m0, m1, gamma=0.05).value
try:
    np.ones(limit // 8 + 1)
    print("NO-LIMIT")
except MemoryError as exc:
    print("LIMIT", limit, error_dict(exc)["code"], float(d.max()) > 0, v > 0)
"""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[0] == "LIMIT", out.stdout
    assert out.stdout.split()[2:] == ["out_of_memory", "True", "True"], out.stdout


@pytest.mark.parametrize(("name", "data"), [
    ("huge.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\n"
     b"property float x\nproperty float y\nproperty float z\nelement face 1\n"
     b"property list uchar int vertex_indices\nend_header\n" + b"\0" * 100),
    ("huge.off", b"OFF\n3000000000 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
    ("count.stl", b"\0" * 80 + (10**9).to_bytes(4, "little") + b"\0" * 50),
    ("big.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999999\n"),
    ("neg.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n"),
    ("text.glb", b"v 0 0 0\n"),
])
def test_hostile_mesh_files(refusing, name, data):
    client = refusing
    r = upload(client, name, data)
    err = assert_4xx(r, "file")
    assert "Error" not in err["message"]  # no exception class names or texts


def test_weld_option_of_the_library(sphere):
    from solvers.domains import load_mesh

    v = sphere.vertices[sphere.faces.ravel()]
    f = np.arange(len(v)).reshape(-1, 3)
    data = trimesh.Trimesh(v, f, process=False).export(file_type="ply")
    assert load_mesh(data, "ply").n == len(sphere.vertices)
    split = load_mesh(data, "ply", weld=False)
    assert split.n == len(v) and split.n_components == len(sphere.faces)
    obj = trimesh.Trimesh(v, f, process=False).export(file_type="obj").encode()
    assert load_mesh(obj, "obj").n == len(v)  # OBJ: position indices only by default
    assert load_mesh(obj, "obj", weld=True).n == len(sphere.vertices)


def test_weld_form_values():
    from service.domains import parse_weld
    from service.errors import InvalidInput

    assert parse_weld("true") is True and parse_weld("0") is False
    assert parse_weld(None) is None and parse_weld("auto") is None
    with pytest.raises(InvalidInput) as info:
        parse_weld("sometimes")
    assert info.value.field == "weld"


@pytest.mark.parametrize("metric", ["w2", "w1"])
@pytest.mark.parametrize("peak", [1.7e308, 5e-324])
def test_masses_near_the_float_limits_normalize_like_ones(client, mesh_id, metric, peak):
    """Masses whose sum overflows (1.7e308 each) gave a 500 (inf sum, zero masses, then the
    LP's own assertion or a segfault); subnormal ones (5e-324) are as valid: both are the
    same distribution as ones, with the total and scale beyond the float range as null."""
    def distance(mu0):
        body = {"mu0": mu0, "mu1": {"vertex": 5, "radius": 0.5}, "metric": metric}
        r = client.post(f"/v1/domains/{mesh_id}/distances", json=body)
        assert r.status_code in (200, 201), r.text
        assert r.json()["state"] == "succeeded", r.text
        return client.get(f"/v1/jobs/{r.json()['id']}/result").json()["values"]

    ones = distance({"indices": [1, 2], "masses": [1.0, 1.0]})
    for mu0 in ({"indices": [1, 2], "masses": [peak, peak]},
                [peak if i in (1, 2) else 0.0 for i in range(162)]):
        values = distance(mu0)
        assert values["value"] == pytest.approx(ones["value"], rel=1e-9)
        report = values["normalization"][0]
        assert report["normalized"] is True
        if peak > 1:
            assert report["given_total"] is None and report["scale"] == pytest.approx(0.5 / peak)
        else:
            assert report["given_total"] == 2 * peak and report["scale"] is None
