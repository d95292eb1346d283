"""Chromium's CPU per viewer page in the browser tests' setting (bench/results/test_suite.md).

One ``otgeo serve`` with a key; Chromium started as tests/browser/conftest.py starts it (plus
any flags given on the command line); four pages, each opened through the key form, spot.obj
dropped on it, two seconds idle, closed. Prints the CPU-seconds of all Chromium processes
(from /proc) spent in each step.

    .venv/bin/python bench/browser_pages.py [--some-chromium-flag ...]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "tests" / "service"))
sys.path.insert(0, str(ROOT / "tests" / "browser"))
os.environ.setdefault("PYTEST_CURRENT_TEST", "bench")  # the test servers' settings

from conftest import CHROMIUM, CHROMIUM_ARGS  # noqa: E402
from liveserver import API  # noqa: E402
from playwright.sync_api import sync_playwright  # noqa: E402
from viewerpage import TIMEOUT, drop_file, open_viewer  # noqa: E402

SPOT = ROOT.parent / "shared" / "meshes" / "spot.obj"


def chromium_seconds() -> float:
    """CPU-seconds (user + system) of every live Chromium process."""
    ticks = 0
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if b"chromium" not in Path(f"/proc/{pid}/cmdline").read_bytes():
                continue
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        ticks += int(fields[11]) + int(fields[12])
    return ticks / os.sysconf("SC_CLK_TCK")


def main(extra_flags: list[str]) -> None:
    tmp = Path(tempfile.mkdtemp())
    api = API({"OTGEO_DATA_DIR": str(tmp / "data"), "OTGEO_WORKERS": "1",
               "OTGEO_API_KEYS": "bench-key"}, tmp)
    try:
        api.wait_healthy(60)
        live = SimpleNamespace(url=api.url, key="bench-key")
        with sync_playwright() as pw:
            context = pw.chromium.launch_persistent_context(
                str(tmp / "profile"), executable_path=str(CHROMIUM), headless=True,
                args=CHROMIUM_ARGS + extra_flags, viewport={"width": 1280, "height": 800})
            print(f"launch {chromium_seconds():.2f} CPU-s")
            for i in range(4):
                steps, start = [chromium_seconds()], time.perf_counter()
                page = context.new_page()
                open_viewer(page, live)
                steps.append(chromium_seconds())
                drop_file(page, "#drop", SPOT)
                page.wait_for_selector("#domains li.active", timeout=TIMEOUT)
                page.wait_for_selector("#empty", state="hidden")
                steps.append(chromium_seconds())
                time.sleep(2)
                steps.append(chromium_seconds())
                page.close()
                open_s, spot_s, idle_s = (b - a for a, b in zip(steps, steps[1:], strict=False))
                print(f"page {i}: open {open_s:.2f}, spot {spot_s:.2f}, idle 2 s {idle_s:.2f} "
                      f"CPU-s; {time.perf_counter() - start:.1f} s wall")
            context.close()
    finally:
        api.stop()


if __name__ == "__main__":
    main(sys.argv[1:])
