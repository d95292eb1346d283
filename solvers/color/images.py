"""Image files in and out (Pillow; 16-bit color TIFF through tifffile).

:func:`read_image` decodes PNG, JPEG (turned upright by its EXIF orientation), TIFF, WebP
(and whatever else Pillow reads) into an ``(H, W, 3)`` or ``(H, W, 4)`` array: uint8 for
8-bit files, uint16 for 16-bit ones (16-bit grayscale PNG/TIFF, 16-bit RGB(A) TIFF);
grayscale is replicated to three channels, palettes are expanded, and an alpha channel is
kept.  Pillow's decompression-bomb check is an error here, truncated files are errors,
and :func:`probe_image` reads only the header (size, mode) so limits can be checked
before decoding.  :func:`write_image` encodes PNG (8 or 16 bits, alpha kept), JPEG
(8-bit, no alpha) or TIFF.

Note: Pillow decodes 16-bit *color* PNGs to 8 bits; those lose their low byte.
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass

import numpy as np

from solvers.errors import InputError

FORMATS = ("png", "jpeg", "tiff", "webp")


@dataclass(frozen=True)
class ImageInfo:
    """Header data of an image file: ``width``, ``height`` (after EXIF orientation),
    ``format`` (Pillow's name), ``mode``."""

    width: int
    height: int
    format: str
    mode: str

    @property
    def pixels(self) -> int:
        return self.width * self.height


def _open(data: bytes, field: str, max_pixels: int | None):
    from PIL import Image, UnidentifiedImageError

    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise InputError(f"{field} must be the bytes of an image file", field=field)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            im = Image.open(io.BytesIO(bytes(data)))
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise InputError(f"{field} is too large to decode safely (decompression bomb)",
                         field=field) from exc
    except UnidentifiedImageError as exc:
        raise InputError(f"{field} is not an image file Pillow can read", field=field) from exc
    except (OSError, ValueError, SyntaxError) as exc:
        raise InputError(f"{field} could not be read as an image", field=field) from exc
    if max_pixels is not None and im.size[0] * im.size[1] > max_pixels:
        raise InputError(f"{field} has {im.size[0] * im.size[1]} pixels, more than the "
                         f"limit of {max_pixels}", field=field)
    return im


def _oriented_size(im) -> tuple[int, int]:
    w, h = im.size
    try:
        orientation = im.getexif().get(0x0112, 1)
    except Exception:  # noqa: BLE001 - a broken EXIF block means "no orientation"
        orientation = 1
    return (h, w) if orientation in (5, 6, 7, 8) else (w, h)


def probe_image(data: bytes, field: str = "image", max_pixels: int | None = None) -> ImageInfo:
    """Header of an image file, without decoding its pixels.

    Parameters
    ----------
    data : bytes
        The image file.
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised if unreadable.
    max_pixels : int, optional
        Refuse images with more pixels than this.

    Returns
    -------
    ImageInfo
        ``width``, ``height`` (after EXIF orientation), ``format`` (Pillow's name), ``mode``.
    """
    im = _open(data, field, max_pixels)
    w, h = _oriented_size(im)
    return ImageInfo(width=int(w), height=int(h), format=str(im.format or ""),
                     mode=str(im.mode))


def read_image(data: bytes, field: str = "image", max_pixels: int | None = None) -> np.ndarray:
    """Decode an image file (EXIF orientation applied; see the module doc).

    Parameters
    ----------
    data, field, max_pixels : bytes, str, int or None
        As in :func:`probe_image`.

    Returns
    -------
    (H, W, 3) or (H, W, 4) array
        uint8 or uint16 pixels (alpha kept).
    """
    from PIL import Image, ImageOps

    im = _open(data, field, max_pixels)
    fmt = im.format
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            if fmt == "TIFF" and _tiff_16bit_color(im):
                return _read_tiff16(data, field)
            im.load()
            im = ImageOps.exif_transpose(im)
            return _to_array(im, field)
    except InputError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        raise InputError(f"{field} is too large to decode safely (decompression bomb)",
                         field=field) from exc
    except (OSError, ValueError, SyntaxError, EOFError) as exc:
        raise InputError(f"{field} is truncated or corrupt", field=field) from exc


def _tiff_16bit_color(im) -> bool:
    try:
        bps = im.tag_v2.get(258)
        spp = im.tag_v2.get(277, 1)
    except AttributeError:
        return False
    bits = bps[0] if isinstance(bps, tuple) else bps
    return bits == 16 and spp in (3, 4)


def _read_tiff16(data: bytes, field: str) -> np.ndarray:
    import tifffile

    arr = tifffile.imread(io.BytesIO(bytes(data)))
    if arr.ndim != 3 or arr.shape[2] not in (3, 4) or arr.dtype != np.uint16:
        raise InputError(f"{field}: unsupported 16-bit TIFF layout {arr.shape}", field=field)
    return np.ascontiguousarray(arr)


def _to_array(im, field: str) -> np.ndarray:
    mode = im.mode
    if mode in ("I;16", "I;16L", "I;16B", "I;16N"):
        g = np.asarray(im).astype(np.uint16)
        return np.ascontiguousarray(np.repeat(g[:, :, None], 3, axis=2))
    if mode == "I":
        g = np.asarray(im)
        if g.min() < 0 or g.max() > 65535:
            raise InputError(f"{field}: 32-bit integer images are not supported", field=field)
        return np.ascontiguousarray(np.repeat(g.astype(np.uint16)[:, :, None], 3, axis=2))
    if mode == "F":
        raise InputError(f"{field}: floating-point images are not supported", field=field)
    has_alpha = mode in ("RGBA", "LA", "PA", "La", "RGBa") or (
        mode == "P" and "transparency" in im.info)
    im = im.convert("RGBA" if has_alpha else "RGB")
    return np.ascontiguousarray(np.asarray(im))


def write_image(img: np.ndarray, format: str = "png", quality: int = 92) -> bytes:
    """Encode pixels as PNG, JPEG, TIFF or WebP bytes.

    PNG keeps alpha; 16-bit color goes to TIFF (tifffile) or is reduced to 8 bits for PNG
    and JPEG (Pillow cannot write 16-bit color PNGs); JPEG drops alpha.

    Parameters
    ----------
    img : (H, W, 3) or (H, W, 4) array
        uint8 or uint16 pixels.
    format : {"png", "jpeg", "jpg", "tiff", "webp"}
        File format.
    quality : int
        JPEG quality.

    Returns
    -------
    bytes
        The encoded file.
    """
    from PIL import Image

    arr = np.asarray(img)
    fmt = format.lower()
    if fmt == "jpg":
        fmt = "jpeg"
    if fmt not in ("png", "jpeg", "tiff", "webp"):
        raise InputError(f"format must be png, jpeg, tiff or webp, got {format!r}",
                         field="format")
    buf = io.BytesIO()
    if arr.dtype == np.uint16 and fmt == "tiff":
        import tifffile

        tifffile.imwrite(buf, arr, photometric="rgb")
        return buf.getvalue()
    if arr.dtype == np.uint16:
        arr = ((arr.astype(np.uint32) + 128) // 257).astype(np.uint8)
    elif arr.dtype != np.uint8:
        arr = np.clip(np.rint(np.asarray(arr, dtype=np.float64) * 255), 0, 255).astype(np.uint8)
    if fmt == "jpeg" and arr.shape[-1] == 4:
        arr = arr[..., :3]
    im = Image.fromarray(np.ascontiguousarray(arr))
    if fmt == "jpeg":
        im.save(buf, format="JPEG", quality=int(quality))
    elif fmt == "png":
        im.save(buf, format="PNG", compress_level=1)
    else:
        im.save(buf, format=fmt.upper())
    return buf.getvalue()
