"""Large domains are built and stored by the memory-bounded builder process; the API gets
their metadata, and a build beyond the bound is a 413 naming the upload's size field."""

from __future__ import annotations

import numpy as np
from service_testing import assert_error, upload_mesh

from service import domain_builder, domains


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

    monkeypatch.setattr(domains, "IN_PROCESS_POINTS", 100)
    monkeypatch.setattr(domains, "build_in_child", spy)
    child = client.post("/v1/domains", json=body)
    assert child.status_code == 201, child.text
    assert calls == ["spec"]
    assert child.json()["id"] == here.json()["id"]  # the same content-addressed domain
    assert child.json()["summary"] == here.json()["summary"]
    again = client.post("/v1/domains", json=body)
    assert again.status_code == 200 and again.json()["id"] == here.json()["id"]
    # errors found by the builder keep their field
    monkeypatch.setattr(domains, "IN_PROCESS_POINTS", 2)
    bad = {"kind": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 7]]}
    assert_error(client.post("/v1/domains", json=bad), 422, "faces")


def test_large_mesh_file_is_built_in_the_child(client, monkeypatch, meshes_dir):
    monkeypatch.setattr(domains, "IN_PROCESS_FILE_BYTES", 1000)
    r = upload_mesh(client, meshes_dir / "woody.obj")
    assert r.status_code == 201, r.text
    assert r.json()["summary"]["vertices"] == 694
    job = client.post(f"/v1/domains/{r.json()['id']}/distances?wait=30",
                      json={"mu0": {"vertex": 0, "radius": 0.3},
                            "mu1": {"vertex": 500, "radius": 0.3}}).json()
    assert job["state"] == "succeeded", job


def test_build_beyond_the_memory_bound_is_413(make_client, monkeypatch):
    """With the builder's address space capped just above its baseline, a 400k-point cloud
    (a k-NN graph and Laplacian of several hundred MB) cannot be built: 413 naming points."""
    client = make_client(job_memory_bytes=256 * 2**20)
    monkeypatch.setattr(domains, "IN_PROCESS_POINTS", 100)
    # the estimate at the door would refuse it first: the builder's bound is the backstop
    monkeypatch.setattr(domains, "check_build_memory", lambda *args: None)
    r = client.post("/v1/domains", json=_cloud(400_000))
    assert_error(r, 413, "points")
    small = client.post("/v1/domains", json=_cloud(500))  # a fresh builder takes the next one
    assert small.status_code == 201, small.text


def test_domain_too_large_to_build_is_413_at_the_door(make_client, monkeypatch):
    """A JSON domain whose estimated build (domain_builder.estimate_build_bytes) exceeds
    OTGEO_JOB_MEMORY_BYTES is refused with 413 naming its size field, before any build."""
    client = make_client(job_memory_bytes=32 * 2**20)
    built = []

    async def no_child(*args, **kwargs):
        built.append("child")
        raise AssertionError("built in the child")

    monkeypatch.setattr(domains, "build_in_child", no_child)
    monkeypatch.setattr(domains, "build_domain", lambda *a: built.append("here"))
    big_cloud = _cloud(20_000)  # 20k points x 30 neighbors x 400 B = 229 MiB
    assert domain_builder.estimate_build_bytes(_spec(big_cloud)) > 32 * 2**20
    err = assert_error(client.post("/v1/domains", json=big_cloud), 413, "points",
                       "payload_too_large")
    assert "OTGEO_JOB_MEMORY_BYTES" in err["message"]
    ring = np.arange(600_000)  # 38 MB
    graph = {"kind": "graph", "n_nodes": len(ring),
             "edges": np.stack([ring[:-1], ring[1:]], 1).tolist()}
    assert_error(client.post("/v1/domains", json=graph), 413, "n_nodes")
    side = 300  # 90k vertices: 100 MB
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
    ok = client.post("/v1/domains", json=_cloud(2_000))  # 23 MiB: built
    assert ok.status_code == 201, ok.text


def _spec(body: dict):
    from pydantic import TypeAdapter

    from service.schemas import DomainSpec

    return TypeAdapter(DomainSpec).validate_python(body)
