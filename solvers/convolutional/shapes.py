r"""Shape interpolation by Wasserstein barycenters of indicator volumes (thesis §3.7).

A solid shape :math:`S \subset \mathbb{R}^d` (``d = 2`` or ``3``) becomes the
normalized indicator :math:`\mu_S = \mathbb{1}_S / |S|` sampled on a regular
grid; the interpolation of shapes :math:`S_1..S_k` with weights
:math:`\lambda` is the convolutional Wasserstein barycenter (eq. 3.13,
Alg. 2, :func:`solvers.convolutional.barycenter`)

.. math:: \mu^\star = \arg\min_\mu \sum_i \lambda_i W^2_{2,H_t}(\mu, \mu_{S_i}),

and the output surface is an iso-surface :math:`\{\mu^\star = \tau\}`
(marching cubes in 3-D, marching squares in 2-D).

Iso-level rule: the barycenter is a blurred density, not an indicator, so
the level is chosen so that the *extracted surface encloses the
interpolated volume* :math:`V^\star = \sum_i \lambda_i |S_i|` (volumes
interpolate linearly; a translated or rotated shape keeps its volume).
:math:`|S_i|` is the exact enclosed volume of a watertight input mesh
(trimesh), else it is measured on the grid, as cell volume times
:math:`\sum v / \max v` for an input volume ``v`` (the cell count for a
binary indicator or a voxelized open mesh), and :math:`\tau` is found by bisection on the volume
enclosed by the extracted (closed) surface, which decreases with
:math:`\tau`.

Meshes are voxelized with trimesh (surface voxels, then the interior filled)
onto one common grid framing all inputs; the grid is normalized so its
longest axis spans ``[0, 1]`` (as in POT's convolutional barycenter), so
``gamma`` is relative to the size of the framed inputs, and the output
vertices are mapped back to the input coordinates.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from solvers.domains.grid import Grid
from solvers.errors import InputError
from solvers.monitor import SolverResult
from solvers.validation import check_weights


@dataclass
class Voxelization:
    """Filled indicator of a mesh on a normalized grid.

    Input coordinates of grid point ``u`` are ``origin + scale * u``.
    """

    indicator: np.ndarray  # bool, grid.shape
    grid: Grid
    origin: np.ndarray  # (d,)
    scale: float

    @property
    def volume(self) -> float:
        """Enclosed volume in input units: filled cells times the cell volume."""
        cell = float(np.prod(self.grid.spacing)) * self.scale ** self.grid.ndim
        return float(self.indicator.sum()) * cell


@dataclass
class ShapeResult(SolverResult):
    """Interpolated shape: barycenter volume and its iso-surface.

    Attributes
    ----------
    volume : array
        Barycenter masses per grid node (``grid.shape``, summing to 1).
    grid : Grid
        The normalized grid.
    vertices : (V, d) array
        Surface vertices, in input coordinates.
    faces : (F, 3) or (E, 2) int array
        Triangles in 3-D (outward oriented, closed); segments of closed polylines in 2-D.
    level : float
        The iso value, in the units of ``volume``.
    target_volume, enclosed_volume : float
        Volume aimed at and enclosed, in input units (areas in 2-D).
    origin : (d,) array
        Input coordinates of grid point 0.
    scale : float
        Input units per grid unit.
    gamma : float
        Regularization used.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    volume: np.ndarray  # grid.shape, masses summing to 1
    grid: Grid
    vertices: np.ndarray
    faces: np.ndarray
    level: float
    target_volume: float
    enclosed_volume: float
    origin: np.ndarray
    scale: float
    gamma: float = float("nan")


def _as_trimesh(shape, field: str):
    """A trimesh.Trimesh in input coordinates from a Trimesh, TriangleMesh, path or (V, F)."""
    import trimesh

    from solvers.domains import supports
    from solvers.domains.mesh import TriangleMesh

    if isinstance(shape, trimesh.Trimesh):
        return shape
    if isinstance(shape, (str, os.PathLike)):
        shape = TriangleMesh.from_file(shape)
    if supports(shape, "faces"):
        return trimesh.Trimesh(shape.vertices * shape.length_scale, shape.faces, process=False)
    if isinstance(shape, tuple) and len(shape) == 2:
        vertices = np.asarray(shape[0], dtype=np.float64)
        faces = np.asarray(shape[1])
        if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
            raise InputError("a mesh must be (vertices (V, 3), faces (F, 3))", field=field)
        return trimesh.Trimesh(vertices, faces, process=False)
    raise InputError(
        f"{field} must be a mesh (trimesh.Trimesh, TriangleMesh, path or (vertices, faces)), "
        f"got {type(shape).__name__}",
        field=field,
    )


def _frame(lo: np.ndarray, hi: np.ndarray, resolution: int, padding: int):
    """Normalized isotropic grid framing the box [lo, hi], centered, ``padding`` empty cells."""
    if int(resolution) < 2 * padding + 3:
        raise InputError(f"resolution must be at least {2 * padding + 3}", field="resolution")
    resolution = int(resolution)
    extent = hi - lo
    longest = float(extent.max())
    if not np.isfinite(longest) or longest <= 0:
        raise InputError("shapes have an empty bounding box", field="shapes")
    cell = longest / (resolution - 1 - 2 * padding)  # input units per cell
    shape = np.minimum(np.ceil(extent / cell - 1e-9).astype(int) + 1 + 2 * padding, resolution)
    shape = np.maximum(shape, 2)
    h = 1.0 / (resolution - 1)
    grid = Grid(tuple(int(s) for s in shape), bounds=[(0.0, (s - 1) * h) for s in shape])
    origin = lo - 0.5 * ((shape - 1) * cell - extent)
    return grid, origin, cell / h


def voxelize(mesh_or_path, resolution: int = 64, *, padding: int = 2,
             frame: tuple[Grid, np.ndarray, float] | None = None) -> Voxelization:
    """Filled voxel indicator of a closed mesh (trimesh voxelization + interior fill).

    Parameters
    ----------
    mesh_or_path : trimesh.Trimesh, TriangleMesh (input units via ``length_scale``),
        path of a mesh file, or ``(vertices, faces)``.
    resolution : grid nodes along the longest axis of the framed box.
    padding : empty cells kept around the shape on every side.
    frame : ``(grid, origin, scale)`` to voxelize onto an existing frame (as
        :func:`shape_interpolation` does for several meshes); ``resolution`` and
        ``padding`` are then ignored.

    Returns
    -------
    Voxelization
        ``indicator`` (bool, ``grid.shape``) on ``grid``; input coordinates of grid
        point ``u`` are ``origin + scale * u``.

    Notes
    -----
    Surface voxels are those hit by the (subdivided) surface; cavities enclosed
    by them are filled (``VoxelGrid.fill``).  An open mesh yields its shell only.
    """
    import trimesh.voxel.creation

    mesh = _as_trimesh(mesh_or_path, "mesh")
    if len(mesh.faces) == 0:
        raise InputError("mesh has no faces", field="mesh")
    if frame is None:
        frame = _frame(mesh.bounds[0], mesh.bounds[1], resolution, padding)
    grid, origin, scale = frame
    cell = scale * grid.spacing[0]  # input units per cell (isotropic frame)
    in_cells = trimesh.Trimesh((mesh.vertices - origin) / cell, mesh.faces, process=False)
    # Subdivide until edges are below half a cell; trimesh's own estimate (max_iter=None)
    # can fall one short, so allow a few more halvings.
    longest = float(np.max(in_cells.edges_unique_length, initial=0.0))
    halvings = max(int(np.ceil(np.log2(max(longest, 1e-12) / 0.5))), 0) + 3
    voxels = trimesh.voxel.creation.voxelize_subdivide(in_cells, pitch=1.0, max_iter=halvings)
    filled = voxels.fill()
    index = np.rint(np.asarray(filled.points)).astype(np.int64)
    inside = np.all((index >= 0) & (index < np.asarray(grid.shape)), axis=1)
    indicator = np.zeros(grid.shape, dtype=bool)
    indicator[tuple(index[inside].T)] = True
    return Voxelization(indicator, grid, np.asarray(origin, dtype=np.float64), float(scale))


def _enclosed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume (3-D, divergence theorem) or signed area (2-D, shoelace)."""
    if len(faces) == 0:
        return 0.0
    if vertices.shape[1] == 3:
        v0, v1, v2 = (vertices[faces[:, j]] for j in range(3))
        return float(np.einsum("ij,ij->i", v0, np.cross(v1, v2)).sum() / 6.0)
    a, b = vertices[faces[:, 0]], vertices[faces[:, 1]]
    return float(0.5 * (a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]).sum())


def _contour(volume: np.ndarray, level: float, spacing) -> tuple[np.ndarray, np.ndarray]:
    """Closed iso-surface of a zero-padded volume, vertices in grid coordinates (from 0)."""
    padded = np.pad(volume, 1)
    if volume.ndim == 3:
        from skimage.measure import marching_cubes

        verts, faces, _, _ = marching_cubes(padded, level, spacing=tuple(spacing))
        verts = verts - np.asarray(spacing)
        return verts, faces.astype(np.int64)
    from skimage.measure import find_contours

    verts, edges, count = [], [], 0
    for line in find_contours(padded, level):
        ring = line[:-1] if np.allclose(line[0], line[-1]) else line
        m = len(ring)
        verts.append((ring - 1.0) * np.asarray(spacing))
        edges.append(count + np.stack([np.arange(m), (np.arange(m) + 1) % m], axis=1))
        count += m
    if not verts:
        return np.empty((0, 2)), np.empty((0, 2), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(edges)


def iso_surface(volume: np.ndarray, grid: Grid, target_volume: float, *, rtol: float = 1e-4,
                max_bisections: int = 60) -> tuple[float, np.ndarray, np.ndarray, float]:
    """Iso level whose closed surface encloses ``target_volume`` (grid units), by bisection.

    The enclosed volume decreases with the level; bisection is geometric on
    ``(0, max(volume)]`` and stops once the enclosed volume is within ``rtol`` of the
    target.

    Parameters
    ----------
    volume : array
        Barycenter masses per grid node (``grid.shape``, 2-D or 3-D).
    grid : Grid
        The grid.
    target_volume : float
        Volume (area in 2-D) to enclose, in grid units.
    rtol : float
        Relative tolerance on the enclosed volume.
    max_bisections : int
        Bisection budget.

    Returns
    -------
    level : float
        The iso value.
    vertices : (V, d) array
        Surface vertices, in grid coordinates.
    faces : (F, 3) or (E, 2) int array
        Outward-oriented triangles (3-D) or closed-polyline segments (2-D).
    enclosed : float
        The enclosed volume.
    """
    spacing = np.asarray(grid.spacing)
    top = float(volume.max())
    cell = float(np.prod(spacing))
    # Initial guess: the level whose super-level set has the target number of cells.
    ranked = np.sort(volume.ravel())[::-1]
    count = int(np.clip(round(target_volume / cell), 1, ranked.size))
    guess = float(ranked[count - 1])
    lo, hi = top * 1e-12, top * (1.0 - 1e-12)
    level = min(max(guess, lo), hi)
    best = None
    for _ in range(max_bisections):
        verts, faces = _contour(volume, level, spacing)
        enclosed = _enclosed_volume(verts, faces)
        if enclosed < 0:  # orient outward
            faces = faces[:, ::-1].copy()
            enclosed = -enclosed
        if best is None or abs(enclosed - target_volume) < abs(best[3] - target_volume):
            best = (level, verts, faces, enclosed)
        if abs(enclosed - target_volume) <= rtol * target_volume or hi / lo < 1 + 1e-12:
            break
        if enclosed > target_volume:
            lo = level
        else:
            hi = level
        level = float(np.sqrt(lo * hi))
    level, verts, faces, enclosed = best
    return level, verts + np.asarray([b[0] for b in grid.bounds]), faces, enclosed


def _grid_sizes(arrays, grid: Grid) -> np.ndarray:
    """Volume of each (indicator-like) array on the grid: cell volume times sum / max."""
    cell = float(np.prod(grid.spacing))
    return np.array([cell * v.sum() / v.max() for v in arrays])


def _volumes_from_arrays(shapes, grid: Grid | None):
    arrays = []
    for i, shape in enumerate(shapes):
        try:
            v = np.asarray(shape, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InputError(f"shapes[{i}] is not a numeric array: {exc}", field="shapes") from exc
        arrays.append(v)
    dims = {v.shape for v in arrays}
    if len(dims) != 1:
        raise InputError(f"volumes must share one shape, got {sorted(dims)}", field="shapes")
    shape = arrays[0].shape
    if len(shape) not in (2, 3):
        raise InputError(f"volumes must be 2-D or 3-D arrays, got shape {shape}", field="shapes")
    for i, v in enumerate(arrays):
        if not np.all(np.isfinite(v)) or np.any(v < 0) or not np.any(v > 0):
            raise InputError(f"shapes[{i}] must be finite, non-negative and not all zero",
                             field="shapes")
    if grid is None:
        h = 1.0 / (max(shape) - 1)
        grid = Grid(shape, bounds=[(0.0, (s - 1) * h) for s in shape])
    elif tuple(grid.shape) != shape:
        raise InputError(f"grid shape {grid.shape} does not match volumes {shape}", field="grid")
    return arrays, grid, np.zeros(len(shape)), 1.0, _grid_sizes(arrays, grid)


def _volumes_from_meshes(shapes, resolution: int, padding: int):
    meshes = [_as_trimesh(s, f"shapes[{i}]") for i, s in enumerate(shapes)]
    lo = np.min([m.bounds[0] for m in meshes], axis=0)
    hi = np.max([m.bounds[1] for m in meshes], axis=0)
    frame = _frame(lo, hi, resolution, padding)
    grid, origin, scale = frame
    arrays = []
    for i, mesh in enumerate(meshes):
        vox = voxelize(mesh, frame=frame)
        if not vox.indicator.any():
            raise InputError(f"shapes[{i}] voxelizes to nothing", field="shapes")
        arrays.append(vox.indicator.astype(np.float64))
    # Sizes in grid units: exact volume of watertight meshes, else the voxel count.
    sizes = _grid_sizes(arrays, grid)
    for i, mesh in enumerate(meshes):
        if mesh.is_watertight and mesh.volume > 0:
            sizes[i] = float(mesh.volume) / scale**3
    return arrays, grid, origin, scale, sizes


@dataclass
class PreparedShapes:
    """Input volumes on one grid: ``arrays`` (k volumes of ``grid.shape``), their sizes
    ``sizes`` (k,) in grid units, and the frame (``origin``, ``scale``) back to input units."""

    arrays: list
    grid: Grid
    origin: np.ndarray
    scale: float
    sizes: np.ndarray


def prepare_shapes(shapes: Sequence, *, resolution: int = 64, grid: Grid | None = None,
                   padding: int = 2) -> PreparedShapes:
    """Voxelize meshes onto one grid framing them all (or check volumes on ``grid``): the
    first step of :func:`shape_interpolation`, done once for several weight vectors."""
    shapes = list(shapes)
    if not shapes:
        raise InputError("need at least one shape", field="shapes")
    if all(isinstance(s, np.ndarray) for s in shapes):
        parts = _volumes_from_arrays(shapes, grid)
    else:
        parts = _volumes_from_meshes(shapes, resolution, padding)
    return PreparedShapes(*parts)


def _interpolate(prepared: PreparedShapes, weights: np.ndarray, gamma: float,
                 options: dict) -> ShapeResult:
    from solvers.convolutional import barycenter

    grid, origin, scale = prepared.grid, prepared.origin, prepared.scale
    target = float(weights @ prepared.sizes)
    mus = np.stack([v.ravel() / v.sum() for v in prepared.arrays], axis=1)
    result = barycenter(grid, mus, weights, gamma=gamma, **options)
    volume = np.asarray(result.masses, dtype=np.float64).reshape(grid.shape)

    level, verts, faces, enclosed = iso_surface(volume, grid, target)
    d = grid.ndim
    return ShapeResult(
        volume=volume,
        grid=grid,
        vertices=origin + scale * verts,
        faces=faces,
        level=level,
        target_volume=target * scale**d,
        enclosed_volume=enclosed * scale**d,
        iterations=int(result.iterations),
        residual=float(result.residual),
        converged=bool(result.converged),
        origin=np.asarray(origin, dtype=np.float64),
        scale=float(scale),
        gamma=float(gamma),
    )


def _barycenter_options(t, substeps, sharpen, tol, max_iter, progress, should_cancel) -> dict:
    options = {"t": t, "substeps": substeps, "sharpen": sharpen, "tol": tol,
               "progress": progress, "should_cancel": should_cancel}
    if max_iter is not None:
        options["max_iter"] = max_iter
    return options


def shape_interpolation(
    shapes: Sequence,
    weights=None,
    *,
    gamma: float,
    resolution: int = 64,
    grid: Grid | None = None,
    padding: int = 2,
    t: float | None = None,
    substeps: int = 1,
    sharpen: bool = False,
    tol: float = 1e-5,
    max_iter: int | None = None,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> ShapeResult:
    r"""Interpolate solid shapes as the Wasserstein barycenter of their indicator volumes.

    Thesis §3.7: :math:`\mu^\star = \arg\min_\mu \sum_i \lambda_i W^2_{2,H_t}(\mu, \mu_{S_i})`
    (eq. 3.13, Alg. 2) with :math:`\mu_{S_i}` the normalized indicators, then
    the iso-surface enclosing :math:`V^\star = \sum_i \lambda_i |S_i|` (module docstring).

    Parameters
    ----------
    shapes : ``k`` meshes (trimesh.Trimesh, TriangleMesh, paths, ``(vertices, faces)``),
        voxelized onto one grid framing them all (``resolution`` nodes along the
        longest axis, ``padding`` empty cells around); or ``k`` non-negative
        2-D/3-D arrays of one shape, sampled on ``grid`` (default: isotropic,
        longest axis ``[0, 1]``).
    weights : ``(k,)`` barycentric weights (default uniform), normalized to sum 1.
    resolution, padding : int
        Voxelization of mesh inputs (:func:`voxelize`).
    grid : Grid, optional
        The grid of array inputs.
    gamma, t, substeps, sharpen, tol, max_iter, progress, should_cancel :
        passed to :func:`solvers.convolutional.barycenter` (``gamma`` in squared
        units of the normalized grid).

    Returns
    -------
    ShapeResult
        ``volume`` (grid.shape barycenter masses), surface ``vertices`` (input
        coordinates) and ``faces``, ``level``, ``target_volume``, ``enclosed_volume`` and
        the barycenter's ``iterations``, ``residual``, ``converged``.
    """
    prepared = prepare_shapes(shapes, resolution=resolution, grid=grid, padding=padding)
    weights = check_weights(weights, len(prepared.arrays))
    options = _barycenter_options(t, substeps, sharpen, tol, max_iter, progress,
                                  should_cancel)
    return _interpolate(prepared, weights, gamma, options)


def shape_interpolations(
    shapes: Sequence,
    weights,
    *,
    gamma: float | None = None,
    resolution: int = 64,
    padding: int = 2,
    t: float | None = None,
    substeps: int = 1,
    sharpen: bool = False,
    tol: float = 1e-5,
    max_iter: int | None = None,
    progress: Callable[[int, float], None] | None = None,
    should_cancel: Callable[[], bool] | None = None,
) -> list[ShapeResult]:
    r""":func:`shape_interpolation` for each row of ``weights`` ``(T, k)`` (frames of an
    interpolation: for two shapes, rows ``(1 - t, t)``), voxelizing the shapes once.

    ``gamma``: default the ``"shapes"`` regularization policy of the grid,
    :math:`(2h)^2` with ``h`` its spacing (:func:`solvers.regularization.choose_regularization`);
    ``progress(iteration, residual)`` counts iterations over all frames."""
    from solvers.regularization import choose_regularization

    prepared = prepare_shapes(shapes, resolution=resolution, padding=padding)
    if gamma is None:
        gamma = choose_regularization(prepared.grid, purpose="shapes").gamma
    k = len(prepared.arrays)
    rows = np.asarray(weights, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] != k or len(rows) == 0:
        raise InputError(f"weights must be a (T, {k}) array, one row per frame",
                         field="weights")
    rows = [check_weights(row, k, f"weights[{i}]") for i, row in enumerate(rows)]
    done = 0

    def frame_progress(iteration, residual, *rest):
        if progress is not None:
            progress(done + iteration, residual)

    out = []
    for row in rows:
        options = _barycenter_options(t, substeps, sharpen, tol, max_iter, frame_progress,
                                      should_cancel)
        out.append(_interpolate(prepared, row, gamma, options))
        done += out[-1].iterations
    return out


def shaded_view(volume: np.ndarray, level: float, *, axis: int = 2, pixels: int = 160
                ) -> np.ndarray:
    """``(H, W)`` gray image in [0, 1] of the super-level set ``{volume >= level}`` seen along
    ``axis`` (from its low end): depth of the first crossing along each ray (linear between
    grid nodes), shaded by the normals of that depth map under a fixed light, background 1.
    Nearest-neighbour upsampled so the longest side has about ``pixels`` pixels."""
    v = np.moveaxis(np.asarray(volume, dtype=np.float64), axis, -1)
    if v.ndim != 3:
        raise InputError("shaded_view needs a 3-D volume", field="volume")
    inside = v >= level
    hit = inside.any(axis=-1)
    first = np.argmax(inside, axis=-1)
    before = np.take_along_axis(v, np.maximum(first - 1, 0)[..., None], -1)[..., 0]
    at = np.take_along_axis(v, first[..., None], -1)[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(first > 0, (level - before) / (at - before), 1.0)
    depth = first - 1.0 + np.clip(np.nan_to_num(frac, nan=1.0), 0.0, 1.0)
    depth = np.where(hit, depth, np.nan)
    filled = np.where(hit, depth, np.nanmax(depth) if hit.any() else 0.0)
    gx, gy = np.gradient(filled)
    normal = np.stack([gx, gy, -np.ones_like(gx)], axis=-1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    light = np.array([-0.45, -0.35, -0.82])
    light /= np.linalg.norm(light)
    shade = 0.15 + 0.85 * np.clip(normal @ light, 0.0, 1.0)
    image = np.where(hit, shade, 1.0).T  # first remaining axis horizontal
    zoom = max(1, int(round(pixels / max(image.shape))))
    return np.kron(image, np.ones((zoom, zoom)))
