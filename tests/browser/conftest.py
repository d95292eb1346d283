"""Browser tests of the viewer: a live ``otgeo serve`` and Debian's Chromium driven by
Playwright (``executable_path=/usr/bin/chromium``; never ``playwright install``).

One server and one Chromium per test process (pytest-xdist worker), shared by the browser test
files that run there: starting them costs ~10 CPU-s (the server, its worker loading the numba
kernels, Chromium), paid once instead of once per file; the server's caches of a domain serve
every file. Each file still starts clean: its own tenant on the server (its own API key, so
its own domains and jobs) and empty page storage (the names the page kept for uploads)."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "service"))
from liveserver import API  # noqa: E402
from shared_meshes import MESHES_DIR  # noqa: E402
from viewerpage import TIMEOUT, drop_file, open_viewer  # noqa: E402

HERE = Path(__file__).resolve().parent
# the server wants a key (every test goes through the key form); each key is its own tenant
API_KEYS = {p.stem: f"viewer-{p.stem.removeprefix('test_viewer_')}-key"
            for p in sorted(HERE.glob("test_*.py"))}
CHROMIUM = Path(os.environ.get("OTGEO_CHROMIUM", "/usr/bin/chromium"))
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    # WebGL without a GPU: ANGLE on SwiftShader (software rendering)
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
]


@pytest.fixture(scope="session")
def viewer_server(tmp_path_factory):
    """``otgeo serve`` started (not yet waited for: Chromium starts meanwhile)."""
    tmp = tmp_path_factory.mktemp("viewer")
    env = {"OTGEO_DATA_DIR": str(tmp / "data"), "OTGEO_WORKERS": "1",
           "OTGEO_REAPER_INTERVAL": "1", "OTGEO_API_KEYS": ",".join(API_KEYS.values())}
    api = API(env, tmp)
    try:
        yield api
    finally:
        api.stop(timeout=1)  # a temporary data dir: no need for a graceful shutdown


@pytest.fixture(scope="session")
def chromium(tmp_path_factory, viewer_server):
    """Chromium with a profile on disk: its HTTP and compiled-code caches make a page of the
    viewer ~0.5 CPU-s cheaper to open than in an incognito context (three.js parsed once)."""
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


@pytest.fixture(scope="module")
def live_api(request, viewer_server, chromium):
    """The server as this test file's tenant: ``url``, ``port`` and its own ``key``."""
    viewer_server.wait_healthy(60)
    return SimpleNamespace(url=viewer_server.url, port=viewer_server.port,
                           key=API_KEYS[Path(request.module.__file__).stem])


@pytest.fixture(scope="module")
def browser_context(chromium, live_api):
    """The browser, its page storage emptied for this file (the names the page kept for
    uploads; the API key is per tab, in sessionStorage)."""
    page = chromium.new_page()
    page.goto(live_api.url + "/healthz")
    page.evaluate("localStorage.clear()")
    page.close()
    return chromium


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
