"""Reference geodesic distances on triangle meshes (potpourri3d).

Used as ground truth for transport costs (exact LPs with geodesic costs) and for
comparison with transport-based distances.
"""

from __future__ import annotations

from weakref import WeakKeyDictionary

import numpy as np
import potpourri3d as pp3d

from solvers.domains.mesh import TriangleMesh

_FLIP_SOLVERS: WeakKeyDictionary = WeakKeyDictionary()


def polyhedral_geodesic_distances(mesh: TriangleMesh, sources, targets) -> np.ndarray:
    """(len(sources), len(targets)) geodesic lengths at the mesh's unit-area scale.

    Each pair is a locally shortest path found by potpourri3d's edge-flip solver
    (the Dijkstra path straightened by edge flips; exact polyhedral geodesics in
    practice). The solver is built once per mesh. Cost grows with the number of pairs:
    meant for small supports (LP oracles, benchmarks).
    """
    solver = _FLIP_SOLVERS.get(mesh)
    if solver is None:
        solver = _FLIP_SOLVERS[mesh] = pp3d.EdgeFlipGeodesicSolver(mesh.vertices, mesh.faces)
    out = np.zeros((len(sources), len(targets)))
    for i, s in enumerate(sources):
        for j, t in enumerate(targets):
            if s != t:
                path = solver.find_geodesic_path(int(s), int(t))
                out[i, j] = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    return out
