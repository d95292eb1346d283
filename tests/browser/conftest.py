"""Browser tests of the viewer: a live ``otgeo serve`` and Debian's Chromium driven by
Playwright (``executable_path=/usr/bin/chromium``; never ``playwright install``)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "service"))
from liveserver import API  # noqa: E402
from shared_meshes import MESHES_DIR  # noqa: E402
from viewerpage import TIMEOUT, drop_file, open_viewer  # noqa: E402

API_KEY = "viewer-test-key"  # the live server wants one: every test goes through the key form
CHROMIUM = Path(os.environ.get("OTGEO_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    # WebGL without a GPU: ANGLE on SwiftShader (software rendering)
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
]


@pytest.fixture(scope="module")
def api_process(tmp_path_factory):
    """``otgeo serve`` started (not yet waited for: Chromium starts meanwhile)."""
    tmp = tmp_path_factory.mktemp("viewer")
    env = {"OTGEO_DATA_DIR": str(tmp / "data"), "OTGEO_WORKERS": "1",
           "OTGEO_REAPER_INTERVAL": "1", "OTGEO_API_KEYS": API_KEY}
    api = API(env, tmp)
    api.key = API_KEY
    try:
        yield api
    finally:
        api.stop(timeout=1)  # a temporary data dir: no need for a graceful shutdown


@pytest.fixture(scope="module")
def live_api(api_process, browser_context):
    api_process.wait_healthy(60)
    return api_process


@pytest.fixture(scope="module")
def browser_context(tmp_path_factory, api_process):
    if not CHROMIUM.exists():  # CI installs it (.ci/run); a missing browser is a failure
        pytest.fail(f"{CHROMIUM} not found: apt-get install chromium")
    from playwright.sync_api import sync_playwright

    profile = tmp_path_factory.mktemp("chromium-profile")  # a fresh user-data-dir
    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            str(profile), executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS,
            viewport={"width": 1280, "height": 800}, accept_downloads=True)
        try:
            yield context
        finally:
            context.close()


@pytest.fixture
def page(browser_context):
    page = browser_context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.js_errors = errors
    yield page
    page.close()


@pytest.fixture
def spot_page(page, live_api):
    open_viewer(page, live_api)
    drop_file(page, "#drop", MESHES_DIR / "spot.obj")
    page.wait_for_selector("#domains li.active", timeout=TIMEOUT)
    page.wait_for_selector("#empty", state="hidden")
    return page
