"""POST /v1/color-transfers: multipart images -> job -> JSON metrics and image files."""

from __future__ import annotations

import io
import json
import struct
import zlib

import numpy as np
import pytest
from PIL import Image
from skimage import data

from solvers.color import read_image, write_image


def png(arr) -> bytes:
    return write_image(np.ascontiguousarray(arr), "png")


@pytest.fixture(scope="module")
def photos():
    return {"coffee": np.ascontiguousarray(data.coffee()[::4, ::4]),      # 100 x 150
            "astronaut": np.ascontiguousarray(data.astronaut()[::4, ::4]),  # 128 x 128
            "chelsea": np.ascontiguousarray(data.chelsea()[::3, ::3])}      # 100 x 151


def post(client, files, wait=30, **form):
    parts = [("images", (name, content, "application/octet-stream")) for name, content in files]
    return client.post(f"/v1/color-transfers?wait={wait}", files=parts,
                       data={k: (json.dumps(v) if isinstance(v, list) else str(v))
                             for k, v in form.items()})


def assert_error(resp, status, field):
    assert resp.status_code == status, resp.text
    body = resp.json()["error"]
    assert body["field"] == field, body
    return body


def test_transfer_sequence_with_files(client, photos):
    src, tgt = photos["coffee"], photos["astronaut"]
    r = post(client, [("a.png", png(src)), ("b.png", png(tgt))],
             alphas=[[1, 0], [0.5, 0.5], [0, 1]], bins=64, gamma=32, mode="barycentric")
    assert r.status_code == 200, r.text
    job = r.json()
    assert job["state"] == "succeeded", job
    res = client.get(f"/v1/jobs/{job['id']}/result").json()
    v = res["values"]
    assert v["converged"] and v["iterations"] > 0 and v["residual"] <= 1e-4
    assert len(v["outputs"]) == 6 and v["barycenter_pictures"] == [
        "barycenter-0.png", "barycenter-1.png", "barycenter-2.png"]
    assert np.asarray(res["arrays"]["barycenters"]).shape == (3, 64 * 64)
    listed = res["files"]
    for out in v["outputs"]:
        f = client.get(f"/v1/jobs/{job['id']}/files/{out['file']}")
        assert f.status_code == 200 and f.headers["content-type"] == "image/png"
        assert listed[out["file"]]["bytes"] == len(f.content)
        img = read_image(f.content)
        shape = (src if out["image_index"] == 0 else tgt).shape
        assert img.shape == shape and (out["height"], out["width"]) == shape[:2]
    # image 0 at alpha (0, 1) moved its mean chroma towards image 1's
    o = {(x["alpha_index"], x["image_index"]): x for x in v["outputs"]}
    before = np.array(o[(2, 0)]["mean_ab_before"])
    after = np.array(o[(2, 0)]["mean_ab_after"])
    target = np.array(o[(0, 1)]["mean_ab_before"])
    assert np.linalg.norm(after - target) < 0.5 * np.linalg.norm(before - target)
    pic = client.get(f"/v1/jobs/{job['id']}/files/barycenter-1.png")
    assert read_image(pic.content).shape == (64, 64, 3)


def test_split_default_with_histograms(client, photos):
    src, tgt = photos["coffee"], photos["chelsea"]
    r = post(client, [("a.png", png(src)), ("b.png", png(tgt))], weights=[0, 1], recolor=[0])
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    jid = r.json()["id"]
    v = client.get(f"/v1/jobs/{jid}/result").json()["values"]
    assert v["mode"] == "split" and v["bins"] == 65 and v["regularization"] > 0
    assert v["converged"] and v["residual"] < 1e-9 and v["iterations"] == 0
    assert [(p["image_index"], p["target"]) for p in v["plans"]] == [(0, "1")]
    assert v["plans"][0]["cost"] > 0
    assert v["histogram_pictures"] == ["histogram-0.png", "histogram-1.png",
                                       "histogram-0-0.png"]
    pics = {n: read_image(client.get(f"/v1/jobs/{jid}/files/{n}").content)
            for n in v["histogram_pictures"]}
    assert all(p.shape == (65, 65, 3) for p in pics.values())
    # the output's histogram picture looks like the target's, not like the input's
    out, inp, target = (pics[n].astype(float) for n in
                        ("histogram-0-0.png", "histogram-0.png", "histogram-1.png"))
    assert np.abs(out - target).mean() < 0.5 * np.abs(inp - target).mean()
    # chrominance only: L* kept
    r = post(client, [("a.png", png(src)), ("b.png", png(tgt))], weights=[0, 1], recolor=[0],
             luminance="false")
    out = read_image(client.get(f"/v1/jobs/{r.json()['id']}/files/image-0-0.png").content)
    from solvers.color import rgb_to_lab

    dL = np.abs(rgb_to_lab(out)[..., 0] - rgb_to_lab(src)[..., 0])
    assert np.median(dL) < 0.5


def test_alpha_jpeg_and_exif_orientation(client, photos):
    rgb = photos["chelsea"]
    alpha = np.random.default_rng(0).integers(0, 256, rgb.shape[:2], dtype=np.uint8)
    rgba = np.concatenate([rgb, alpha[..., None]], axis=-1)
    # a JPEG stored sideways with EXIF orientation 6 (rotate 90° clockwise to view)
    sideways = Image.fromarray(np.ascontiguousarray(np.rot90(photos["coffee"], 1)))
    exif = Image.Exif()
    exif[0x0112] = 6
    buf = io.BytesIO()
    sideways.save(buf, format="JPEG", exif=exif, quality=95)
    r = post(client, [("a.png", png(rgba)), ("b.jpg", buf.getvalue())], weights=[0.5, 0.5],
             bins=32, gamma=64)
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    jid = r.json()["id"]
    out0 = read_image(client.get(f"/v1/jobs/{jid}/files/image-0-0.png").content)
    assert out0.shape == rgba.shape and np.array_equal(out0[..., 3], alpha)
    out1 = read_image(client.get(f"/v1/jobs/{jid}/files/image-0-1.png").content)
    assert out1.shape == photos["coffee"].shape  # upright, as viewed
    # JPEG output on request (alpha dropped)
    r = post(client, [("a.png", png(rgba)), ("b.jpg", buf.getvalue())], bins=32, gamma=64,
             format="jpeg", recolor=[0])
    jid = r.json()["id"]
    f = client.get(f"/v1/jobs/{jid}/files/image-0-0.jpg")
    assert f.status_code == 200 and f.headers["content-type"] == "image/jpeg"
    assert read_image(f.content).shape == rgb.shape
    assert client.get(f"/v1/jobs/{jid}/files/image-0-1.jpg").status_code == 404


def _png_header_only(width: int, height: int) -> bytes:
    def chunk(tag, payload):
        return (struct.pack(">I", len(payload)) + tag + payload
                + struct.pack(">I", zlib.crc32(tag + payload) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
            + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))


def test_refusals_name_the_field(client, make_client, photos):
    good = png(photos["coffee"])
    assert_error(post(client, [("a.png", good)]), 422, "images")
    assert_error(post(client, [("a.png", good), ("b.txt", b"hello, not an image")]), 422,
                 "images[1]")
    truncated = png(photos["astronaut"])
    assert_error(post(client, [("a.png", good), ("b.png", truncated[: len(truncated) // 2])]),
                 422, "images[1]")
    bomb = _png_header_only(30000, 30000)  # 900 Mpx claimed in a few bytes
    body = assert_error(post(client, [("a.png", good), ("b.png", bomb)]), 422, "images[1]")
    assert "decompression bomb" in body["message"]
    assert_error(post(client, [("a.png", good), ("b.png", good)], weights=[1.0]), 422,
                 "weights")
    assert_error(post(client, [("a.png", good), ("b.png", good)], weights=[1, 0],
                      alphas=[[1, 0]]), 422, "alphas")
    assert_error(post(client, [("a.png", good), ("b.png", good)], bins=4), 422, "bins")
    assert_error(post(client, [("a.png", good), ("b.png", good)], mode="nearest"), 422, "mode")
    assert_error(post(client, [("a.png", good), ("b.png", good)], regularization=-1), 422,
                 "regularization")
    assert_error(post(client, [("a.png", good), ("b.png", good)], format="gif"), 422, "format")
    for slope in (0.5, -1):  # 0 (exact map) or a limit >= 1
        assert_error(post(client, [("a.png", good), ("b.png", good)], luminance_slope=slope),
                     422, "luminance_slope")
    assert_error(post(client, [("a.png", good), ("b.png", good)], resplit=2), 422, "resplit")
    # 16 squared ab units cannot resolve an 8-node grid (h = 36.6) where gamma acts
    body = assert_error(post(client, [("a.png", good), ("b.png", good)], bins=8, gamma=16,
                             mode="barycentric"), 422, "gamma")
    assert "smallest regularization" in body["message"]
    # nothing was queued by the refused submissions
    assert client.get("/v1/jobs?operation=color-transfers").json()["jobs"] == []


def test_coarse_grid_takes_its_default_gamma(client, photos):
    """bins alone (no gamma) is a valid request on every grid: the default gamma follows a
    coarse grid (twice the smallest an 8-node grid resolves) and the result reports it."""
    files = [("a.png", png(photos["coffee"])), ("b.png", png(photos["chelsea"]))]
    r = post(client, files, bins=8, mode="barycentric")
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text
    values = client.get(f"/v1/jobs/{r.json()['id']}/result").json()["values"]
    from solvers.validation import GAMMA_RESOLUTION

    assert values["gamma"] == pytest.approx(2 * GAMMA_RESOLUTION * (256 / 7) ** 2)
    assert values["converged"]


def test_pixel_limits_are_413(make_client, photos):
    small = make_client(color_max_pixels=100 * 150)  # coffee fits exactly, astronaut not
    coffee, astro = png(photos["coffee"]), png(photos["astronaut"])
    assert_error(post(small, [("a.png", coffee), ("b.png", astro)]), 413, "images[1]")
    per_job = make_client(color_max_job_pixels=20000)
    assert_error(post(per_job, [("a.png", coffee), ("b.png", coffee)]), 413, "images")
