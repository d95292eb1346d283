r"""BRDF interpolation by Wasserstein barycenters on the hemisphere (thesis §3.7, Fig. 3.11).

A BRDF slice is, for one incoming direction :math:`\omega_i` (polar angle
:math:`\theta_i`, azimuth 0), the reflected-energy distribution over outgoing directions

.. math::  m_j = f(\omega_i, \omega_{o,j}) \cos\theta_{o,j}\, a_j / Z(\omega_i), \qquad
           Z = \textstyle\sum_j f \cos\theta_o\, a_j ,

on a :class:`~solvers.convolutional.hemisphere.HemisphereGrid`.  Given ``k`` materials
(the thesis' corners: closed-form Blinn–Phong and Ashikhmin–Shirley lobes), the
interpolated material at barycentric weights :math:`\lambda` is, per incoming direction,
the convolutional Wasserstein barycenter (eq. 3.13, Alg. 2)

.. math::  m^\star(\omega_i) = \arg\min_m \sum_c \lambda_c\, W^2_{2,H_t}(m, m_c(\omega_i)),

optionally entropy-bounded (Alg. 3, :math:`H(m^\star) \le H_0`, default the largest input
entropy of that incoming direction), and its scale :math:`Z` is interpolated linearly.
All barycenters (every incoming direction × every weight vector) run as one batch of
columns in :func:`solvers.convolutional.barycenter.barycenters_log` on the hemisphere's
latitude-modulated Gaussian kernel.  Highlights then *move* between the corners'
lobes, where the linear mix :math:`\sum_c \lambda_c m_c` cross-fades two lobes in place.

``bilinear_weights`` gives the weights of a ``rows × cols`` grid over the parameter square
of four corner materials (Fig. 3.11); :func:`render_spheres` shades a grid of spheres with
the interpolated BRDFs under one directional light (numpy, orthographic view).

Materials are dicts:

* ``{"model": "blinn-phong", "exponent": e, "ks": 1, "kd": 0}`` —
  :math:`f = k_d/\pi + k_s\frac{e+8}{8\pi}(n\cdot h)^e`;
* ``{"model": "ashikhmin-shirley", "nu": , "nv": , "rs": 0.05, "rd": 0}`` —
  Ashikhmin & Shirley (2000): anisotropic specular lobe with Schlick–Fresnel
  :math:`F = r_s + (1-r_s)(1-k\cdot h)^5` and the coupled diffuse term.  The tangent
  ``u`` is the x axis of the local frame (the incidence plane).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from solvers.convolutional.barycenter import barycenters_log
from solvers.convolutional.common import entropy, masses_from_log, prepare
from solvers.convolutional.distance import watch_stagnation
from solvers.convolutional.hemisphere import HemisphereGrid, spherical_to_vector
from solvers.errors import InputError
from solvers.monitor import SolverResult
from solvers.validation import check_entropy_bound, check_finite, check_int, check_weights

MODELS = ("blinn-phong", "ashikhmin-shirley")
_DEFAULTS = {
    "blinn-phong": {"exponent": 50.0, "ks": 1.0, "kd": 0.0},
    "ashikhmin-shirley": {"nu": 100.0, "nv": 100.0, "rs": 0.05, "rd": 0.0},
}
_LIMITS = {"exponent": (0.0, 1e5), "ks": (0.0, 1e3), "kd": (0.0, 1e3), "nu": (0.0, 1e5),
           "nv": (0.0, 1e5), "rs": (0.0, 1.0), "rd": (0.0, 1.0)}


def check_material(material, field: str = "material") -> dict:
    """A validated material dict with its model's defaults filled in.

    Parameters
    ----------
    material : dict
        ``{"model": ..., parameters}`` (module docstring).
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised.

    Returns
    -------
    dict
    """
    if not isinstance(material, dict) or material.get("model") not in MODELS:
        raise InputError(f"{field} must be a dict with model one of {', '.join(MODELS)}",
                         field=field)
    model = material["model"]
    out = {"model": model}
    for key, default in _DEFAULTS[model].items():
        v = check_finite(material.get(key, default), f"{field}.{key}")
        lo, hi = _LIMITS[key]
        if not lo <= v <= hi:
            raise InputError(f"{field}.{key} = {v:g} must lie in [{lo:g}, {hi:g}]",
                             field=f"{field}.{key}")
        out[key] = v
    extra = set(material) - set(out)
    if extra:
        raise InputError(f"{field}: unknown parameters {sorted(extra)}", field=field)
    if model == "blinn-phong" and out["ks"] + out["kd"] <= 0 \
            or model == "ashikhmin-shirley" and out["rs"] + out["rd"] <= 0:
        raise InputError(f"{field} reflects no light (all coefficients 0)", field=field)
    return out


def evaluate(material: dict, w_in: np.ndarray, w_out: np.ndarray) -> np.ndarray:
    """BRDF values ``(P,)`` for unit directions ``w_in`` ``(3,)`` or ``(P, 3)`` and ``w_out``
    ``(P, 3)`` in the local frame (z = normal, x = tangent ``u``).

    Parameters
    ----------
    material : dict
        A validated material.
    w_in : (3,) or (P, 3) array
        Incoming unit directions.
    w_out : (P, 3) array
        Outgoing unit directions.

    Returns
    -------
    (P,) array
    """
    m = check_material(material)
    w_in = np.broadcast_to(np.asarray(w_in, float), np.shape(w_out))
    w_out = np.asarray(w_out, float)
    h = w_in + w_out
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    nh = np.clip(h[..., 2], 0.0, 1.0)
    ci, co = np.clip(w_in[..., 2], 0.0, 1.0), np.clip(w_out[..., 2], 0.0, 1.0)
    if m["model"] == "blinn-phong":
        e = m["exponent"]
        with np.errstate(under="ignore"):
            return m["kd"] / np.pi + m["ks"] * (e + 8.0) / (8.0 * np.pi) * nh ** e
    nu, nv, rs, rd = m["nu"], m["nv"], m["rs"], m["rd"]
    kh = np.clip(np.einsum("...c,...c->...", w_in, h), 1e-6, 1.0)
    sin2 = np.maximum(1.0 - nh ** 2, 1e-300)
    expo = (nu * h[..., 0] ** 2 + nv * h[..., 1] ** 2) / sin2
    fresnel = rs + (1.0 - rs) * (1.0 - kh) ** 5
    with np.errstate(under="ignore"):
        spec = (np.sqrt((nu + 1.0) * (nv + 1.0)) / (8.0 * np.pi) * nh ** expo
                / (kh * np.maximum(np.maximum(ci, co), 1e-6)) * fresnel)
    diff = (28.0 * rd / (23.0 * np.pi) * (1.0 - rs)
            * (1.0 - (1.0 - 0.5 * ci) ** 5) * (1.0 - (1.0 - 0.5 * co) ** 5))
    return spec + diff


def check_incoming(incoming_theta, field: str = "incoming_theta") -> np.ndarray:
    """Polar angles ``(n_in,)`` of the incoming directions, in ``[0, pi/2)``, increasing.

    Parameters
    ----------
    incoming_theta : (n_in,) array
        Polar angles.
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised.

    Returns
    -------
    (n_in,) array
    """
    try:
        x = np.atleast_1d(np.asarray(incoming_theta, dtype=np.float64))
    except (TypeError, ValueError) as exc:
        raise InputError(f"{field} must be numbers", field=field) from exc
    if x.ndim != 1 or len(x) == 0 or not np.all(np.isfinite(x)) \
            or np.any(x < 0) or np.any(x >= 0.5 * np.pi) or np.any(np.diff(x) <= 0):
        raise InputError(f"{field} must be increasing angles in [0, pi/2) (radians)",
                         field=field)
    return x


def brdf_slices(grid: HemisphereGrid, material: dict, incoming_theta) -> tuple[np.ndarray,
                                                                               np.ndarray]:
    """``(masses (n_in, n), scale (n_in,))``: the material's reflected-energy distribution
    per incoming direction (module docstring) and its normalization ``Z``.

    Parameters
    ----------
    grid : HemisphereGrid
        The hemisphere of outgoing directions (``n`` points).
    material : dict
        A material.
    incoming_theta : (n_in,) array
        Polar angles of the incoming directions.

    Returns
    -------
    masses : (n_in, n) array
        Reflected-energy distribution per incoming direction.
    scale : (n_in,) array
        Its normalization :math:`Z`.
    """
    th = check_incoming(incoming_theta)
    masses = np.empty((len(th), grid.n))
    scale = np.empty(len(th))
    co = np.cos(grid.theta)
    for i, t in enumerate(th):
        w_in = spherical_to_vector(t, 0.0)
        f = evaluate(material, w_in, grid.directions)
        e = f * co * grid.areas
        scale[i] = float(e.sum())
        if not (np.isfinite(scale[i]) and scale[i] > 0):
            raise InputError("the material's slice has no mass on this grid (a lobe "
                             "sharper than the grid?)", field="materials")
        masses[i] = e / scale[i]
    return masses, scale


def bilinear_weights(rows: int, cols: int) -> np.ndarray:
    """``(rows*cols, 4)`` weights of corners ``(0,0), (0,1), (1,0), (1,1)`` of the unit
    parameter square on a ``rows × cols`` grid (row-major, both ends included).

    Parameters
    ----------
    rows, cols : int
        Size of the grid of weight vectors.

    Returns
    -------
    (rows*cols, 4) array
    """
    rows = check_int(rows, "rows", low=1)
    cols = check_int(cols, "cols", low=1)
    u = np.linspace(0.0, 1.0, rows) if rows > 1 else np.zeros(1)
    v = np.linspace(0.0, 1.0, cols) if cols > 1 else np.zeros(1)
    U, V = np.meshgrid(u, v, indexing="ij")
    U, V = U.ravel(), V.ravel()
    return np.stack([(1 - U) * (1 - V), (1 - U) * V, U * (1 - V), U * V], axis=1)


@dataclass
class BRDFInterpolationResult(SolverResult):
    r"""Interpolated slices.

    ``masses`` ``(n_in, B, n)``: barycenter per incoming direction and weight vector;
    ``linear`` ``(n_in, B, n)``: the linear mix :math:`\sum_c\lambda_c m_c` (comparison);
    ``scale`` ``(n_in, B)``: linearly interpolated :math:`Z`; ``inputs`` ``(n_in, k, n)``;
    ``entropy`` ``(n_in, B)``; ``entropy_bound`` ``(n_in, B)`` or None; ``residual``: the
    largest L1 marginal violation over all barycenters.

    Attributes
    ----------
    masses : (n_in, B, n) array
        Barycenter per incoming direction and weight vector.
    linear : (n_in, B, n) array
        The linear mix :math:`\sum_c \lambda_c m_c`.
    scale : (n_in, B) array
        Linearly interpolated :math:`Z`.
    inputs : (n_in, k, n) array
        The inputs' slices.
    weights : (B, k) array
        The weight vectors.
    incoming_theta : (n_in,) array
        Polar angles of the incoming directions.
    entropy : (n_in, B) array
        Entropy of each barycenter.
    entropy_bound : (n_in, B) array or None
        Sharpening bounds.
    gamma : float
        Regularization used.
    iterations, residual, converged : int, float, bool
        Convergence data; ``residual`` is the largest L1 marginal violation over all
        barycenters.
    """

    masses: np.ndarray
    linear: np.ndarray
    scale: np.ndarray
    inputs: np.ndarray
    weights: np.ndarray
    incoming_theta: np.ndarray
    entropy: np.ndarray
    entropy_bound: np.ndarray | None
    gamma: float


def interpolate_brdfs(
    grid: HemisphereGrid,
    materials: Sequence[dict],
    weights,
    incoming_theta,
    *,
    gamma: float,
    entropy_bound: float | str | None = None,
    tol: float = 1e-4,
    max_iter: int | None = None,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> BRDFInterpolationResult:
    """Barycenters of ``k`` materials' slices for every weight vector and incoming direction.

    Parameters
    ----------
    grid : the hemisphere of outgoing directions.
    materials : ``k`` material dicts (module docstring).
    weights : ``(B, k)`` barycentric weights (rows normalized), e.g. :func:`bilinear_weights`.
    incoming_theta : ``(n_in,)`` increasing polar angles of the incoming directions.
    gamma : regularization (unit-hemisphere-area units); ``t = gamma/4``.
    entropy_bound : None (plain Alg. 2), ``"inputs"`` (Alg. 3 with :math:`H_0` the largest
        entropy of that direction's inputs) or a number :math:`H_0`.
    tol, max_iter, progress, should_cancel : as in :func:`~solvers.convolutional.barycenter`.

    Returns
    -------
    BRDFInterpolationResult
    """
    if not isinstance(materials, (list, tuple)) or len(materials) < 1:
        raise InputError("materials must be a non-empty list", field="materials")
    mats = [check_material(m, f"materials[{c}]") for c, m in enumerate(materials)]
    k = len(mats)
    try:
        W = np.asarray(weights, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError("weights must be numbers", field="weights") from exc
    if W.ndim == 1:
        W = W[None, :]
    if W.ndim != 2 or W.shape[1] != k:
        raise InputError(f"weights must have shape (B, {k})", field="weights")
    W = np.stack([check_weights(row, k, "weights") for row in W])
    th = check_incoming(incoming_theta)
    n_in, B = len(th), len(W)
    setup = prepare(grid, gamma=gamma, t=None, substeps=1, tol=tol, max_iter=max_iter,
                    progress=progress, should_cancel=should_cancel)
    monitor = watch_stagnation(setup, project=max_iter is None)
    slices = np.empty((n_in, k, grid.n))
    scales = np.empty((n_in, k))
    for c, m in enumerate(mats):
        slices[:, c], scales[:, c] = brdf_slices(grid, m, th)
    ent_in = np.asarray(entropy(slices.reshape(-1, grid.n).T, setup.areas)).reshape(n_in, k)
    bounds = None
    if entropy_bound is not None:
        if isinstance(entropy_bound, str):
            if entropy_bound != "inputs":
                raise InputError("entropy_bound must be a number or 'inputs'",
                                 field="entropy_bound")
            bounds = np.repeat(ent_in.max(axis=1)[:, None], B, axis=1)
        else:
            b = check_entropy_bound(entropy_bound, setup.areas, "entropy_bound")
            bounds = np.full((n_in, B), b)
    # Columns: (direction i, barycenter b, material c) -> i*B*k + b*k + c; barycenter i*B + b.
    cols = slices[:, None, :, :].repeat(B, axis=1).reshape(n_in * B * k, grid.n).T
    owners = np.repeat(np.arange(n_in * B), k)
    Wc = np.zeros((n_in * B * k, n_in * B))
    Wc[np.arange(n_in * B * k), owners] = np.tile(W.ravel(), n_in)
    lbar, it, res, conv = barycenters_log(
        setup.logk, setup.areas, np.ascontiguousarray(cols), Wc, tol=setup.tol,
        max_iter=setup.max_iter, monitor=monitor, owners=owners,
        entropy_bounds=None if bounds is None else bounds.ravel(),
        relax=bounds is None)
    masses = masses_from_log(lbar, setup.areas).T.reshape(n_in, B, grid.n)
    linear = np.einsum("bc,icn->ibn", W, slices)
    ent = np.asarray(entropy(masses.reshape(-1, grid.n).T, setup.areas)).reshape(n_in, B)
    return BRDFInterpolationResult(
        masses=masses, linear=linear, scale=scales @ W.T, inputs=slices, weights=W,
        incoming_theta=th, entropy=ent, entropy_bound=bounds, gamma=setup.gamma,
        iterations=int(it), residual=float(res), converged=bool(conv))


def density(grid: HemisphereGrid, masses: np.ndarray) -> np.ndarray:
    """Densities ``m / a`` of ``(..., n)`` masses (per unit hemisphere area).

    Parameters
    ----------
    grid : HemisphereGrid
        The hemisphere of outgoing directions (``n`` points).
    masses : (..., n) array
        Masses.

    Returns
    -------
    (..., n) array
    """
    return np.asarray(masses) / grid.areas


def peak_direction(grid: HemisphereGrid, masses: np.ndarray) -> tuple[float, float]:
    """``(theta, phi)`` of the largest density of ``(n,)`` masses.

    Parameters
    ----------
    grid : HemisphereGrid
        The hemisphere of outgoing directions (``n`` points).
    masses : (n,) array
        Masses.

    Returns
    -------
    theta, phi : float
    """
    j = int(np.argmax(density(grid, masses)))
    return float(grid.theta[j]), float(grid.phi[j])


def local_maxima(grid: HemisphereGrid, masses: np.ndarray, rel: float = 0.05) -> np.ndarray:
    """Grid points whose density is at least ``rel`` × the largest and strictly above its
    8 grid neighbours (phi periodic; the pole row compares only within the grid).

    Parameters
    ----------
    grid, masses
        As in :func:`peak_direction`.
    rel : float
        Smallest density kept, relative to the largest.

    Returns
    -------
    array of int
    """
    nt, nphi = grid.shape
    d = density(grid, masses).reshape(nt, nphi)
    pad = np.full((nt + 2, nphi), -np.inf)
    pad[1:-1] = d
    is_max = d >= rel * d.max()
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == 0 and dj == 0:
                continue
            nb = np.roll(pad[1 + di:nt + 1 + di], -dj, axis=1)
            is_max &= d > nb
    return np.flatnonzero(is_max.ravel())


def lookup(grid: HemisphereGrid, values: np.ndarray, theta: np.ndarray,
           phi: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of ``(..., n)`` grid values at angles ``(P,)`` → ``(..., P)``
    (phi periodic, theta clamped to the cell-centre range).

    Parameters
    ----------
    grid : HemisphereGrid
        The hemisphere of outgoing directions (``n`` points).
    values : (..., n) array
        Values on the grid points.
    theta, phi : (P,) array
        Angles.

    Returns
    -------
    (..., P) array
    """
    nt, nphi = grid.shape
    v = np.asarray(values).reshape(values.shape[:-1] + (nt, nphi))
    ft = np.clip(theta / (0.5 * np.pi / nt) - 0.5, 0.0, nt - 1.0)
    fp = ((phi + np.pi) / (2.0 * np.pi / nphi)) % nphi
    i0 = np.minimum(ft.astype(np.int64), nt - 2) if nt > 1 else np.zeros_like(ft, int)
    j0 = np.floor(fp).astype(np.int64) % nphi
    j1 = (j0 + 1) % nphi
    u, w = ft - i0, fp - np.floor(fp)
    i1 = np.minimum(i0 + 1, nt - 1)
    return ((1 - u) * (1 - w) * v[..., i0, j0] + (1 - u) * w * v[..., i0, j1]
            + u * (1 - w) * v[..., i1, j0] + u * w * v[..., i1, j1])


def render_spheres(grid: HemisphereGrid, masses: np.ndarray, scale: np.ndarray,
                   incoming_theta, rows: int, cols: int, *, size: int = 96,
                   light=(0.6, 0.5, 0.62), exposure: float | None = None) -> np.ndarray:
    r"""``(rows*size, cols*size, 3)`` uint8 image of spheres shaded with interpolated BRDFs.

    ``masses`` ``(n_in, B, n)`` and ``scale`` ``(n_in, B)`` (``B = rows*cols``, row-major)
    from :func:`interpolate_brdfs`.  Orthographic view along -z, one directional light
    ``light``; per pixel with normal :math:`n` the local frame has x along the light's
    tangential part (the slices' incidence plane, isotropic lookup), the BRDF is
    :math:`f = m Z / (a \cos\theta_o)` interpolated linearly in :math:`\theta_i` and
    bilinearly in :math:`(\theta_o,\phi_o)`, and the radiance :math:`f\cos\theta_i`
    (plus a small ambient term) is tone-mapped with gamma 2.2 (``exposure``: the radiance
    shown white; default the 99.5th percentile over all spheres).

    Parameters
    ----------
    grid : HemisphereGrid
        The hemisphere of outgoing directions (``n`` points).
    masses : (n_in, B, n) array
        Interpolated slices.
    scale : (n_in, B) array
        Their normalizations.
    incoming_theta : (n_in,) array
        Polar angles of the incoming directions.
    rows, cols : int
        Layout of the ``B = rows*cols`` spheres.
    size : int
        Pixels per sphere.
    light : (3,) array
        Direction of the light.
    exposure : float, optional
        Radiance shown white.

    Returns
    -------
    (rows*size, cols*size, 3) uint8 array
    """
    th_in = check_incoming(incoming_theta)
    n_in, B, n = masses.shape
    if B != rows * cols:
        raise InputError(f"masses hold {B} materials, not rows*cols = {rows * cols}",
                         field="rows")
    L = np.asarray(light, float)
    L = L / np.linalg.norm(L)
    co = np.maximum(np.cos(grid.theta), 0.05)
    brdf = masses * scale[:, :, None] / (grid.areas * co)  # (n_in, B, n)
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    X, Y = np.meshgrid(c, -c)
    inside = X ** 2 + Y ** 2 < 1.0
    N = np.stack([X[inside], Y[inside], np.sqrt(1.0 - X[inside] ** 2 - Y[inside] ** 2)], 1)
    view = np.array([0.0, 0.0, 1.0])
    cos_i = N @ L
    lit = cos_i > 0
    tx = L[None] - cos_i[:, None] * N
    norm = np.linalg.norm(tx, axis=1, keepdims=True)
    fallback = np.cross(N, [0.0, 1.0, 0.0])
    tx = np.where(norm > 1e-8, tx / np.maximum(norm, 1e-300), fallback)
    ty = np.cross(N, tx)
    theta_i = np.arccos(np.clip(cos_i, -1, 1))
    theta_o = np.arccos(np.clip(N @ view, -1, 1))
    phi_o = np.arctan2(ty @ view, tx @ view)
    fi = np.interp(theta_i, th_in, np.arange(n_in, dtype=float))
    i0 = np.floor(fi).astype(np.int64)
    i1 = np.minimum(i0 + 1, n_in - 1)
    wi = fi - i0
    radiance = np.zeros((B, len(N)))
    for b in range(B):
        f0 = lookup(grid, brdf[:, b], theta_o, phi_o)  # (n_in, P)
        f = (1 - wi) * f0[i0, np.arange(len(N))] + wi * f0[i1, np.arange(len(N))]
        radiance[b] = np.where(lit, f * np.maximum(cos_i, 0.0), 0.0) + 0.02
    top = float(np.percentile(radiance, 99.5)) if exposure is None else float(exposure)
    top = top if top > 0 else 1.0
    img = np.zeros((rows * size, cols * size, 3))
    tone = np.clip(radiance / top, 0.0, 1.0) ** (1.0 / 2.2)
    for b in range(B):
        r, q = divmod(b, cols)
        tile = np.zeros((size, size))
        tile[inside] = tone[b]
        img[r * size:(r + 1) * size, q * size:(q + 1) * size] = tile[:, :, None]
    return (255.0 * img + 0.5).astype(np.uint8)


def png_bytes(image: np.ndarray) -> bytes:
    """PNG encoding of an ``(H, W, 3)`` uint8 image (Pillow).

    Parameters
    ----------
    image : (H, W, 3) uint8 array
        The image.

    Returns
    -------
    bytes
    """
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(image, dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()
