"""Fixtures for service tests: an app on a temporary data dir, and a test client."""

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


def upload_mesh(client, path, **data):
    with open(path, "rb") as fh:
        return client.post("/v1/domains", files={"file": (path.name, fh)}, data=data)


def assert_error(response, status: int, field: str | None, code: str | None = None) -> dict:
    assert response.status_code == status, response.text
    err = response.json()["error"]
    assert set(err) == {"code", "message", "field"}
    assert err["field"] == field, err
    if code is not None:
        assert err["code"] == code, err
    assert err["message"]
    return err
