r"""Color transfer between images by Wasserstein barycenters of chrominance (thesis §3.7).

:func:`color_transfer` recolors each of ``k >= 2`` images towards the barycenter of all
their color distributions, for one or several weight vectors :math:`\alpha`
(Fig. 3.12: :math:`\alpha = (1 - s, s)` interpolates between two palettes).

``mode="split"`` (default): chrominance by the exact plan between nearest-node ab
histograms, each source node's pixels split among its targets in the plan's proportions
by a spatially coherent order (:mod:`solvers.color.split`), then the displacement field
regularized by a guided filter on the input's luminance (:mod:`solvers.color.regularize`),
and the filtered colours split once more by the exact plan from their histogram to the
target, which puts back the fidelity the filter costs (a filter -> re-split step, as in
the regularized transport maps of Rabin, Delon and Gousseau).  L* goes through the exact
1-D map with its slope limited (``luminance_slope``, :func:`~solvers.color.luminance.
limit_slope`; ``inf`` = the exact map).  Colours out of the sRGB gamut: each pixel's move
to its nearest in-gamut L* (within ``GAMUT_REACH``) is guided-filtered by the input's L*
(the shift's slope along the input's L* limited per window, ``GAMUT_MAX_SLOPE``) and the
smooth shift applied to all pixels (a per-pixel move would add L* texture); a colour
still out of the gamut loses chroma at its L* and hue.  The re-split's correction is
itself guided-filtered over a window of radius ``CORRECTION_RADIUS`` cells.  Towards an
input, every colour is then remapped inside its histogram node to the target's colours
there (per-axis quantiles on ``WITHIN_NODE_SUBBINS`` sub-bins,
:func:`~solvers.color.split.remap_within_nodes`): the grid fixes the histogram to the
node, this to a sixteenth of a node.
Towards a vertex of the simplex (``alphas`` with a single 1) the plan goes to that image's
histogram; for ``k = 2`` and :math:`\alpha = (1 - s, s)` every pixel moves the fraction
:math:`s` of its displacement (McCann's interpolation, the exact W2 geodesic between the
binned histograms); for ``k > 2`` the plan goes to the entropic barycenter (Alg. 2) on the
same grid.  An image of weight 1 is returned unchanged.

``mode="barycentric"``: the thesis' method (Fig. 3.12):

* chrominance (a*, b*): histograms on a regular grid over :math:`[-128, 128]^2`, their
  barycenter :math:`\mu_\alpha` by Alg. 2 with the exact Gaussian kernel, and the
  barycentric projection :math:`T_i` of each input's plan, applied to every pixel's ab by
  bilinear lookup (:mod:`solvers.color.chrominance`);
* luminance (L*): 1-D optimal transport to the barycenter of the L* distributions, in
  closed form by quantile matching (:mod:`solvers.color.luminance`); ``luminance=False``
  keeps each pixel's L*.

The corrected image :math:`f_i^\alpha = T_i \circ f_i` keeps the size, orientation,
dtype and alpha channel of the input.  Cost: two fused passes over the pixels (Lab and
histograms; map lookup and back to sRGB, :mod:`solvers.color._kernels`) plus a
barycenter on the histogram grid whose cost does not depend on the number of pixels.

The two maps.  ``mode="split"``: for the exact plan :math:`\pi` between the ab histograms
:math:`\mu_i` and the target :math:`\nu` (an input, McCann's interpolant or the barycenter)

.. math::  \min_{\pi \ge 0} \sum_{xy} \pi(x, y) |x - y|^2, \quad
           \pi 1 = \mu_i, \; \pi^T 1 = \nu,

the :math:`n_i(x)` pixels at node :math:`x` are split into runs of
:math:`n_i(x) \pi(x, y) / \mu_i(x)` pixels (integer, largest remainders) moved by
:math:`y - x`, in a spatially coherent order; the displacement field is then guided-
filtered by the input's luminance (``regularization`` = its :math:`\varepsilon`;
0 turns the filter off).  This is not the thesis' map; ``mode="barycentric"`` is:

.. math::  f_i^\alpha = (T^L_{i}, T^{ab}_{i}) \circ f_i, \qquad
           T^{ab}_i(y) = \frac{1}{\mu_i(y)} \int \pi_i(x, y)\, x\, dx,

:math:`\pi_i = D_{v_i} K D_{w_i}` the plan between the ab histogram :math:`\mu_i` and
the barycenter :math:`\arg\min_\mu \sum_j \alpha_j W^2_{2,\gamma}(\mu, \mu_j)`
(eq. 3.13, Alg. 2).  In both modes :math:`T^L_i = (\sum_j \alpha_j Q_j) \circ F_i`
is the 1-D optimal map of the L* channel.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from solvers.color import _kernels
from solvers.color import _split_kernels as SK
from solvers.color.chrominance import AbGrid, check_bins, chrominance_barycenters
from solvers.color.lab import check_image, code_scale, lut_for, pixels
from solvers.color.luminance import L_MAX, LBINS, limit_slope, luminance_maps
from solvers.color.regularize import guided_coefficients, guided_solve_moments, moment_buffer
from solvers.color.split import (
    ExactPlan,
    exact_plan,
    moved_histogram,
    remap_within_nodes,
    scratch_buffers,
    split_displacements,
)
from solvers.errors import InputError
from solvers.monitor import SolverResult
from solvers.validation import (
    GAMMA_RESOLUTION,
    check_choice,
    check_gamma_resolved,
    check_positive,
    check_weights,
)

DEFAULT_GAMMA = 16.0
MAX_IMAGES = 16
MODES = ("split", "barycentric")
# odd: a* = b* = 0 (every grey) is a node, not a boundary between nodes
DEFAULT_BINS = {"split": 65, "barycentric": 256}
# guided filter epsilon (squared units of L*/100); chosen in bench/color.py
DEFAULT_REGULARIZATION = 1e-5
# window radii as fractions of sqrt(H W): guided filter, and the smoothing of the key
# that orders a bin's pixels (the split is coherent over about this scale)
FILTER_RADIUS = 0.01
KEY_RADIUS = 0.02
MIN_FILTER_RADIUS = 4  # pixels: small images still get a window that can smooth a step
# images are reduced by s x s blocks for the filters' moments above this many pixels
REDUCED_PIXELS = 2**19
GUIDE_CHANNELS = 1
# an out-of-gamut result moves to the nearest in-gamut L* up to this far (keeps its ab)
GAMUT_REACH = 100.0
# the L* move into the gamut is guided-filtered (window: the guided filter's) with this
# epsilon, each pixel weighted 1 if out of the gamut and GAMUT_IN_WEIGHT if in it (a mean
# over the pixels that need a move, diluted where they are few); chosen in bench/color.py
# and bench/color_gamut.py (bench/results/color.md)
GAMUT_SHIFT_STRENGTH = 1e-4
GAMUT_IN_WEIGHT = 0.3
# the shift's slope along the input's L* (dL*_out / dL*_in it adds) kept within
# [-GAMUT_MAX_SLOPE, GAMUT_MAX_SLOPE] per window, so that it cannot stretch or flatten the
# input's L* edges much whatever its epsilon (inf: no limit); bench/color_gamut.py
GAMUT_MAX_SLOPE = 0.85
# that move is sampled on every min(s, GAMUT_STRIDE)-th row and column (s: the block
# size of the reduced image; 1 below REDUCED_PIXELS): the filter averages it over many
# blocks anyway
GAMUT_STRIDE = 2
# split mode: the L* table's slope kept within [1/c, c] times its mean slope
# (luminance.limit_slope; inf = the exact 1-D map); chosen in bench/color.py
DEFAULT_LUMINANCE_SLOPE = 1.25
# fraction of the re-split's correction applied after the guided filter (1: the output
# histogram is the target's up to the binning and the correction's filter); chosen in
# bench/color.py
DEFAULT_RESPLIT = 1.0
# window radius (cells of the reduced image) of the guided filter of the re-split's
# correction: small, so the histogram stays the target's but no single pixel steps alone
CORRECTION_RADIUS = 1
# sub-bins per node and axis of the within-node quantile remap towards an input's colours
# (split.remap_within_nodes; 0: off): the grid fixes the output histogram to the node,
# this to h / WITHIN_NODE_SUBBINS inside it (photographs' atoms, e.g. greys, sit inside)
WITHIN_NODE_SUBBINS = 16


@dataclass(kw_only=True)
class ColorTransferResult(SolverResult):
    """Result of :func:`color_transfer`.

    ``mode="split"``: ``histograms`` count pixels at their nearest node; ``barycenters``
    are the histograms the plans go to (an input's, McCann's interpolant for ``k = 2``,
    the entropic barycenter for ``k > 2``); ``maps`` is ``None``; ``plans`` maps
    ``(i, j)`` (``j`` an input index, or ``"b{b}"`` for barycenter ``b``) to the
    :class:`~solvers.color.split.ExactPlan` used; ``residual`` the largest marginal
    violation of those plans (and of the barycenter's, if any).

    Attributes
    ----------
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`); ``residual`` is the
        largest L1 marginal violation over all plans.
    images : list of list of array or None
        ``images[b][i]``: input ``i`` recolored for ``alphas[b]`` (same shape and dtype as
        the input; ``None`` when not requested through ``recolor``).
    alphas : (B, k) array
        The weight vectors.
    barycenters : (B, bins, bins) array
        ab masses (axis 0: a*, axis 1: b*, nodes ``-128 + h·i``).
    histograms : (k, bins, bins) array
        The inputs' ab masses.
    maps : (B, k, 2, bins, bins) array or None
        The ab value :math:`T_i` sends each node to (NaN outside ``window``).
    luminance_maps : (B, k, lbins) array or None
        The L* each L bin goes to (``None`` with ``luminance=False``).
    window : tuple of slice
        The part of the ab grid where maps are computed.
    bins : int
        Nodes per axis of the ab grid.
    gamma : float
        Entropic regularization used, in squared ab units.
    mode : {"barycentric", "split"}
        How pixels are recolored.
    regularization : float
        ``mode="split"``: the guided-filter epsilon (0: no filter).
    plans : dict
        ``mode="split"``: the exact plans used, by ``(i, j)``.
    entropy_bounds : (B,) array or None
        Entropy bounds of sharpening, if any.
    timings : dict
        Seconds per stage.
    """

    images: list[list[np.ndarray | None]]
    alphas: np.ndarray
    barycenters: np.ndarray
    histograms: np.ndarray
    maps: np.ndarray | None
    luminance_maps: np.ndarray | None
    window: tuple[slice, slice]
    bins: int
    gamma: float
    mode: str = "barycentric"
    regularization: float = 0.0
    plans: dict = field(default_factory=dict)
    entropy_bounds: np.ndarray | None = None
    timings: dict = field(default_factory=dict)


def check_alphas(alphas, k: int) -> np.ndarray:
    """``None`` (uniform), one ``(k,)`` weight vector or a ``(B, k)`` list -> ``(B, k)``."""
    if alphas is None:
        return np.full((1, k), 1.0 / k)
    arr = np.asarray(alphas, dtype=object)
    rows = [alphas] if arr.ndim == 1 else list(alphas)
    if not rows:
        raise InputError("alphas must not be empty", field="alphas")
    out = []
    for b, row in enumerate(rows):
        try:
            out.append(check_weights(row, k))
        except InputError as exc:
            raise InputError(f"alphas[{b}]: {exc}", field="alphas") from exc
    return np.stack(out)


def color_transfer(
    images: Sequence[np.ndarray], alphas=None, *, mode: str = "split",
    bins: int | None = None, gamma: float | None = None, luminance: bool = True,
    regularization: float = DEFAULT_REGULARIZATION,
    luminance_slope: float = DEFAULT_LUMINANCE_SLOPE, resplit: float = DEFAULT_RESPLIT,
    sharpen: bool = False, debiased: bool = False, recolor: Sequence[int] | None = None,
    tol: float = 1e-4, max_iter: int = 3000,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> ColorTransferResult:
    r"""Recolor ``images`` towards Wasserstein barycenters of their colors (thesis §3.7).

    ``mode="split"`` (default) splits each node's pixels by the exact plan between the ab
    histogram and the target, then guided-filters the displacements; ``mode="barycentric"``
    is the thesis' map :math:`f_i^\alpha = (T^L_{i}, T^{ab}_{i}) \circ f_i`.  Both are
    written out in the module doc ("The two maps").  In both modes
    :math:`T^L_i = (\sum_j \alpha_j Q_j) \circ F_i` is the 1-D optimal map of the L* channel.

    Parameters
    ----------
    images : ``k >= 2`` (at most 16) images ``(H_i, W_i, 3|4)``, uint8, uint16 or float
        in [0, 1] (sizes may differ; a fourth channel is alpha, copied through).
    alphas : ``(k,)`` weights or a ``(B, k)`` list of them (each row normalized); default
        uniform.  ``(0, 1)`` recolors image 0 with image 1's colors; ``(1 - s, s)`` for a
        sequence of ``s`` interpolates (Fig. 3.12).
    mode : ``"split"`` or ``"barycentric"``.
    bins : nodes per axis of the ab grid over ``[-128, 128]^2`` (8..1024; default 65 for
        ``split``, 256 for ``barycentric``).
    gamma : entropic regularization in squared ab units (kernel ``exp(-|x-y|^2/gamma)``,
        blur of standard deviation ``sqrt(gamma/2)``) of the entropic barycenters; default
        :func:`default_gamma` (16, or twice the smallest the grid resolves below 17 nodes).
    luminance : also transfer L* (1-D OT); ``False`` transfers chrominance only and keeps
        each pixel's L*.
    regularization : ``split`` only: guided-filter epsilon (>= 0; 0: no filter).  With a
        filter the filtered colours are split once more by the exact plan from their
        histogram to the target (the filter moves colours off the target's histogram;
        this puts them back, up to the binning).
    resplit : ``split`` only: fraction in [0, 1] of that re-split's correction that is
        applied, after a guided filter of radius ``CORRECTION_RADIUS`` cells (default 1:
        output histogram = target's up to the binning and that small filter; 0: the
        filtered colours as they are).
    luminance_slope : ``split`` only: contrast limit ``c >= 1`` of the L* map
        (:func:`~solvers.color.luminance.limit_slope`: the exact 1-D map's slope clipped
        to ``[g/c, g c]``, ``g`` its mean slope); ``inf`` keeps the exact 1-D map.  The
        default, 1.25, keeps local contrast (edges) that the exact map changes.
    sharpen, debiased : entropic sharpening (Alg. 3) / debiased barycenters, against the
        desaturation by entropic blur.
    recolor : indices of the images to recolor (default all); the others only contribute
        their histograms.
    tol, max_iter : stopping rule of the entropic barycenter (L1 marginal violation).
    progress, should_cancel : called every barycenter iteration.

    Returns
    -------
    ColorTransferResult
    """
    t0 = time.perf_counter()
    images = _check_images(images)
    k = len(images)
    mode = check_mode(mode)
    A = check_alphas(alphas, k)
    bins = resolve_bins(bins, mode)
    gamma = resolve_gamma(gamma, bins)
    regularization = check_regularization(regularization)
    luminance_slope = check_luminance_slope(luminance_slope)
    resplit = check_fraction(resplit, "resplit")
    todo = _recolored(recolor, k)
    opts = dict(gamma=gamma, sharpen=sharpen, debiased=debiased, tol=tol,
                max_iter=max_iter, progress=progress, should_cancel=should_cancel)
    if mode == "barycentric":
        return _barycentric(images, A, bins, luminance, todo, t0, opts)
    return _split(images, A, bins, luminance, (regularization, luminance_slope, resplit), todo,
                  t0, opts)


def _check_images(images) -> list[np.ndarray]:
    """``2..MAX_IMAGES`` images, each checked (:func:`~solvers.color.lab.check_image`)."""
    if isinstance(images, np.ndarray) and images.ndim == 3:
        images = [images]
    images = list(images)
    k = len(images)
    if not 2 <= k <= MAX_IMAGES:
        raise InputError(f"color transfer needs 2 to {MAX_IMAGES} images, got {k}",
                         field="images")
    return [check_image(img, f"images[{i}]") for i, img in enumerate(images)]


def _recolored(recolor, k: int) -> list[int]:
    """The sorted indices of the images to recolor (default all ``k``)."""
    todo = list(range(k)) if recolor is None else sorted({int(i) for i in recolor})
    if any(not 0 <= i < k for i in todo):
        raise InputError(f"recolor indices must lie in [0, {k})", field="recolor")
    return todo


def resolve_bins(bins, mode: str) -> int:
    """``bins`` checked (:func:`~solvers.color.chrominance.check_bins`), or the ``mode``'s
    default (:data:`DEFAULT_BINS`) when ``None``."""
    return check_bins(DEFAULT_BINS[mode] if bins is None else bins)


def default_gamma(bins: int) -> float:
    """The default entropic regularization on an ab grid of ``bins`` nodes per axis:
    ``DEFAULT_GAMMA`` squared ab units, or twice the smallest the grid resolves
    (``2 GAMMA_RESOLUTION h**2``) on grids too coarse for 16 (below 17 nodes: 8 nodes give
    h = 36.6, where the kernel between neighbouring nodes, ``exp(-h**2 / 16)``, falls below
    machine epsilon).  Measured against larger choices: bench/results/color.md."""
    return max(DEFAULT_GAMMA, 2.0 * GAMMA_RESOLUTION * AbGrid(bins).spacing ** 2)


def resolve_gamma(gamma, bins: int) -> float:
    """``gamma`` checked (positive, resolving the ab grid of ``bins`` nodes per axis: an
    explicit value is held to the grid whether or not the transfer's mode uses it), or its
    default :func:`default_gamma` when ``None``."""
    if gamma is None:
        return default_gamma(bins)
    return check_gamma_resolved(check_positive(gamma, "gamma"), AbGrid(bins).spacing, "gamma")


def check_mode(mode) -> str:
    check_choice(mode, MODES, "mode")
    return str(mode)


def _number(value, name: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a number", field=name) from exc


def check_fraction(value, name: str) -> float:
    v = _number(value, name)
    if not 0 <= v <= 1:
        raise InputError(f"{name} must lie in [0, 1], got {value!r}", field=name)
    return v


def check_luminance_slope(value) -> float:
    v = _number(value, "luminance_slope")
    if np.isnan(v) or v < 1:
        raise InputError(f"luminance_slope must be >= 1 (inf: exact map), got {value!r}",
                         field="luminance_slope")
    return v


def check_regularization(value) -> float:
    v = _number(value, "regularization")
    if not np.isfinite(v) or v < 0:
        raise InputError(f"regularization must be finite and >= 0, got {value!r}",
                         field="regularization")
    return v


def _analyze_all(images, bins, luminance, todo, nearest):
    """Lab of the images to recolor, ab histograms, L* counts (and with ``nearest`` the
    mean ab at each node, ``(k, 2, bins²)``, and the within-node offset counts
    ``(k, 2, bins², WITHIN_NODE_SUBBINS)``, ``None`` if that is 0)."""
    grid = AbGrid(bins)
    lbins = LBINS if luminance else 0
    sub = WITHIN_NODE_SUBBINS if nearest else 0
    labs, hists, lcounts, means, subs = [], [], [], [], []
    for i, img in enumerate(images):
        px = pixels(img)
        lut, scale = lut_for(px.dtype)
        lab, counts, lc, *extra = _kernels.analyze(px, lut, scale, bins, -128.0,
                                                   grid.spacing, lbins, L_MAX,
                                                   keep_lab=i in todo, nearest=nearest,
                                                   subbins=sub)
        labs.append(lab)
        hists.append(counts.reshape(bins, bins) / px.shape[0])
        lcounts.append(lc)
        means.extend(extra[:1])
        subs.extend(extra[1:])
    if not nearest:
        return labs, np.stack(hists), lcounts, None
    return labs, np.stack(hists), lcounts, (np.stack(means), np.stack(subs) if sub else None)


def _barycentric(images, A, bins, luminance, todo, t0, opts) -> ColorTransferResult:
    """The thesis' transfer: barycentric projections of the entropic plans."""
    times: dict[str, float] = {}
    k = len(images)
    grid = AbGrid(bins)
    labs, H, lcounts, _ = _analyze_all(images, bins, luminance, todo, nearest=False)
    times["analyze"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    cb = chrominance_barycenters(H, A, **opts)
    lmaps = luminance_maps(np.stack(lcounts), A) if luminance else None
    times["barycenter"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    rows, cols = cb.window
    nodes = grid.nodes
    empty1 = np.zeros(0, dtype=np.float32)
    out_images: list[list[np.ndarray | None]] = [[None] * k for _ in range(A.shape[0])]
    for b in range(A.shape[0]):
        for i in todo:
            img = images[i]
            src = pixels(img)
            out = np.empty_like(src)
            ta = np.ascontiguousarray(cb.maps[b, i, 0, rows, cols], dtype=np.float32)
            tb = np.ascontiguousarray(cb.maps[b, i, 1, rows, cols], dtype=np.float32)
            lut_l = empty1 if lmaps is None else lmaps[b, i].astype(np.float32)
            scale = code_scale(img.dtype)
            offset = 0.5 if img.dtype.kind in "ui" else 0.0
            _kernels.apply(labs[i], src, out, lut_l, L_MAX / LBINS, ta, tb,
                           nodes[rows.start], nodes[cols.start], grid.spacing, scale, offset)
            out_images[b][i] = out.reshape(img.shape).astype(img.dtype, copy=False)
    times["apply"] = time.perf_counter() - t2
    times["total"] = time.perf_counter() - t0
    return ColorTransferResult(
        images=out_images, alphas=A, barycenters=cb.barycenters, histograms=H, maps=cb.maps,
        luminance_maps=lmaps, window=cb.window, bins=bins, gamma=cb.gamma,
        mode="barycentric", entropy_bounds=cb.entropy_bounds, timings=times,
        iterations=cb.iterations, residual=cb.residual, converged=cb.converged)


def _mccann(plan: ExactPlan, grid: AbGrid, s: float) -> np.ndarray:
    """Histogram of the plan pushed through ``(1 - s) x + s y`` (bilinear on the nodes)."""
    i, j = np.nonzero(plan.plan)
    pts = (1 - s) * plan.sources[i] + s * plan.targets[j]
    index, weight = grid.splat(pts)
    m = plan.plan[i, j]
    out = sum(np.bincount(q, weights=w * m, minlength=grid.bins**2)
              for q, w in zip(index, weight, strict=True))
    return out.reshape(grid.bins, grid.bins)


def _targets(H, A, grid, opts):
    """For each weight row: ``(kind, data)`` with kind ``"vertex"`` (index), ``"pair"``
    (k = 2 interior) or ``"bary"`` (row of the entropic barycenters); the histograms the
    plans go to; the barycenter solve (or ``None``)."""
    k = H.shape[0]
    kinds, targets = [], np.zeros((A.shape[0],) + H.shape[1:])
    inner = [b for b in range(A.shape[0])
             if k > 2 and not np.any(A[b] == 1.0)]
    cb = chrominance_barycenters(H, A[inner], **opts) if inner else None
    for b in range(A.shape[0]):
        if np.any(A[b] == 1.0):
            j = int(np.flatnonzero(A[b] == 1.0)[0])
            kinds.append(("vertex", j))
            targets[b] = H[j]
        elif k == 2:
            kinds.append(("pair", None))
        else:
            targets[b] = cb.barycenters[inner.index(b)]
            kinds.append(("bary", b))
    return kinds, targets, cb


def _split(images, A, bins, luminance, settings, todo, t0, opts) -> ColorTransferResult:
    """The split transfer (module doc), towards each weight row's target; ``settings`` =
    ``(regularization, luminance_slope, resplit)``."""
    regularization, slope, resplit = settings
    times: dict[str, float] = {}
    k = len(images)
    grid = AbGrid(bins)
    labs, H, lcounts, (means, subs) = _analyze_all(images, bins, luminance, todo, nearest=True)
    times["analyze"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    kinds, targets, cb = _targets(H, A, grid, opts)
    lmaps = luminance_maps(np.stack(lcounts), A) if luminance else None
    plans: dict = {}

    def plan(i, key, target, target_means=None):
        if key not in plans:
            plans[key] = exact_plan(H[i], target, grid, means[i], target_means)
        return plans[key]

    if k == 2 and any(kind == "pair" for kind, _ in kinds):
        p01 = plan(0, (0, 1), H[1], means[1])
    for b, (kind, _) in enumerate(kinds):
        if kind == "pair":
            targets[b] = _mccann(p01, grid, float(A[b, 1]))
    times["plans"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    out_images: list[list[np.ndarray | None]] = [[None] * k for _ in range(A.shape[0])]
    for b, (kind, data) in enumerate(kinds):
        for i in todo:
            if A[b, i] == 1.0:
                out_images[b][i] = images[i].copy()
                continue
            if kind == "vertex":
                p, scale = plan(i, (i, data), H[data], means[data]), 1.0
                target = (H[data], means[data], None if subs is None else subs[data])
            elif kind == "pair":
                j = 1 - i
                p, scale = plan(i, (i, j), H[j], means[j]), float(A[b, j])
                target = (targets[b], None, None)
            else:
                p, scale = plan(i, (i, f"b{data}"), targets[b]), 1.0
                target = (targets[b], None, None)
            lut_l = None if lmaps is None else limit_slope(lmaps[b, i], lcounts[i], slope)
            out_images[b][i] = _recolor_split(images[i], labs[i], p, grid, scale, lut_l,
                                              (regularization, resplit), target)
    times["apply"] = time.perf_counter() - t2
    times["total"] = time.perf_counter() - t0
    residuals = [p.residual for p in plans.values()] + ([cb.residual] if cb else [])
    converged = all(p.converged for p in plans.values()) and (cb is None or cb.converged)
    full = (slice(0, bins), slice(0, bins))
    return ColorTransferResult(
        images=out_images, alphas=A, barycenters=targets, histograms=H, maps=None,
        luminance_maps=lmaps, window=full, bins=bins, gamma=opts["gamma"], mode="split",
        regularization=regularization, plans=plans,
        entropy_bounds=None if cb is None else cb.entropy_bounds, timings=times,
        iterations=0 if cb is None else cb.iterations,
        residual=float(max(residuals, default=0.0)), converged=converged)


def reduction(shape: tuple[int, int]) -> tuple[int, int, int]:
    """``(s, key radius, filter radius)``: block size of the reduced image and the two
    window radii in blocks (depend on the image size only)."""
    H, W = shape
    side = float(np.sqrt(H * W))
    s = max(1, int(np.sqrt(H * W / REDUCED_PIXELS)))
    filter_px = max(MIN_FILTER_RADIUS, FILTER_RADIUS * side)
    return (s, max(1, round(KEY_RADIUS * side / s)), max(1, round(filter_px / s)))


def _recolor_split(img, lab, plan, grid, scale, lut_l, settings, target):
    """Split (module doc), guided filter, then the filtered colours split again by the
    exact plan from their histogram to ``target`` = ``(histogram, node means or None,
    within-node offset counts or None)``, the fraction ``resplit`` of that correction
    applied (1: the output histogram is the target's again), then with offset counts (a
    target that is an input) every colour remapped inside its node to the target's
    offsets (:func:`~solvers.color.split.remap_within_nodes`); ``settings`` =
    ``(regularization, resplit)``."""
    regularization, resplit = settings
    shape = img.shape[:2]
    s, key_radius, filter_radius = reduction(shape)
    scratch = scratch_buffers(lab.shape[0])
    disp = split_displacements(lab, shape, plan, grid, scale=scale, s=s, radius=key_radius,
                               scratch=scratch)
    moved = None  # the remap's offset counts of the final colours, if counted on the way
    moments = moment_buffer(shape, s, GUIDE_CHANNELS)  # reused by each filter below
    if regularization > 0:
        coef = guided_coefficients(lab, disp, shape, strength=regularization, s=s,
                                   radius=filter_radius, nguide=GUIDE_CHANNELS,
                                   moments=moments)
        if resplit > 0:  # filtered field and its histogram in one pass
            hist, hmeans = moved_histogram(lab, disp, grid,
                                           guided=(coef, GUIDE_CHANNELS, s, shape[1], False))
            again = exact_plan(hist, target[0], grid, hmeans, target[1])
            corr = split_displacements(lab, shape, again, grid, scale=resplit, s=s,
                                       radius=key_radius, base=disp, scratch=scratch)
            coef = guided_coefficients(lab, corr, shape, strength=regularization, s=s,
                                       radius=CORRECTION_RADIUS, nguide=GUIDE_CHANNELS,
                                       moments=moments)
            if target[2] is None:
                SK.guided_field(lab, coef, GUIDE_CHANNELS, s, shape[1], corr)
                disp += corr
            else:  # disp += the filtered correction, and the remap's counts, in one pass
                del corr
                moved = moved_histogram(lab, disp, grid, target[2].shape[-1],
                                        guided=(coef, GUIDE_CHANNELS, s, shape[1], True))[2]
        else:
            SK.guided_field(lab, coef, GUIDE_CHANNELS, s, shape[1], disp)
    if target[2] is not None:
        remap_within_nodes(lab, disp, grid, target[2], moved)
    lut = np.zeros(0, dtype=np.float32) if lut_l is None else lut_l.astype(np.float32)
    shift = _gamut_shift(lab, lut, disp, shape, s, filter_radius, moments)
    src = pixels(img)
    out = np.empty_like(src)
    scale_out = code_scale(img.dtype)
    offset = 0.5 if img.dtype.kind in "ui" else 0.0
    SK.apply_field(lab, src, out, lut, L_MAX / LBINS, disp, _kernels._M_INV, scale_out,
                   offset, shift, s, shape[1])
    return out.reshape(img.shape).astype(img.dtype, copy=False)


def _gamut_shift(lab, lut, disp, shape, s, radius, mom):
    """Coefficients ``(2, h, w)`` (``a``, ``b`` of ``a L*/100 + b``) of a smooth L* shift
    towards the gamut: each recolored pixel's move to its nearest in-gamut L*
    (:func:`~solvers.color._split_kernels.gamut_lightness`, 0 in the gamut),
    guided-filtered by the input's L* with in-gamut pixels down-weighted.  A per-pixel
    move adds L* texture the input does not have; the smooth shift keeps the input's
    structure, and the colours it leaves out of the gamut lose chroma at their L*.
    ``mom``: a :func:`~solvers.color.regularize.moment_buffer` (overwritten)."""
    W = shape[1]
    mom = mom[:SK.n_moments(1)]  # one guide channel
    mom.fill(0.0)
    SK.gamut_shift_moments(lab, lut, L_MAX / LBINS, disp, _kernels._M_INV, float(GAMUT_REACH),
                           W, s, min(s, GAMUT_STRIDE), GAMUT_IN_WEIGHT, mom)
    coef = guided_solve_moments(mom, 1, GAMUT_SHIFT_STRENGTH, radius, weighted=True,
                                max_gain=GAMUT_MAX_SLOPE / SK.GUIDE_SCALE)
    return np.ascontiguousarray(coef[[0, 2]])
