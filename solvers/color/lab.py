r"""sRGB :math:`\leftrightarrow` CIE-Lab (D65 white, 2° observer).

The reference is scikit-image (:func:`rgb_to_lab_reference`, :func:`lab_to_rgb_reference`:
``skimage.color.rgb2lab`` / ``lab2rgb``, float64).  The fast path (:func:`rgb_to_lab`,
:func:`lab_to_rgb`) uses the same constants in one fused float32 pass per pixel (numba,
parallel), with the sRGB transfer function of integer images read from a lookup table
(one entry per code value: 256 for 8-bit, 65536 for 16-bit).  Tests hold the two within
1e-4 Lab units.

Images are ``(..., 3)`` or ``(..., 4)`` arrays (a fourth channel is alpha and is ignored
here); integer images (uint8, uint16) are read as codes ``0..2^bits-1``, float images as
values in ``[0, 1]``.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from solvers.errors import InputError

L_MAX = 100.0


def check_image(img, field: str = "image") -> np.ndarray:
    """An ``(H, W, 3|4)`` uint8, uint16 or float image (finite, in [0, 1] when float)."""
    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4) or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InputError(f"{field} must be an (H, W, 3) or (H, W, 4) array, got shape "
                         f"{arr.shape}", field=field)
    if arr.dtype not in (np.uint8, np.uint16) and arr.dtype.kind != "f":
        raise InputError(f"{field} must be uint8, uint16 or float, got {arr.dtype}",
                         field=field)
    if arr.dtype.kind == "f":
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{field} has non-finite values", field=field)
        if arr.min() < 0.0 or arr.max() > 1.0:
            raise InputError(f"{field}: float images must lie in [0, 1]", field=field)
    return arr


@cache
def decode_lut(dtype_name: str) -> np.ndarray:
    """Linear value of every code of an integer image (float32, exact sRGB decode)."""
    bits = np.iinfo(np.dtype(dtype_name)).bits
    v = np.arange(2**bits, dtype=np.float64) / (2**bits - 1)
    lin = np.where(v > 0.04045, ((v + 0.055) / 1.055) ** 2.4, v / 12.92)
    return lin.astype(np.float32)


def code_scale(dtype) -> float:
    """Largest code of an integer dtype (1 for floats)."""
    dtype = np.dtype(dtype)
    return float(np.iinfo(dtype).max) if dtype.kind in "ui" else 1.0


def pixels(img: np.ndarray) -> np.ndarray:
    """The image as a read-only, C-contiguous ``(N, C)`` block (a view when possible); float
    images as float32. numba compiles a kernel per argument type, and read-only is part of
    the type: decoded uploads are read-only, a library caller's arrays are not, so without
    this each would compile (and cache) its own variants of every kernel. So the kernels are
    compiled for read-only uint8, uint16 and float32 pixels only."""
    arr = np.ascontiguousarray(img).reshape(-1, img.shape[-1])
    if arr.dtype.kind == "f" and arr.dtype != np.float32:
        arr = arr.astype(np.float32)
    view = arr.view()
    view.flags.writeable = False
    return view


def lut_for(dtype) -> tuple[np.ndarray, float]:
    """``(lut, scale)`` arguments of the fused kernels for an image dtype."""
    dtype = np.dtype(dtype)
    if dtype.kind in "ui":
        return decode_lut(dtype.name), 1.0
    return np.zeros(0, dtype=np.float32), 1.0


def rgb_to_lab(img) -> np.ndarray:
    """Fast sRGB -> CIE-Lab.

    Parameters
    ----------
    img : (..., 3) or (..., 4) array
        sRGB pixels: integer codes, or floats in [0, 1]; alpha is ignored.

    Returns
    -------
    (..., 3) float32 array
        L*, a*, b*.
    """
    arr = np.asarray(img)
    if arr.shape[-1] not in (3, 4):
        raise InputError("images need 3 or 4 channels", field="image")
    from solvers.color import _kernels

    px = pixels(arr)
    if px.dtype.kind == "f" and px.dtype != np.float32:
        px = px.astype(np.float32)  # one compiled float variant (values in [0, 1])
    lut, scale = lut_for(px.dtype)
    lab, _, _ = _kernels.analyze(px, lut, scale, 0, 0.0, 1.0, 0, L_MAX)
    return lab.reshape(arr.shape[:-1] + (3,))


def lab_to_rgb(lab, dtype=np.float32) -> np.ndarray:
    """Fast CIE-Lab -> sRGB, clipped to the gamut's [0, 1] box.

    Parameters
    ----------
    lab : (..., 3) array
        L*, a*, b*.
    dtype : dtype
        Floating dtype for values in [0, 1], or an integer dtype for codes
        (e.g. ``np.uint8``).

    Returns
    -------
    (..., 3) array of ``dtype``
        sRGB values.
    """
    from solvers.color import _kernels

    lab = np.asarray(lab, dtype=np.float32)
    if lab.shape[-1] != 3:
        raise InputError("Lab arrays have 3 channels", field="lab")
    flat = np.ascontiguousarray(lab).reshape(-1, 3)
    dtype = np.dtype(dtype)
    kernel_dtype = dtype if dtype.kind in "ui" else np.dtype(np.float32)  # one float variant
    out = np.empty((flat.shape[0], 3), dtype=kernel_dtype)
    scale = code_scale(dtype)
    offset = 0.5 if dtype.kind in "ui" else 0.0
    empty2 = np.zeros((0, 0), dtype=np.float32)
    _kernels.apply(flat, flat, out, np.zeros(0, dtype=np.float32), 1.0, empty2, empty2,
                   0.0, 0.0, 1.0, scale, offset)
    return out.reshape(lab.shape).astype(dtype, copy=False)


def _as_unit_float(img) -> np.ndarray:
    arr = np.asarray(img)[..., :3]
    if arr.dtype.kind in "ui":
        return arr.astype(np.float64) / code_scale(arr.dtype)
    return arr.astype(np.float64)


def rgb_to_lab_reference(img) -> np.ndarray:
    """scikit-image's ``rgb2lab`` (float64), the reference of :func:`rgb_to_lab`."""
    from skimage.color import rgb2lab

    return rgb2lab(_as_unit_float(img))


def lab_to_rgb_reference(lab) -> np.ndarray:
    """scikit-image's ``lab2rgb`` (float64 in [0, 1]), the reference of :func:`lab_to_rgb`."""
    import warnings

    from skimage.color import lab2rgb

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # negative Z clipped (as the fast path)
        return lab2rgb(np.asarray(lab, dtype=np.float64))
