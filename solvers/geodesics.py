"""Exact geodesic distances on triangle meshes: the ground truth of transport costs.

Used by the exact transport method (:mod:`solvers.transport.exact`), as ground truth for
transport costs in tests and benchmarks (exact LPs with geodesic costs), and for comparison
with transport-based distances.

Two exact polyhedral algorithms, both on the *fan-split* surface (below):

* ``"mmp"`` — Mitchell–Mount–Papadimitriou exact geodesics (Kirsanov's implementation in
  ``tvb-gdist``) from one source to every vertex, optionally stopped at a distance bound;
  cost grows with the area covered (plus a mesh setup per call), not with the number of
  targets.
* ``"edge-flip"`` — potpourri3d's edge-flip solver (Sharp & Crane 2020): the Dijkstra path
  straightened by edge flips into a locally shortest geodesic, one pair at a time; cheap per
  pair, so it wins for a few pairs on a large mesh.

Non-manifold meshes.  Both algorithms need a manifold surface.  A vertex whose incident
faces form several fans (an "hourglass", e.g. one vertex of cow.obj) or that lies on an
edge with more than two faces (beetle.obj) is split into one copy per fan, which gives a
manifold surface (possibly in several pieces).  The copies of one vertex are the same point,
so a path may pass from one copy to another for free: distances on the original surface are
recovered exactly *through vertices* by a closure over these junction vertices (exact
distances from every junction, then shortest paths in the junction graph).  Paths that would
cross a non-manifold edge in its interior instead of at a vertex are not represented (an
overestimate of at most the length of the shared edge's detour; none on hourglass vertices).
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
from collections import deque
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, shortest_path

from solvers.errors import InputError
from solvers.validation import check_choice

if TYPE_CHECKING:  # the mesh calls these solvers for its ground distances, not the reverse
    from solvers.domains.mesh import TriangleMesh

METHODS = ("mmp", "edge-flip")


@dataclass
class _Pieces:
    """The fan-split (manifold) surface of a mesh and its junction closure."""

    vertices: np.ndarray  # (n_split, 3)
    faces: np.ndarray  # (n_faces, 3) int32, indices into vertices
    owner: np.ndarray  # (n_split,) original vertex of each copy
    first_copy: np.ndarray  # (n,) one split vertex of each original vertex
    junctions: np.ndarray  # original vertices with more than one copy
    closure: np.ndarray | None = None  # (J, n) distances from each junction (through junctions)
    longest_edge: np.ndarray | None = None  # (n_faces,) longest edge of each face

    def __post_init__(self):
        corners = self.vertices[self.faces]  # (n_faces, 3, 3)
        self.longest_edge = np.linalg.norm(corners - np.roll(corners, 1, axis=1),
                                           axis=2).max(axis=1)


def _split_fans(vertices: np.ndarray, f: np.ndarray):
    """One vertex per (vertex, fan of incident faces): the manifold surface of ``f``."""
    nv, nf = len(vertices), len(f)
    half = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    edges, edge_of_half, counts = np.unique(np.sort(half, axis=1), axis=0,
                                            return_inverse=True, return_counts=True)
    edge_of_half = edge_of_half.reshape(-1)
    face_of_half = np.tile(np.arange(nf), 3)
    interior = np.flatnonzero(counts == 2)
    order = np.argsort(edge_of_half, kind="stable")
    starts = np.searchsorted(edge_of_half[order], interior)
    f1, f2 = face_of_half[order[starts]], face_of_half[order[starts + 1]]
    corner = np.arange(3 * nf).reshape(3, nf).T  # corner id of (face, local vertex)
    pairs = []
    for endpoint in (0, 1):  # corners of one vertex across a manifold edge share a fan
        vert = edges[interior, endpoint]
        c1 = corner[f1, np.argmax(f[f1] == vert[:, None], axis=1)]
        c2 = corner[f2, np.argmax(f[f2] == vert[:, None], axis=1)]
        pairs.append(np.stack([c1, c2], axis=1))
    pairs = np.concatenate(pairs) if pairs else np.zeros((0, 2), dtype=np.int64)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                          shape=(3 * nf, 3 * nf))
    _, fan = connected_components(graph, directed=False)
    corner_vertex = f.T.reshape(-1)
    keys, new = np.unique(np.stack([corner_vertex, fan], axis=1), axis=0, return_inverse=True)
    faces = new.reshape(-1).reshape(3, nf).T.astype(np.int32)
    owner = keys[:, 0]
    first = np.full(nv, -1, dtype=np.int64)
    first[owner[::-1]] = np.arange(len(owner))[::-1]
    counts_per_vertex = np.bincount(owner, minlength=nv)
    return (np.ascontiguousarray(vertices[owner], dtype=np.float64), faces, owner, first,
            np.flatnonzero(counts_per_vertex > 1))


def _pieces(mesh: TriangleMesh) -> _Pieces:
    def build():
        v, f, owner, first, junctions = _split_fans(np.asarray(mesh.vertices, np.float64),
                                                    np.asarray(mesh.faces, np.int64))
        pieces = _Pieces(v, f, owner, first, junctions)
        if len(junctions):
            raw = np.stack([_mmp_split(pieces, int(j)) for j in junctions])  # (J, n)
            # Shortest paths in the junction graph.
            between = shortest_path(np.ascontiguousarray(raw[:, junctions]), directed=False)
            # Through junctions: d(j, x) = min_k D*(j, k) + raw(k, x).
            closure = raw.copy()
            for k in range(len(junctions)):
                np.minimum(closure, between[:, k, None] + raw[k], out=closure)
            pieces.closure = closure
        return pieces

    return mesh.operators.get(("geodesic-pieces",), build)


def _mmp_split(pieces: _Pieces, source: int, bound: float | None = None) -> np.ndarray:
    """(n,) exact distances on the split surface from all copies of original ``source``
    (``inf`` beyond ``bound`` when given; vertices a little beyond it may be finite).

    A bounded solve runs on the faces near the source only (:func:`_ball_faces`): tvb-gdist
    sets its mesh up anew on every call, at a cost proportional to the mesh it is given, so
    a solve of radius ``bound`` costs about the area it covers instead of the whole mesh's
    setup, with the same distances within ``bound``."""
    import gdist

    copies = np.flatnonzero(pieces.owner == source)
    finite = bound is not None and np.isfinite(bound)
    keep = _ball_faces(pieces, copies[0], float(bound)) if finite else None
    if keep is None:  # the whole surface
        vertices, faces, sources, used = pieces.vertices, pieces.faces, copies, None
    else:
        faces = pieces.faces[keep]
        used = np.zeros(len(pieces.vertices), dtype=bool)
        used[faces.reshape(-1)] = True
        renumber = np.cumsum(used) - 1  # keeps the vertices' and faces' order
        vertices = np.ascontiguousarray(pieces.vertices[used])
        faces, sources = renumber[faces].astype(np.int32), renumber[copies]
    extra = {"max_distance": float(bound)} if finite else {}
    d = gdist.compute_gdist(vertices, faces, source_indices=sources.astype(np.int32), **extra)
    d = np.where(d > 1e30, np.inf, d)  # other pieces are unreachable on the split surface
    if used is not None:
        d_all = np.full(len(pieces.vertices), np.inf)
        d_all[used] = d
        d = d_all
    out = np.full(len(pieces.first_copy), np.inf)
    np.minimum.at(out, pieces.owner, d)
    return out


# A bounded solve runs on the whole surface when the faces near its source are more than
# this fraction of the faces (the copy would save little)
LOCAL_SOLVE_FRACTION = 0.5


def _ball_faces(pieces: _Pieces, vertex: int, bound: float) -> np.ndarray | None:
    """Mask of the faces that may meet the straight ball of radius ``bound`` around split
    vertex ``vertex`` (a vertex within ``bound`` plus the face's longest edge: every point of
    a face is that close to one of its corners), or None when that is most of the surface.

    A path of length at most ``bound`` from the source stays in that ball, so it crosses
    only these faces: the distances within ``bound`` on them are those on the whole surface
    (the vertices on the new boundary lie outside the ball, beyond ``bound``, where MMP
    stops; tests/test_exact_route.py compares both bitwise)."""
    v = pieces.vertices
    near = np.sqrt(np.square(v - v[vertex]).sum(axis=1))
    keep = near[pieces.faces].min(axis=1) <= bound + pieces.longest_edge
    if keep.mean() > LOCAL_SOLVE_FRACTION:
        return None
    return keep


def _edge_graph(mesh: TriangleMesh):
    """Vertex graph weighted by edge lengths (its path lengths bound geodesics above)."""
    def build():
        e = np.asarray(mesh.edges)
        w = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)
        return sp.csr_matrix((w, (e[:, 0], e[:, 1])), shape=(mesh.n, mesh.n))

    return mesh.operators.get(("edge-length-graph",), build)


def _one_to_all(pieces: _Pieces, source: int, bound: float | None = None) -> np.ndarray:
    """Exact distances from ``source``; correct at least up to ``bound`` (an upper bound
    of the wanted distances: MMP stops propagating there)."""
    d = _mmp_split(pieces, source, None if bound is None else bound * (1 + 1e-9) + 1e-12)
    if pieces.closure is not None:
        via = d[pieces.junctions][:, None] + pieces.closure  # through a junction
        d = np.minimum(d, via.min(axis=0))
    return d


def _edge_flip_solver(mesh: TriangleMesh, pieces: _Pieces):
    import potpourri3d as pp3d

    return mesh.operators.get(("edge-flip-solver",),
                              lambda: pp3d.EdgeFlipGeodesicSolver(pieces.vertices,
                                                                  pieces.faces))


def _check_indices(mesh: TriangleMesh, values, name: str) -> np.ndarray:
    idx = np.asarray(values, dtype=np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= mesh.n):
        raise InputError(f"{name} must be vertex indices in [0, {mesh.n - 1}]", field=name)
    return idx


# Model of one MMP solve (tvb-gdist, one core of the 2-core machine), calibrated offline by
# ``bench/distance_routes.py calibrate`` (fit and data: bench/results/distance_routes.md) and
# committed: the mesh setup of every call, MMP_SETUP_PER_VERTEX * n, plus MMP_FULL_COEF *
# n ** MMP_FULL_POWER for a one-to-all solve, of which a solve stopped at a bound pays about
# (fraction of vertices reached) ** MMP_REACH_POWER.  A pure function of the sizes: never of
# timings measured in the process (a default decision must not depend on a worker's history).
MMP_SETUP_PER_VERTEX = 1.15e-6
MMP_FULL_COEF = 2.87e-7
MMP_FULL_POWER = 1.458
MMP_REACH_POWER = 1.204


def mmp_solve_seconds(n: int, reach: float = 1.0) -> float:
    """Modelled seconds of one MMP solve on an ``n``-vertex mesh reaching the fraction
    ``reach`` of the vertices (constants above).

    Parameters
    ----------
    n : int
        Vertices of the mesh.
    reach : float
        Fraction of the vertices the solve reaches.

    Returns
    -------
    float
    """
    return (MMP_SETUP_PER_VERTEX * n
            + MMP_FULL_COEF * n ** MMP_FULL_POWER * min(max(reach, 0.0), 1.0) ** MMP_REACH_POWER)


def edge_path_distances(mesh: TriangleMesh, sources) -> np.ndarray:
    """``(len(sources), n)`` shortest edge-path lengths (Dijkstra on the edge graph, unit
    area): upper bounds of the geodesic distances, ``inf`` across components.

    Parameters
    ----------
    mesh : TriangleMesh
        The surface (``n`` vertices).
    sources : array of int
        Source vertices.

    Returns
    -------
    (len(sources), n) array
    """
    from scipy.sparse.csgraph import dijkstra

    src = _check_indices(mesh, sources, "sources")
    return np.atleast_2d(dijkstra(_edge_graph(mesh), directed=False, indices=src))


def geodesic_distances_within(mesh: TriangleMesh, source: int, bound: float) -> np.ndarray:
    """``(n,)`` exact geodesic distances from ``source`` where they are at most ``bound``,
    ``inf`` where they are larger (MMP stops propagating past ``bound``; ``bound=inf``: a
    one-to-all solve).

    Parameters
    ----------
    mesh : TriangleMesh
        The surface.
    source : int
        The source vertex.
    bound : float
        Largest distance computed.

    Returns
    -------
    (n,) array
    """
    pieces = _pieces(mesh)
    finite = bool(np.isfinite(bound))
    d = _one_to_all(pieces, int(source), float(bound) if finite else None)
    if finite:
        d = np.where(d <= bound, d, np.inf)
    return d


def geodesic_distances(mesh: TriangleMesh, sources, targets=None, *, method: str = "mmp",
                       should_cancel=None) -> np.ndarray:
    """Exact polyhedral geodesic distances ``(len(sources), len(targets))`` at unit area.

    ``targets=None``: every vertex.  ``method``: ``"mmp"`` (default: one exact solve from
    each source, or target when there are fewer, stopped at the largest edge-path distance
    to the other side), ``"edge-flip"`` (one locally shortest path per pair, only on meshes
    without junction vertices; a locally shortest path, so never shorter and sometimes
    longer than the MMP distance).  Vertices on other connected
    components are at distance ``inf``.  ``should_cancel()`` is checked between solves.

    Parameters
    ----------
    mesh, sources : TriangleMesh, array of int
        The surface and the source vertices.
    targets : array of int, optional
        Target vertices (default: every vertex).
    method : {"mmp", "edge-flip"}
        Exact MMP, or locally shortest edge-flip paths.
    should_cancel : callable, optional
        ``should_cancel() -> bool``, checked between solves.

    Returns
    -------
    (len(sources), len(targets)) array
    """
    check_choice(method, METHODS, "method")
    src = _check_indices(mesh, sources, "sources")
    dst = np.arange(mesh.n) if targets is None else _check_indices(mesh, targets, "targets")
    pieces = _pieces(mesh)
    if method == "edge-flip" and len(pieces.junctions):
        raise InputError("the edge-flip method needs a manifold mesh; use method='mmp'",
                         field="method")
    if method == "mmp":
        flip = len(dst) < len(src)  # symmetric: solve from the smaller side
        rows, cols = (dst, src) if flip else (src, dst)
        out = np.zeros((len(rows), len(cols)))
        if len(cols) < mesh.n:  # stop each solve past the farthest wanted vertex
            from scipy.sparse.csgraph import dijkstra

            graph = _edge_graph(mesh)
        for i, s in enumerate(rows):
            if should_cancel is not None and should_cancel():
                from solvers.errors import CancelledError

                raise CancelledError("cancelled between geodesic solves")
            bound = None
            if len(cols) < mesh.n:
                reach = dijkstra(graph, directed=False, indices=int(s))[cols]
                finite = reach[np.isfinite(reach)]
                bound = float(finite.max()) if finite.size else 0.0
            out[i] = _one_to_all(pieces, int(s), bound)[cols]
        return out.T if flip else out
    solver = _edge_flip_solver(mesh, pieces)
    labels = mesh.component_labels
    out = np.zeros((len(src), len(dst)))
    for i, s in enumerate(src):
        for j, t in enumerate(dst):
            if labels[s] != labels[t]:
                out[i, j] = np.inf
            elif s != t:
                path = solver.find_geodesic_path(int(pieces.first_copy[s]),
                                                 int(pieces.first_copy[t]))
                out[i, j] = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    return out


def polyhedral_geodesic_distances(mesh: TriangleMesh, sources, targets) -> np.ndarray:
    """(len(sources), len(targets)) exact geodesic lengths at the mesh's unit-area scale.

    The oracle of tests and benchmarks: potpourri3d's edge-flip paths on manifold meshes
    (as before), exact MMP distances with the junction closure on non-manifold ones (cow,
    beetle), see the module docstring.

    Parameters
    ----------
    mesh : TriangleMesh
        The surface (``n`` vertices).
    sources, targets : array of int
        Vertices.

    Returns
    -------
    (len(sources), len(targets)) array
    """
    pieces = _pieces(mesh)
    method = "mmp" if len(pieces.junctions) else "edge-flip"
    return geodesic_distances(mesh, sources, targets, method=method)


# Result rows of :func:`all_pairs_geodesics` in flight from its worker processes (at most,
# with at most 4 processes; 2 per process beyond): within the n-vectors the memory estimate
# gives a geodesic solve's work (``GEODESIC_WORK_VECTORS`` in solvers.domains.mesh), which
# the parent does not use while the children solve.
ALL_PAIRS_ROWS_IN_FLIGHT = 8
# The pieces of the running all-pairs computations by token: forked children inherit them
# (nothing is pickled to them but row indices)
_FORKED_PIECES: dict[int, _Pieces] = {}
_TOKENS = itertools.count()


def _rows_in_worker(token: int, sources: np.ndarray) -> np.ndarray:
    return np.stack([_one_to_all(_FORKED_PIECES[token], int(s)) for s in sources])


def all_pairs_geodesics(mesh: TriangleMesh, *, processes: int | None = None,
                        dtype=np.float64, should_cancel=None) -> np.ndarray:
    """All-pairs exact geodesics ``(n, n)`` (one MMP solve from each vertex; the same values
    as :func:`geodesic_distances` with every vertex on both sides), solved in parallel over
    the sources by ``processes`` forked worker processes (the MMP solver holds the GIL, so
    threads do not help: 16 solves on spot took 1.33 s in one thread, 1.29 s in two).

    Parameters
    ----------
    mesh : TriangleMesh
        The surface.
    processes : int, optional
        Worker processes (default: the CPUs this process may use; 1, or in a daemonic
        process, which may have no children: solved here).
    dtype : numpy dtype
        Of the result (``float32`` halves its memory; the solves are float64).
    should_cancel : callable, optional
        ``should_cancel() -> bool``, checked between solves (or their chunks).

    Returns
    -------
    (n, n) array
        ``d[i, j]``: the distance between vertices ``i`` and ``j`` at unit area.
    """
    count = len(os.sched_getaffinity(0)) if processes is None else int(processes)
    if count < 1:
        raise InputError(f"processes must be at least 1, got {processes!r}", field="processes")
    n, pieces = mesh.n, _pieces(mesh)
    out = np.empty((n, n), dtype=dtype)
    if count == 1 or n < 4 * count or multiprocessing.current_process().daemon:
        for s in range(n):
            _check_cancel(should_cancel)
            out[s] = _one_to_all(pieces, s)
        return out
    import gdist  # noqa: F401  (imported before the fork: the children import nothing)

    rows = max(1, ALL_PAIRS_ROWS_IN_FLIGHT // (2 * count))
    chunks = iter([np.arange(k, min(k + rows, n)) for k in range(0, n, rows)])
    token = next(_TOKENS)
    _FORKED_PIECES[token] = pieces
    try:
        _solve_in_children(out, token, count, chunks, should_cancel)
    finally:
        _FORKED_PIECES.pop(token, None)
    return out


def _solve_in_children(out, token: int, count: int, chunks, should_cancel) -> None:
    """Rows ``chunks`` of ``out`` solved by ``count`` forked processes, ``2 count`` chunks
    in flight."""
    pending: deque = deque()
    # forked: the children only run the MMP solver on the pieces they inherit (no locks, no
    # threads), and start in milliseconds where a spawned child imports the library (~1 s)
    # and re-runs an unguarded main script
    with ProcessPoolExecutor(count, mp_context=multiprocessing.get_context("fork")) as pool:
        def submit_next() -> None:
            chunk = next(chunks, None)
            if chunk is not None:
                pending.append((chunk, pool.submit(_rows_in_worker, token, chunk)))

        for _ in range(2 * count):
            submit_next()
        try:
            while pending:
                _check_cancel(should_cancel)
                chunk, future = pending.popleft()
                out[chunk] = future.result()
                del future  # its rows: not kept beside the result
                submit_next()
        finally:
            for _, future in pending:
                future.cancel()


def _check_cancel(should_cancel) -> None:
    if should_cancel is not None and should_cancel():
        from solvers.errors import CancelledError

        raise CancelledError("cancelled between geodesic solves")
