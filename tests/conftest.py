"""Shared fixtures: the real test meshes beside the repository (``../shared/meshes``).

Helpers live in ``tests/shared_meshes.py``; import them from there, not from ``conftest``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from shared_meshes import MESHES_DIR, load_shared_mesh

from solvers.geodesics import polyhedral_geodesic_distances


@pytest.fixture(scope="session")
def meshes_dir() -> Path:
    """Directory of the shared real test meshes; fails loudly if it is missing."""
    assert MESHES_DIR.is_dir(), f"shared meshes not found at {MESHES_DIR}"
    return MESHES_DIR


@pytest.fixture(scope="session")
def shared_mesh(meshes_dir):
    """``shared_mesh("spot.obj")`` -> the loaded TriangleMesh, cached for the session."""
    return load_shared_mesh


@pytest.fixture(scope="session")
def flip_geodesics():
    """``flip_geodesics(mesh, sources, targets)`` -> exact-in-practice geodesic lengths."""
    return polyhedral_geodesic_distances
