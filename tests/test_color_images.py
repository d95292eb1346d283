"""solvers.color.images: formats, bit depths, alpha, EXIF orientation, refusals."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image
from skimage import data

from solvers.color import color_transfer, probe_image, read_image, write_image
from solvers.errors import InputError


@pytest.fixture(scope="module")
def rgb():
    return np.ascontiguousarray(data.chelsea()[::2, ::2])  # 150 x 226


def test_png_roundtrip_rgb_and_rgba(rgb):
    assert np.array_equal(read_image(write_image(rgb, "png")), rgb)
    alpha = np.arange(rgb.shape[0] * rgb.shape[1], dtype=np.uint32).reshape(rgb.shape[:2])
    rgba = np.concatenate([rgb, (alpha % 256).astype(np.uint8)[..., None]], axis=-1)
    back = read_image(write_image(rgba, "png"))
    assert back.shape == rgba.shape and np.array_equal(back, rgba)


def test_jpeg_webp_and_palette(rgb):
    for fmt in ("jpeg", "webp"):
        back = read_image(write_image(rgb, fmt))
        assert back.shape == rgb.shape and back.dtype == np.uint8
        assert np.abs(back.astype(int) - rgb).mean() < 6
    buf = io.BytesIO()
    Image.fromarray(rgb).convert("P").save(buf, format="PNG")
    assert read_image(buf.getvalue()).shape == rgb.shape
    gray = io.BytesIO()
    Image.fromarray(rgb[..., 0]).save(gray, format="PNG")
    g = read_image(gray.getvalue())
    assert g.shape == rgb.shape and np.array_equal(g[..., 0], g[..., 2])


def test_sixteen_bit_gray_png_and_color_tiff(rgb):
    g16 = (np.arange(60 * 70, dtype=np.uint32).reshape(60, 70) * 15).astype(np.uint16)
    buf = io.BytesIO()
    Image.fromarray(g16).save(buf, format="PNG")
    back = read_image(buf.getvalue())
    assert back.dtype == np.uint16 and np.array_equal(back[..., 1], g16)
    c16 = rgb.astype(np.uint16) * 257 + 3
    tif = write_image(c16, "tiff")
    back = read_image(tif)
    assert back.dtype == np.uint16 and np.array_equal(back, c16)
    # and through a color transfer: 16-bit in, 16-bit out
    r = color_transfer([back, rgb], [0.5, 0.5], bins=32, gamma=64.0, recolor=[0])
    assert r.images[0][0].dtype == np.uint16 and r.images[0][0].shape == c16.shape


def test_exif_orientation_is_applied(rgb):
    sideways = Image.fromarray(np.ascontiguousarray(np.rot90(rgb, 1)))  # stored 226 x 150
    exif = Image.Exif()
    exif[0x0112] = 6  # view: rotate 90 degrees clockwise
    buf = io.BytesIO()
    sideways.save(buf, format="JPEG", exif=exif, quality=95)
    info = probe_image(buf.getvalue())
    assert (info.height, info.width) == rgb.shape[:2]
    up = read_image(buf.getvalue())
    assert up.shape == rgb.shape
    assert np.abs(up.astype(int) - rgb).mean() < 6  # upright again


def test_refusals(rgb, monkeypatch):
    with pytest.raises(InputError) as e:
        read_image(b"GIF89a-no-not-really", field="images[3]")
    assert e.value.field == "images[3]"
    full = write_image(rgb, "png")
    with pytest.raises(InputError) as e:
        read_image(full[: len(full) // 2], field="img")
    assert e.value.field == "img" and "truncated" in str(e.value)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # warning above 1000, error above 2000
    with pytest.raises(InputError) as e:
        read_image(full, field="img")
    assert "decompression bomb" in str(e.value)
    assert read_image(write_image(rgb[:20, :40], "png")).shape == (20, 40, 3)  # 800 px: fine
    with pytest.raises(InputError) as e:
        probe_image(full, field="img", max_pixels=100)
    assert e.value.field == "img"
