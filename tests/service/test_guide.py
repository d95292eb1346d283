"""The built documentation is served at /guide/ (offline, like /docs) when present, and
/guide/ explains how to build it when it is not."""

from __future__ import annotations

from fastapi.testclient import TestClient

from service.app import create_app
from service.settings import Settings


def _client(tmp_path, guide_dir):
    settings = Settings(data_dir=tmp_path / "data", queue="immediate", guide_dir=guide_dir)
    return TestClient(create_app(settings, start_background=False))


def test_built_guide_is_served_with_its_assets(tmp_path):
    site = tmp_path / "html"
    (site / "guide").mkdir(parents=True)
    (site / "index.html").write_text("<html><body>otgeo guide</body></html>")
    (site / "guide" / "emd.html").write_text("<html><body>chapter 2</body></html>")
    with _client(tmp_path, site) as client:
        index = client.get("/guide/")
        assert index.status_code == 200 and "otgeo guide" in index.text
        page = client.get("/guide/guide/emd.html")
        assert page.status_code == 200 and "chapter 2" in page.text
        assert client.get("/guide/nope.html").status_code == 404


def test_missing_guide_says_how_to_build_it(tmp_path):
    with _client(tmp_path, tmp_path / "absent") as client:
        response = client.get("/guide/")
        assert response.status_code == 404
        error = response.json()["error"]
        assert "make docs" in error["message"]
        assert str(tmp_path) not in error["message"]  # no server paths in responses


def test_guide_built_while_the_server_runs_is_served(tmp_path):
    """``make docs`` with ``make serve`` running: the guide is served without a restart (and
    a removed build answers the 404 again)."""
    site = tmp_path / "html"
    with _client(tmp_path, site) as client:
        assert client.get("/guide/").status_code == 404
        site.mkdir()
        (site / "index.html").write_text("<html><body>otgeo guide</body></html>")
        index = client.get("/guide/")
        assert index.status_code == 200 and "otgeo guide" in index.text
        (site / "index.html").unlink()
        missing = client.get("/guide/")
        assert missing.status_code == 404 and "make docs" in missing.json()["error"]["message"]
