"""Shared fixtures: the real test meshes beside the repository (``../shared/meshes``).

Helpers live in ``tests/shared_meshes.py``; import them from there, not from ``conftest``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from shared_meshes import MESHES_DIR, load_shared_mesh


@pytest.fixture(scope="session")
def meshes_dir() -> Path:
    """Directory of the shared real test meshes; fails loudly if it is missing."""
    assert MESHES_DIR.is_dir(), f"shared meshes not found at {MESHES_DIR}"
    return MESHES_DIR


@pytest.fixture(scope="session")
def shared_mesh(meshes_dir):
    """``shared_mesh("spot.obj")`` -> the loaded TriangleMesh, cached for the session."""
    return load_shared_mesh


def edge_flip_geodesics(mesh, sources, targets):
    """(len(sources), len(targets)) polyhedral geodesic lengths between mesh vertices.

    potpourri3d's edge-flip solver shortens the Dijkstra path to a locally shortest
    geodesic (exact polyhedral geodesics in practice); the solver is kept per mesh.
    """
    import numpy as np
    import potpourri3d as pp3d

    solver = _FLIP_SOLVERS.get(id(mesh))
    if solver is None:
        solver = _FLIP_SOLVERS[id(mesh)] = pp3d.EdgeFlipGeodesicSolver(mesh.vertices, mesh.faces)
    out = np.zeros((len(sources), len(targets)))
    for i, s in enumerate(sources):
        for j, t in enumerate(targets):
            if s != t:
                path = solver.find_geodesic_path(int(s), int(t))
                out[i, j] = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    return out


_FLIP_SOLVERS: dict = {}


@pytest.fixture(scope="session")
def flip_geodesics():
    """``flip_geodesics(mesh, sources, targets)`` -> exact-in-practice geodesic lengths."""
    return edge_flip_geodesics
