r"""Exact plans between ab histograms, and pixels split in the plans' proportions.

The barycentric projection of a plan (thesis §3.7, :mod:`solvers.color.chrominance`)
sends all pixels of one ab bin to one colour, the mean of the target colours the plan
gives that bin: when the plan splits a source colour between two targets, the output
gets a third colour neither image has.  Here the plan itself is kept:

* the histograms count every pixel at its nearest node of a ``bins × bins`` ab grid
  (:class:`~solvers.color.chrominance.AbGrid`);
* :func:`exact_plan` solves the discrete problem

  .. math::  \min_{\pi \ge 0} \sum_{ij} \pi_{ij} |x_i - y_j|^2 \quad
             \text{s.t. } \pi 1 = \mu, \; \pi^T 1 = \nu

  between the occupied nodes by the network simplex (POT ``ot.emd``), and measures its
  marginal violation;
* :func:`integer_split` turns row ``i`` of the plan into pixel counts ``n_ij`` summing to
  the ``n_i`` pixels of node ``i`` (largest remainders);
* :func:`split_displacements` orders the pixels of each source node by a spatially
  coherent key (the box-smoothed ab around the pixel, projected on the principal
  direction of its targets; ties in raster order) and the node's targets by their
  projection on the same direction, and gives consecutive runs of ``n_ij`` pixels the
  displacement :math:`y_j - x_i` (node points: the mean ab of each node's pixels, so
  the output's mean colour within every target node is the target's).  No random draw:
  equal inputs give equal outputs.

Every pixel then lands at the target node the plan sends it to, so the output histogram
is the target's up to the binning and the integer rounding (before regularization,
:mod:`solvers.color.regularize`, and the clipping to the sRGB gamut).

Within a node the pixels keep their offsets from their source node's mean, so the
output's distribution inside each node is the source's, not the target's; where a node
holds much mass (a grey atom, a dark sky) that shows at scales finer than the grid.
:func:`remap_within_nodes` moves every colour inside its node by the 1-D monotone
(quantile) map :math:`F_t^{-1} \circ F_m`, per axis, from the output's offsets to the
target's, both counted in ``K`` sub-bins per node (CDFs linear inside a sub-bin): the
output's per-axis marginals in every node become the target's up to the sub-bins, and
no colour leaves its node.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.color import _split_kernels as K
from solvers.color.chrominance import AbGrid
from solvers.color.regularize import box_filter
from solvers.errors import ConvergenceError

KEY_LEVELS = 4096


@dataclass
class ExactPlan:
    """A plan between two node histograms: ``rows`` / ``cols`` the occupied source /
    target node indices (flat, a* major), ``sources`` / ``targets`` their ab points
    ``(R, 2)`` / ``(C, 2)`` (the mean ab of each node's pixels), ``plan`` ``(R, C)``
    masses, ``cost`` :math:`\\sum \\pi_{ij} |x_i - y_j|^2`, ``residual`` the L1 violation
    of both marginals, ``converged`` the network simplex reported an optimum."""

    rows: np.ndarray
    cols: np.ndarray
    sources: np.ndarray
    targets: np.ndarray
    plan: np.ndarray
    cost: float
    residual: float
    converged: bool


def node_points(grid: AbGrid, index: np.ndarray) -> np.ndarray:
    nodes = grid.nodes
    return np.stack([nodes[index // grid.bins], nodes[index % grid.bins]], axis=1)


def exact_plan(source: np.ndarray, target: np.ndarray, grid: AbGrid,
               source_means: np.ndarray | None = None,
               target_means: np.ndarray | None = None) -> ExactPlan:
    """Optimal plan (squared ab distance) between two ``(bins, bins)`` histograms; each
    node's mass sits at its ``(2, bins²)`` mean ab (default: the node itself)."""
    import ot

    mu = np.asarray(source, dtype=np.float64).ravel()
    nu = np.asarray(target, dtype=np.float64).ravel()
    rows, cols = np.flatnonzero(mu > 0), np.flatnonzero(nu > 0)
    a, b = mu[rows] / mu[rows].sum(), nu[cols] / nu[cols].sum()
    xs = node_points(grid, rows) if source_means is None else source_means[:, rows].T
    ys = node_points(grid, cols) if target_means is None else target_means[:, cols].T
    M = ot.dist(xs, ys)
    plan, log = ot.emd(a, b, M, numItermax=50_000_000, log=True)
    residual = float(np.abs(plan.sum(1) - a).sum() + np.abs(plan.sum(0) - b).sum())
    if not np.all(np.isfinite(plan)):
        raise ConvergenceError("the network simplex returned a non-finite plan")
    return ExactPlan(rows=rows, cols=cols, sources=xs, targets=ys, plan=plan,
                     cost=float((plan * M).sum()),
                     residual=residual, converged=int(log["result_code"]) == 1)


def integer_split(plan: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Integer pixel counts ``(R, C)`` whose rows sum to ``counts`` ``(R,)`` and that are
    the plan's rows scaled to ``counts`` rounded by largest remainders (ties: lower
    column first)."""
    row = plan.sum(axis=1)
    r, c = np.nonzero(plan)  # row-major: columns ascending within each row
    share = plan[r, c] / np.where(row > 0, row, 1.0)[r] * counts[r]
    base = np.floor(share).astype(np.int64)
    missing = counts.astype(np.int64) - np.bincount(r, weights=base, minlength=len(counts)
                                                    ).astype(np.int64)
    order = np.lexsort((-(share - base), r))  # by row, then largest remainder first
    first = np.searchsorted(r[order], np.arange(len(counts)))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order)) - first[r[order]]
    out = np.zeros(plan.shape, dtype=np.int64)
    out[r, c] = base + (rank < missing[r])
    return out


def _principal_directions(points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Unit principal axis ``(R, 2)`` of each row's weighted target points."""
    w = weights / np.maximum(weights.sum(axis=1, keepdims=True), 1e-300)
    mean = w @ points
    xx = w @ points[:, 0] ** 2 - mean[:, 0] ** 2
    yy = w @ points[:, 1] ** 2 - mean[:, 1] ** 2
    xy = w @ (points[:, 0] * points[:, 1]) - mean[:, 0] * mean[:, 1]
    theta = 0.5 * np.arctan2(2 * xy, xx - yy)
    return np.stack([np.cos(theta), np.sin(theta)], axis=1)


def block_mean_ab(lab: np.ndarray, base: np.ndarray, shape: tuple[int, int],
                  s: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean a*, b* (of ``lab[:, 1:] + base``; ``base`` empty: of ``lab``) over ``s × s``
    blocks (the last partial blocks averaged over what they hold), ``(h, w)`` each."""
    H, W = shape
    h, w = -(-H // s), -(-W // s)
    sums = np.zeros((3, h, w))
    K.block_sums_ab(lab, base, W, s, sums)
    return sums[0] / sums[2], sums[1] / sums[2]


def split_displacements(lab: np.ndarray, shape: tuple[int, int], plan: ExactPlan,
                        grid: AbGrid, *, scale: float, s: int, radius: int,
                        base: np.ndarray | None = None,
                        scratch: tuple | None = None) -> np.ndarray:
    """Per-pixel ab displacements ``(N, 2)`` float32: ``scale`` times ``y_j - x_i`` for the
    target node ``j`` each pixel of source node ``i`` is given (module doc).

    ``lab`` ``(N, 3)`` the image's Lab (C order over ``shape``), its ab moved by ``base``
    ``(N, 2)`` if given; the ordering key smooths ab by a box of ``2 radius + 1`` cells
    on the image reduced by ``s``; ``scratch``: :func:`scratch_buffers` for the image, to
    reuse across calls (fresh pages of a 12 Mpx buffer cost more than filling it)."""
    H, W = shape
    key, row, straddle = scratch_buffers(lab.shape[0]) if scratch is None else scratch
    if base is None:
        base = np.zeros((0, 2), dtype=np.float32)
    a, b = block_mean_ab(lab, base, shape, s)
    size = 2 * radius + 1
    sa, sb = box_filter([a, b], size)  # in place
    R = len(plan.rows)
    row_of = np.full(grid.bins**2, -1, dtype=np.int64)
    row_of[plan.rows] = np.arange(R)
    targets = plan.targets
    dirs = _principal_directions(targets, plan.plan)
    # the same float32 grid constants as the histogram pass, so both bin pixels alike
    K.keys(lab, base, W, s, sa, sb, np.float32(grid.nodes[0]), np.float32(grid.spacing), grid.bins,
           row_of, dirs, key, row)
    lo, hi, missing = K.key_ranges(key, row, R)
    if missing:  # the plan was built from this image's own histogram
        raise RuntimeError("a pixel's ab node is missing from the plan's support")
    levels = np.zeros((R, KEY_LEVELS), dtype=row.dtype)
    K.level_counts(key, row, lo, hi, levels)
    counts = levels.sum(axis=1, dtype=np.int64)  # pixels per row
    split = integer_split(plan.plan, counts)
    # each row's targets in the order of their projection on the row's direction
    proj = targets @ dirs.T  # (C, R)
    offsets = np.zeros(R + 1, dtype=np.int64)
    cols_list, ends_list = [], []
    for r in range(R):
        nz = np.flatnonzero(split[r])
        nz = nz[np.argsort(proj[nz, r], kind="stable")]
        cols_list.append(nz)
        ends_list.append(np.cumsum(split[r, nz]))
        offsets[r + 1] = offsets[r] + len(nz)
    cols = np.concatenate(cols_list)
    ends = np.concatenate(ends_list).astype(np.int64)
    disp = targets[cols] - np.repeat(plan.sources, np.diff(offsets), axis=0)
    K.exclusive_cumsum(levels)  # now each level's first rank in its row
    out = np.empty((lab.shape[0], 2), dtype=np.float32)
    K.assign(key, row, lo, hi, levels, offsets, ends, disp, float(scale), out, straddle)
    return out


def scratch_buffers(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel scratch of :func:`split_displacements` for ``n`` pixels: ordering key
    (float32), source row and pixel flags; rows (and the rank counters, which share
    their dtype) in int32 when ``n`` fits it."""
    index = np.int32 if n < 2**31 else np.int64
    return (np.empty(n, dtype=np.float32), np.empty(n, dtype=index),
            np.empty(n, dtype=np.bool_))


def moved_histogram(lab: np.ndarray, disp: np.ndarray, grid: AbGrid, subbins: int = 0,
                    guided: tuple | None = None):
    """Nearest-node histogram ``(bins, bins)`` (pixel counts) of ``lab[:, 1:] + disp`` and
    the mean ab ``(2, bins²)`` at each node (with ``subbins > 0`` also the counts
    ``(2, bins², subbins)`` of the offsets from the node in that many sub-bins).

    ``guided`` = ``(coef, nguide, s, width, add)``: ``disp`` is first set to (``add``:
    increased by) the guided filter's field of those coefficients
    (:func:`~solvers.color._split_kernels.guided_field`), in the same pass."""
    from solvers.color._kernels import _chunks

    n2 = grid.bins**2
    chunks = _chunks(lab.shape[0])
    counts = np.zeros((chunks, n2))
    sums = np.zeros((chunks, 2, n2))
    sub = np.zeros((chunks, 2, n2, subbins) if subbins else (chunks, 1, 1, 0))
    lo, h = np.float32(grid.nodes[0]), np.float32(grid.spacing)
    if guided is None:
        K.moved_histogram(lab, disp, lo, h, grid.bins, counts, sums, sub)
    else:
        coef, nguide, s, width, add = guided
        K.guided_moved_histogram(lab, coef, nguide, s, width, disp, bool(add), lo, h,
                                 grid.bins, counts, sums, sub)
    total = counts.sum(axis=0)
    out = total.reshape(grid.bins, grid.bins), sums.sum(axis=0) / np.maximum(total, 1.0)
    return (*out, sub.sum(axis=0)) if subbins else out


def within_node_cdfs(moved: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per axis and node, the CDFs ``(2, n, K + 1)`` at the ``K + 1`` sub-bin edges of the
    counts ``moved`` and ``target`` ``(2, n, K)``; both the uniform CDF (the remap is then
    the identity) where either has no mass."""
    K = moved.shape[-1]
    uniform = np.arange(K + 1) / K

    def cdf(counts, total):
        c = np.concatenate([np.zeros(counts.shape[:2] + (1,)), np.cumsum(counts, -1)], -1)
        return c / np.where(total > 0, total, 1.0)[..., None]

    tm, tt = moved.sum(-1), target.sum(-1)
    both = ((tm > 0) & (tt > 0))[..., None]
    return (np.where(both, cdf(moved, tm), uniform), np.where(both, cdf(target, tt), uniform))


def remap_within_nodes(lab: np.ndarray, disp: np.ndarray, grid: AbGrid,
                       target_sub: np.ndarray, moved: np.ndarray | None = None) -> None:
    """Move each colour ``lab[:, 1:] + disp`` inside its nearest node so that, per node
    and axis, the offsets' distribution is ``target_sub`` ``(2, bins², K)`` (module doc);
    ``disp`` updated in place.  ``moved``: the colours' own offset counts (same layout,
    :func:`moved_histogram`) if already counted."""
    if moved is None:
        moved = moved_histogram(lab, disp, grid, target_sub.shape[-1])[2]
    lo, h = np.float32(grid.nodes[0]), np.float32(grid.spacing)
    fm, ft = (c.astype(np.float32) for c in within_node_cdfs(moved, target_sub))
    # per moved sub-bin j: the target sub-bin holding fm[j] (the kernel steps on from it)
    y = np.clip(fm[..., :-1], np.float32(1e-7), np.float32(1 - 1e-7))
    start = np.zeros_like(fm)
    start[..., :-1] = (ft[..., None, 1:-1] < y[..., :, None]).sum(-1)
    cdfs = np.ascontiguousarray(np.stack([fm, ft, start], axis=2).transpose(1, 0, 2, 3))
    K.remap_in_nodes(lab, disp, lo, h, grid.bins, cdfs)
