"""The real test meshes beside the repository (``../shared/meshes``), loaded once per session.

Import from here (``from shared_meshes import load_shared_mesh``), not from ``conftest``:
several ``conftest.py`` files exist (tests/, tests/service/) and whichever pytest imported
last owns the module name ``conftest``.
"""

from __future__ import annotations

from pathlib import Path

# CI clones the repository with ``shared/`` beside it, exactly like /work/main and /work/shared.
MESHES_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
MESH_FILES = sorted(p.name for p in MESHES_DIR.glob("*.obj"))

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


def hat_bump(mesh, i: int, r: float):
    """The service's bump ``{"vertex": i, "radius": r}``: masses ``a_j max(0, 1 - |x_j -
    x_i| / r)`` (unit-area coordinates), normalized."""
    import numpy as np

    d = np.linalg.norm(mesh.vertices - mesh.vertices[i], axis=1)
    m = mesh.areas * np.clip(1 - d / r, 0, None)
    return m / m.sum()
