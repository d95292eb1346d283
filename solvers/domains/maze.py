"""Planar maze meshes: a grid of square cells with the wall cells removed, triangulated.

Test and gallery geometry for path planning (thesis Fig. 2.12).  A layout is a list of
equal-length strings, one character per cell: ``#`` is a wall (no triangles), any other
character an open cell; letters other than ``#`` and ``.`` name regions (occupants, exits)
whose vertices :func:`maze_mesh` returns.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from solvers.domains.mesh import TriangleMesh
from solvers.errors import InputError

# Fig. 2.12: a perfect maze (its passages form a tree, so the open region is simply
# connected) with two occupants (A, B) and two exits (E, F).  Through the maze A is nearer
# to E and B to F, although B is nearer to E as the crow flies.
FIG_2_12_LAYOUT = (
    "#############",
    "#E..#.......#",
    "###.#####.#.#",
    "#...#...B.#.#",
    "#.###.#####.#",
    "#.#.A.#...#.#",
    "#.###.#.###.#",
    "#.....#.#...#",
    "#######.#.###",
    "#...#...#.#.#",
    "#.#.#.#.#.#.#",
    "#.#...#....F#",
    "#############",
)


@dataclass
class Maze:
    """``mesh`` (unit area, z = 0), ``regions``: letter → vertex indices of its cells, and
    ``cell_size`` the side of one cell at unit area.

    Attributes
    ----------
    mesh : TriangleMesh
        The maze (unit area, z = 0).
    regions : dict of str to array of int
        Letter -> vertex indices of its cells.
    cell_size : float
        Side of one cell at unit area.
    """

    mesh: TriangleMesh
    regions: dict[str, np.ndarray]
    cell_size: float


def _check_layout(layout: Sequence[str], subdivisions: int) -> tuple[int, int]:
    rows = list(layout)
    if not rows or any(len(r) != len(rows[0]) for r in rows) or not rows[0]:
        raise InputError("layout must be non-empty rows of equal length", field="layout")
    if not isinstance(subdivisions, (int, np.integer)) or subdivisions < 1:
        raise InputError("subdivisions must be a positive integer", field="subdivisions")
    if all(c == "#" for r in rows for c in r):
        raise InputError("layout has no open cell", field="layout")
    return len(rows), len(rows[0])


def maze_mesh(layout: Sequence[str] = FIG_2_12_LAYOUT, subdivisions: int = 2) -> Maze:
    """Triangulate the open cells of ``layout`` (row 0 at the top), each as a grid of
    ``subdivisions`` × ``subdivisions`` squares split into two triangles, welded along
    shared sides.

    Two open cells touching only at a corner would pinch the surface into a non-manifold
    vertex; the Fig. 2.12 layout has none.

    Parameters
    ----------
    layout : sequence of str
        Rows of the maze: ``#`` walls, any other character an open cell (letters name
        regions); default the layout of Fig. 2.12.
    subdivisions : int
        Squares per cell side.

    Returns
    -------
    Maze
    """
    n_rows, n_cols = _check_layout(layout, subdivisions)
    s = int(subdivisions)
    index = -np.ones((n_rows * s + 1, n_cols * s + 1), dtype=np.int64)  # lattice → vertex
    faces, cell_vertices = [], {}
    for r, row in enumerate(layout):
        for c, ch in enumerate(row):
            if ch == "#":
                continue
            i0, j0 = r * s, c * s
            block = index[i0:i0 + s + 1, j0:j0 + s + 1]
            new = block < 0
            block[new] = np.arange(new.sum()) + index.max() + 1
            a, b = block[:-1, :-1], block[:-1, 1:]
            d, e = block[1:, :-1], block[1:, 1:]
            faces.append(np.stack([a, d, e], -1).reshape(-1, 3))
            faces.append(np.stack([a, e, b], -1).reshape(-1, 3))
            if ch != ".":
                cell_vertices.setdefault(ch, []).append(block.ravel().copy())
    ii, jj = np.nonzero(index >= 0)
    order = np.argsort(index[ii, jj])
    vertices = np.column_stack([jj[order], -ii[order], np.zeros(len(order))]) / s
    mesh = TriangleMesh(vertices.astype(np.float64), np.concatenate(faces))
    open_cells = sum(ch != "#" for row in layout for ch in row)
    regions = {k: np.unique(np.concatenate(v)) for k, v in cell_vertices.items()}
    return Maze(mesh=mesh, regions=regions, cell_size=float(np.sqrt(1.0 / open_cells)))
