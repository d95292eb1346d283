"""Fixtures for service tests: an app on a temporary data dir, and a test client.

Plain helpers (``upload_mesh``, ``assert_error``) live in ``service_testing.py``; import them
from there (``tests`` itself is not importable as a package: a dependency ships one).
"""

from __future__ import annotations

import contextlib

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.settings import Settings


@pytest.fixture
def make_client(tmp_path):
    """``make_client(**settings)`` -> a started TestClient (closed at teardown).

    Defaults: data in ``tmp_path``, ``queue="immediate"`` (jobs run inside the request).
    """
    stack = contextlib.ExitStack()

    def make(**overrides) -> TestClient:
        overrides.setdefault("data_dir", tmp_path)
        overrides.setdefault("queue", "immediate")
        app = create_app(Settings(**overrides))
        return stack.enter_context(TestClient(app))

    yield make
    stack.close()


@pytest.fixture
def client(make_client) -> TestClient:
    return make_client()


@pytest.fixture
def woody(client, meshes_dir, shared_mesh):
    """``(mesh, domain id)`` of woody.obj loaded here and uploaded to ``client``."""
    from service_testing import upload_mesh

    return shared_mesh("woody.obj"), upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
