"""Large domains are built and stored by the memory-bounded builder process; the API gets
their metadata, and a build beyond the bound is a 413 naming the upload's size field."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from service_testing import assert_error, upload_mesh

from service import domain_builder, domains
from service.mesh_sizes import mesh_file_counts


def _cloud(n: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return {"kind": "pointcloud", "points": rng.normal(size=(n, 3)).tolist()}


def test_large_json_domain_is_built_in_the_child(client, monkeypatch):
    body = _cloud(300)
    here = client.post("/v1/domains", json=body)
    assert here.status_code == 201, here.text
    client.delete(f"/v1/domains/{here.json()['id']}")
    calls = []
    original = domain_builder.build_in_child

    async def spy(*args, **kwargs):
        calls.append(args[1])
        return await original(*args, **kwargs)

    monkeypatch.setattr(domains, "IN_PROCESS_BUILD_BYTES", 1000)
    monkeypatch.setattr(domains, "build_in_child", spy)
    child = client.post("/v1/domains", json=body)
    assert child.status_code == 201, child.text
    assert calls == ["spec"]
    assert child.json()["id"] == here.json()["id"]  # the same content-addressed domain
    assert child.json()["summary"] == here.json()["summary"]
    again = client.post("/v1/domains", json=body)
    assert again.status_code == 200 and again.json()["id"] == here.json()["id"]
    # errors found by the builder keep their field
    monkeypatch.setattr(domains, "IN_PROCESS_BUILD_BYTES", 0)
    bad = {"kind": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 7]]}
    assert_error(client.post("/v1/domains", json=bad), 422, "faces")


def test_large_mesh_file_is_built_in_the_child(client, monkeypatch, meshes_dir):
    monkeypatch.setattr(domains, "IN_PROCESS_BUILD_BYTES", 1000)
    r = upload_mesh(client, meshes_dir / "woody.obj")
    assert r.status_code == 201, r.text
    assert r.json()["summary"]["vertices"] == 694
    job = client.post(f"/v1/domains/{r.json()['id']}/distances?wait=30",
                      json={"mu0": {"vertex": 0, "radius": 0.3},
                            "mu1": {"vertex": 500, "radius": 0.3}}).json()
    assert job["state"] == "succeeded", job


def test_build_beyond_the_memory_bound_is_413(make_client, monkeypatch):
    """With the builder's address space capped just above its baseline (an interpreter
    allowance of 1 GiB instead of WORKER_BASE_BYTES plus a 1 MiB job: the child imports in
    about 0.6 GB, and a 30k-point cloud still builds in the rest), a 100k-point cloud (a k-NN
    graph and Laplacian of several hundred MB) cannot be built: 413 naming points. (A job
    allowance of 256 MiB needed a 200k-point cloud: 3x the wall time, most of it the child's
    k-NN work before its allocation failed.)"""
    assert domain_builder.WORKER_BASE_BYTES > 2**30  # lowered below, never raised
    monkeypatch.setattr(domain_builder, "WORKER_BASE_BYTES", 2**30)
    client = make_client(job_memory_bytes=2**20)
    # the estimate at the door would refuse it first: the builder's bound is the backstop
    monkeypatch.setattr(domains, "check_build_memory", lambda *args: None)
    r = client.post("/v1/domains", json=_cloud(100_000))
    assert "a domain build may use" in assert_error(r, 413, "points")["message"]  # the bound
    small = client.post("/v1/domains", json=_cloud(500))  # a fresh builder takes the next one
    assert small.status_code == 201, small.text


def test_domain_too_large_to_build_is_413_at_the_door(make_client, monkeypatch):
    """A JSON domain whose estimated build (domain_builder.estimate_build_bytes) exceeds
    OTGEO_JOB_MEMORY_BYTES is refused with 413 naming its size field, before any build."""
    client = make_client(job_memory_bytes=4 * 2**20)  # the door compares estimates only
    built = []

    async def no_child(*args, **kwargs):
        built.append("child")
        raise AssertionError("built in the child")

    monkeypatch.setattr(domains, "build_in_child", no_child)
    monkeypatch.setattr(domains, "build_domain", lambda *a: built.append("here"))
    big_cloud = _cloud(2_000)  # 2k points x 30 neighbors x 400 B = 23 MiB
    assert domain_builder.estimate_build_bytes(_spec(big_cloud)) > 4 * 2**20
    err = assert_error(client.post("/v1/domains", json=big_cloud), 413, "points",
                       "payload_too_large")
    assert "OTGEO_JOB_MEMORY_BYTES" in err["message"]
    ring = np.arange(100_000)  # 6.1 MiB
    graph = {"kind": "graph", "n_nodes": len(ring),
             "edges": np.stack([ring[:-1], ring[1:]], 1).tolist()}
    assert_error(client.post("/v1/domains", json=graph), 413, "n_nodes")
    side = 60  # 3,600 vertices, 7,000 faces: 5.4 MiB
    y, x = np.mgrid[0:side, 0:side]
    idx = (y[:-1, :-1] * side + x[:-1, :-1]).ravel()
    mesh = {"kind": "mesh", "vertices": np.stack([x.ravel(), y.ravel(), 0 * x.ravel()],
                                                 1).tolist(),
            "faces": np.concatenate([np.stack([idx, idx + 1, idx + side], 1),
                                     np.stack([idx + 1, idx + side + 1, idx + side], 1)]
                                    ).tolist()}
    assert_error(client.post("/v1/domains", json=mesh), 413, "vertices")
    assert built == []
    monkeypatch.undo()
    ok = client.post("/v1/domains", json=_cloud(300))  # 3.4 MiB: built
    assert ok.status_code == 201, ok.text


def _spec(body: dict):
    from pydantic import TypeAdapter

    from service.schemas import DomainSpec

    return TypeAdapter(DomainSpec).validate_python(body)


# -- issue 44 item 13: every sizeable build in the child, files sized from their headers ----
def _spy_child(monkeypatch) -> list:
    calls = []
    original = domain_builder.build_in_child

    async def spy(*args, **kwargs):
        calls.append(args[1])
        return await original(*args, **kwargs)

    monkeypatch.setattr(domains, "build_in_child", spy)
    return calls


def _grid_mesh(side: int) -> trimesh.Trimesh:
    y, x = np.mgrid[0:side, 0:side].astype(float)
    idx = (np.arange(side - 1)[:, None] * side + np.arange(side - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([idx, idx + 1, idx + side], 1),
                            np.stack([idx + 1, idx + side + 1, idx + side], 1)])
    return trimesh.Trimesh(np.stack([x.ravel(), y.ravel(), np.sin(x.ravel())], 1), faces,
                           process=False)


def test_sizeable_builds_run_in_the_child_by_their_estimate(client, monkeypatch):
    """By default a 3,000-point cloud (about 36 MB to build) and a 1 MB PLY of 22,500
    vertices (about 40 MB) are built in the builder process, not in the API; a small grid
    and a small mesh file stay in the API process."""
    calls = _spy_child(monkeypatch)
    assert client.post("/v1/domains", json={"kind": "grid", "shape": [40, 40]}
                       ).status_code == 201
    small = _grid_mesh(20).export(file_type="ply")
    r = client.post("/v1/domains/upload", files={"file": ("small.ply", small)})
    assert r.status_code == 201, r.text
    assert calls == []
    assert client.post("/v1/domains", json=_cloud(3_000)).status_code == 201
    assert calls == ["spec"]
    ply = _grid_mesh(150).export(file_type="ply")
    assert len(ply) < 2 * 2**20
    r = client.post("/v1/domains/upload", files={"file": ("grid.ply", ply)})
    assert r.status_code == 201, r.text
    assert r.json()["summary"]["vertices"] == 150 * 150
    assert calls == ["spec", "file"]


def test_mesh_file_is_sized_from_its_header_before_any_build(make_client, monkeypatch,
                                                             meshes_dir):
    """A PLY declaring more vertices than OTGEO_MAX_VERTICES, or a file whose declared counts
    need more than OTGEO_JOB_MEMORY_BYTES to build, is refused with 413 naming the file,
    without being parsed or built."""
    def no_build(*args, **kwargs):
        raise AssertionError("built")

    monkeypatch.setattr(domains, "build_in_child", no_build)
    monkeypatch.setattr(domains, "build_mesh_file", no_build)
    client = make_client(max_vertices=1_000_000)
    header = (b"ply\nformat binary_little_endian 1.0\nelement vertex 2100000\n"
              b"property float x\nproperty float y\nproperty float z\nelement face 4200000\n"
              b"property list uchar int vertex_indices\nend_header\n") + bytes(1000)
    err = assert_error(client.post("/v1/domains/upload", files={"file": ("big.ply", header)}),
                       413, "file")
    assert "2100000" in err["message"] and "1000000" in err["message"]
    client = make_client(job_memory_bytes=2**20)  # woody: 694 vertices, about 1.2 MB
    err = assert_error(upload_mesh(client, meshes_dir / "woody.obj"), 413, "file")
    assert "OTGEO_JOB_MEMORY_BYTES" in err["message"]


@pytest.mark.parametrize("ext", ["ply", "obj", "off", "stl", "glb", "gltf"])
def test_mesh_file_counts_match_the_file(ext):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    data = sphere.export(file_type=ext)
    data = data.encode() if isinstance(data, str) else data
    if ext == "gltf":  # a dict of files: the .gltf with its buffers embedded
        data = trimesh.exchange.gltf.export_gltf(sphere, embed_buffers=True)["model.gltf"]
    vertices, faces = len(sphere.vertices), len(sphere.faces)
    expected = (faces // 2, faces) if ext == "stl" else (vertices, faces)
    assert mesh_file_counts(data, ext) == expected
    if ext == "stl":  # ASCII too
        ascii_stl = trimesh.exchange.stl.export_stl_ascii(sphere).encode()
        assert mesh_file_counts(ascii_stl, "stl") == expected
    assert mesh_file_counts(b"garbage", ext) in (None, (0, 0))


def test_builder_child_is_replaced_when_left_large(client, monkeypatch):
    """A builder child resident above RECYCLE_RSS_BYTES after a build is retired (a fresh
    one takes the next build), so a large build's memory does not stay."""
    monkeypatch.setattr(domains, "IN_PROCESS_BUILD_BYTES", 0)
    monkeypatch.setattr(domain_builder, "RECYCLE_RSS_BYTES", 2**40)
    assert client.post("/v1/domains", json=_cloud(200)).status_code == 201
    assert domain_builder.BUILDER.active  # kept: below the bound
    monkeypatch.setattr(domain_builder, "RECYCLE_RSS_BYTES", 0)
    assert client.post("/v1/domains", json=_cloud(200, seed=1)).status_code == 201
    assert not domain_builder.BUILDER.active  # retired
    assert client.post("/v1/domains", json=_cloud(200, seed=2)).status_code == 201


def test_large_upload_is_hashed_and_sized_off_the_event_loop(client, monkeypatch):
    """Hashing an 80 MB upload (for Idempotency-Key) and counting an OBJ's lines take tenths
    of a second: they run in the thread pool, not on the loop that answers /healthz."""
    import asyncio
    import hashlib
    import types

    from service.api import domains as domains_api

    on_loop = []

    def running_loop() -> bool:
        try:
            asyncio.get_running_loop()
            return True
        except RuntimeError:
            return False

    def sha256(data):
        on_loop.append(("sha256", len(data), running_loop()))
        return hashlib.sha256(data)

    def counts(data, ext):
        on_loop.append(("counts", len(data), running_loop()))
        return mesh_file_counts(data, ext)

    monkeypatch.setattr(domains_api, "hashlib", types.SimpleNamespace(sha256=sha256))
    monkeypatch.setattr(domains, "mesh_file_counts", counts)
    obj = _grid_mesh(150).export(file_type="obj").encode()
    assert len(obj) > 2**20
    r = client.post("/v1/domains/upload", files={"file": ("grid.obj", obj)})
    assert r.status_code == 201, r.text
    assert [c for c in on_loop if c[1] > 2**20 and c[2]] == [], on_loop
    assert {c[0] for c in on_loop} == {"sha256", "counts"}
