"""tests/service/liveserver.py under parallel test workers: a live server whose free port
another process took first starts again on another port."""

from __future__ import annotations

import socket

import httpx
import liveserver
from liveserver import API


def test_api_whose_port_was_taken_restarts_on_another(tmp_path, monkeypatch):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        ports = iter([taken.getsockname()[1]])
        real_free_port = liveserver.free_port
        monkeypatch.setattr(liveserver, "free_port", lambda: next(ports, None) or
                            real_free_port())
        api = API({"OTGEO_DATA_DIR": str(tmp_path / "data"), "OTGEO_WORKERS": "0"}, tmp_path)
        try:
            first = api.port
            api.wait_healthy(timeout=120)
            assert api.port != first
            assert httpx.get(api.url + "/healthz").status_code == 200
            assert "address already in use" in api.log(10**6)
        finally:
            api.stop()
