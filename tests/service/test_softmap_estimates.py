"""Soft maps: the queue choice and the memory bound count samples and target points."""

from __future__ import annotations

import numpy as np
import trimesh
from service_testing import assert_error, upload_mesh

from service.operations.softmaps import LOG_STEP_COST, SoftMapRequest, estimate_sizes

LANDMARKS = [{"source": 0, "target": 0}, {"source": 40, "target": 40}]
NEFERTITI = 49_971  # vertices


def _sphere(tmp_path, name, scale=(1.0, 1.0, 1.0)):
    s = trimesh.creation.icosphere(subdivisions=2)
    s.vertices = s.vertices * np.asarray(scale)
    path = tmp_path / name
    path.write_text(trimesh.exchange.obj.export_obj(s))
    return path


def test_the_issue_soft_map_is_long_and_above_its_measured_peak():
    """859 samples on nefertiti at full resolution peaked at ~4.4 GiB and ran 429 s: the
    estimate is at least that peak (so 413 under the 4 GiB default) and the job is long."""
    req = SoftMapRequest(source_id="a" * 16, target_id="b" * 16, samples=859, target_points=None,
                         landmarks=LANDMARKS)
    sizes = estimate_sizes(NEFERTITI, NEFERTITI, req)
    assert sizes["bytes"] >= 4.4 * 2**30
    assert sizes["cost"] >= 100 * 5e7
    coarse = estimate_sizes(NEFERTITI, NEFERTITI, req.model_copy(update={"target_points":
                                                                         "auto"}))
    assert coarse["bytes"] < sizes["bytes"] / 5 and coarse["cost"] < sizes["cost"] / 10


def test_queue_follows_samples_and_sweeps(make_client, tmp_path):
    client = make_client(queue="sqlite", workers=0, long_job_cost=5e5 * LOG_STEP_COST)
    a = upload_mesh(client, _sphere(tmp_path, "a.obj")).json()["id"]
    b = upload_mesh(client, _sphere(tmp_path, "b.obj", (1.2, 1.0, 0.8))).json()["id"]
    body = {"source_id": a, "target_id": b, "landmarks": LANDMARKS, "k": 20,
            "target_points": None}
    # 3 edges x 100 samples x 162 target points per sweep: 48,600 log-domain steps (was:
    # 162 x max_iter), LOG_STEP_COST cost units each
    short = client.post("/v1/soft-maps", json={**body, "samples": 100, "max_iter": 5}).json()
    assert short["queue"] == "short", short
    long = client.post("/v1/soft-maps", json={**body, "samples": 100, "max_iter": 20}).json()
    assert long["queue"] == "long", long


def test_memory_bound_counts_the_target_resolution(make_client, tmp_path):
    client = make_client(job_memory_bytes=4 * 2**20)
    a = upload_mesh(client, _sphere(tmp_path, "a.obj")).json()["id"]
    b = upload_mesh(client, _sphere(tmp_path, "b.obj", (1.2, 1.0, 0.8))).json()["id"]
    body = {"source_id": a, "target_id": b, "landmarks": LANDMARKS, "k": 20,
            "samples": 160, "target_points": None, "n_energies": 1000}
    assert_error(client.post("/v1/soft-maps", json=body), 413, "samples")
