"""Shared fixtures: the real test meshes beside the repository (``../shared/meshes``)."""

from __future__ import annotations

from pathlib import Path

import pytest

# CI clones the repository with ``shared/`` beside it, exactly like /work/main and /work/shared.
MESHES_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
MESH_FILES = sorted(p.name for p in MESHES_DIR.glob("*.obj"))
# Meshes below this many vertices are cheap enough for dense or eigen-solver checks.
SMALL_MESHES = ("woody.obj", "suzanne.obj", "beetle.obj", "spot.obj")

_MESH_CACHE: dict = {}


def load_shared_mesh(name: str, **kwargs):
    """Load ``../shared/meshes/<name>`` once per test session (keyed by name and options).

    Tests must not mutate the returned mesh; heat kernels it caches are shared.
    """
    from solvers.domains import load_mesh

    key = (name, tuple(sorted(kwargs.items())))
    if key not in _MESH_CACHE:
        _MESH_CACHE[key] = load_mesh(MESHES_DIR / name, **kwargs)
    return _MESH_CACHE[key]


@pytest.fixture(scope="session")
def meshes_dir() -> Path:
    """Directory of the shared real test meshes; fails loudly if it is missing."""
    assert MESHES_DIR.is_dir(), f"shared meshes not found at {MESHES_DIR}"
    return MESHES_DIR


@pytest.fixture(scope="session")
def shared_mesh(meshes_dir):
    """``shared_mesh("spot.obj")`` -> the loaded TriangleMesh, cached for the session."""
    return load_shared_mesh
