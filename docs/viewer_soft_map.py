"""Makes docs/viewer-soft-map.png from a real soft-map job (spot -> cow, 256 samples, 30 sweeps,
one landmark; ~30-60 s on 2 busy cores, too slow for the test suite, whose soft-map view test
stubs the job). Run from the repository: `.venv/bin/python docs/viewer_soft_map.py`."""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# tests/browser first: its conftest (the Chromium settings), not tests/conftest
sys.path[:0] = [str(ROOT / "tests" / d) for d in ("browser", "service", "")]

from conftest import CHROMIUM, CHROMIUM_ARGS  # noqa: E402
from liveserver import API  # noqa: E402
from playwright.sync_api import sync_playwright  # noqa: E402
from shared_meshes import MESHES_DIR  # noqa: E402


def main() -> None:
    tmp = Path(tempfile.mkdtemp())
    api = API({"OTGEO_DATA_DIR": str(tmp / "data"), "OTGEO_WORKERS": "1"}, tmp)
    api.wait_healthy(60)
    try:
        with sync_playwright() as pw:
            ctx = pw.chromium.launch_persistent_context(
                str(tmp / "profile"), executable_path=str(CHROMIUM), headless=True,
                args=CHROMIUM_ARGS, viewport={"width": 1280, "height": 800})
            page = ctx.new_page()
            page.goto(api.url + "/")
            page.wait_for_selector("body[data-ready='1']")
            ids = {}
            for name in ("cow.obj", "spot.obj"):
                page.set_input_files("#file", str(MESHES_DIR / name))
                page.wait_for_function("(n) => document.getElementById('status').textContent"
                                       ".startsWith(n)", arg=name)
                ids[name] = page.evaluate("otgeo.domain.id")
            page.select_option("#operation", "createSoftMapJob")
            page.select_option("#op-form select[name=source_id]", ids["spot.obj"])
            page.select_option("#op-form select[name=target_id]", ids["cow.obj"])
            page.fill("#op-form textarea[name=landmarks]",
                      json.dumps([{"source": 0, "target": 0}]))
            page.click("#op-form details > summary")
            page.fill("#op-form input[name=samples]", "256")
            page.fill("#op-form input[name=max_iter]", "30")
            page.click("#run")
            page.wait_for_selector("#progress[data-state=succeeded]", timeout=600_000)
            page.wait_for_selector("#hover:not([hidden])")
            box = page.locator("#view canvas").bounding_box()
            page.mouse.move(box["x"] + 0.22 * box["width"], box["y"] + 0.45 * box["height"])
            page.wait_for_function("document.getElementById('hover').dataset.vertex")
            page.wait_for_timeout(1000)
            page.screenshot(path=str(ROOT / "docs" / "viewer-soft-map.png"))
            ctx.close()
    finally:
        api.stop()


if __name__ == "__main__":
    main()
