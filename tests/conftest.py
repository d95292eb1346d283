"""Shared fixtures: the real test meshes beside the repository (``../shared/meshes``).

Helpers live in ``tests/shared_meshes.py``; import them from there, not from ``conftest``.
"""

from __future__ import annotations

import os
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


# BLAS/OpenMP pools (service.cli.BLAS_ENV): one thread per pytest-xdist worker
BLAS_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                    "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def pytest_configure(config):
    """With ``-n N``, each worker gets one BLAS thread unless the caller set a number: N
    workers of one thread per core, rather than N x cores threads spinning on the cores. Set
    in the controller, before it starts the workers (numpy reads it when it loads)."""
    if getattr(config.option, "numprocesses", None) and "PYTEST_XDIST_WORKER" not in os.environ:
        for name in BLAS_THREAD_VARS:
            os.environ.setdefault(name, "1")


# The test files that take longest (pytest --durations, summed per file; an order only, never a
# selection). make test hands whole files to its workers in collection order: these go first,
# so that none of them is left running alone at the end.
LONGEST_FILES = (
    "service/test_schemathesis.py", "service/test_readme_examples.py",
    "service/test_result_budget.py", "service/test_jobs.py", "service/test_fuzz.py",
    "service/test_two_workers.py", "service/test_hostile_inputs.py", "service/test_sdk.py",
    "test_color.py", "service/test_domain_builder.py", "service/test_distance_matrices.py",
    "browser/test_viewer_browser.py", "test_color_kernels.py", "service/test_scale.py",
    "test_color_split.py", "test_convolutional.py",
)


def pytest_collection_modifyitems(config, items):
    """Longest files first (stable: the rest keep their order)."""
    rank = {name: i for i, name in enumerate(LONGEST_FILES)}
    tests = Path(__file__).parent

    def key(item):
        path = Path(item.fspath)
        name = path.relative_to(tests).as_posix() if path.is_relative_to(tests) else ""
        return rank.get(name, len(rank))

    items.sort(key=key)

