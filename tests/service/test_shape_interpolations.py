"""POST /v1/shape-interpolations (thesis §3.7): frames of translated balls lie in between.

Ground truth: the W2 barycenter of a shape and its translate is the shape translated by the
interpolated offset (centroid at (1 - t) c0 + t c1, same volume)."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh
from PIL import Image
from service_testing import assert_error, upload_mesh

from service.export import parse_glb
from service.operations.shapes import ShapeInterpolationValues


def _upload(client, tmp_path, mesh, name):
    path = tmp_path / name
    path.write_text(trimesh.exchange.obj.export_obj(mesh))
    return upload_mesh(client, path).json()["id"]


@pytest.fixture
def balls(client, tmp_path):
    ball = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    moved = ball.copy()
    moved.apply_translation([3.0, 0.0, 0.0])
    box = trimesh.creation.box(extents=[1.5, 1.5, 1.5])
    box.apply_translation([1.5, 2.0, 0.0])
    return [_upload(client, tmp_path, m, f"{n}.obj") for n, m in
            (("ball", ball), ("moved", moved), ("box", box))], ball


def test_two_shapes_frames_move_linearly(client, balls):
    ids, ball = balls
    body = {"shapes": ids[:2], "times": [0.0, 0.5, 1.0], "resolution": 24}
    r = client.post("/v1/shape-interpolations?wait=60", json=body)
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    job = r.json()["id"]
    v = client.get(f"/v1/jobs/{job}/result").json()["values"]
    ShapeInterpolationValues.model_validate(v)
    assert v["converged"] and len(v["frames"]) == 3
    for frame, t in zip(v["frames"], [0.0, 0.5, 1.0], strict=True):
        assert frame["time"] == t and frame["weights"] == pytest.approx([1 - t, t])
        np.testing.assert_allclose(frame["centroid"], [3.0 * t, 0.0, 0.0], atol=0.1 * v["cell"])
        assert frame["enclosed_volume"] == pytest.approx(ball.volume, rel=2e-3)
    doc, _ = parse_glb(client.get(f"/v1/jobs/{job}/result.glb").content)
    assert [n["name"] for n in doc["nodes"]] == ["t=0", "t=0.5", "t=1"]
    png = client.get(f"/v1/jobs/{job}/files/frames.png")
    assert png.status_code == 200
    img = np.asarray(Image.open(io.BytesIO(png.content)))
    assert img.ndim == 3 and (img < 250).any()


def test_three_shapes_default_frames(client, balls):
    ids, _ = balls
    r = client.post("/v1/shape-interpolations?wait=60",
                    json={"shapes": ids, "resolution": 20, "view_axis": "x"})
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    v = client.get(f"/v1/jobs/{r.json()['id']}/result").json()["values"]
    weights = [f["weights"] for f in v["frames"]]
    assert weights[:3] == [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    assert weights[3] == pytest.approx([1 / 3] * 3)
    centroids = np.array([f["centroid"] for f in v["frames"]])
    # the uniform barycenter of translated solids sits near the mean of their centroids
    np.testing.assert_allclose(centroids[3], centroids[:3].mean(axis=0), atol=2 * v["cell"])


def test_bad_requests_are_refused(client, balls, tmp_path, make_client):
    ids, _ = balls
    cases = [({"shapes": [ids[0]]}, "shapes"),
             ({"shapes": ids, "times": [0.5]}, "times"),
             ({"shapes": ids[:2], "times": [1.5]}, "times[0]"),
             ({"shapes": ids[:2], "weights": [[1, -1]]}, "weights[0]"),
             ({"shapes": ids[:2], "weights": [[1, 0, 0]]}, "weights[0]"),
             ({"shapes": [ids[0], "0" * 64]}, "shapes[1]")]
    for body, field in cases:
        assert_error(client.post("/v1/shape-interpolations", json=body),
                     404 if field == "shapes[1]" else 422, field)
    grid = client.post("/v1/domains", json={"kind": "graph", "n_nodes": 3,
                                             "edges": [[0, 1], [1, 2]]}).json()["id"]
    assert_error(client.post("/v1/shape-interpolations", json={"shapes": [ids[0], grid]}),
                 422, "shapes[1]", "unsupported_operation")
    box = trimesh.creation.box()
    opened = trimesh.Trimesh(box.vertices, box.faces[1:])
    open_id = _upload(client, tmp_path, opened, "open.obj")
    assert_error(client.post("/v1/shape-interpolations", json={"shapes": [ids[0], open_id]}),
                 422, "shapes[1]", "unsupported_operation")
    small = make_client(job_memory_bytes=2**20, data_dir=client.app.state.runtime.settings
                        .data_dir)
    assert_error(small.post("/v1/shape-interpolations",
                            json={"shapes": ids[:2], "resolution": 64}), 413, "resolution")
