"""Helpers of the browser tests: open the page (through the API-key form), drop files on it,
pick vertices on the canvas, run an operation, and read the canvas by pixel statistics.

``OTGEO_VIEWER_SCREENSHOTS=docs`` also writes the screenshots shown in the README."""

from __future__ import annotations

import base64
import io
import os
import re
from pathlib import Path

import numpy as np
from PIL import Image

SHOTS = os.environ.get("OTGEO_VIEWER_SCREENSHOTS")
TIMEOUT = 30_000  # ms


def canvas_pixels(page) -> np.ndarray:
    """RGB screenshot of the 3-D canvas without the bands of its overlays (legend and hover box
    at the top, the frame slider at the bottom)."""
    png = page.locator("#view canvas").screenshot()
    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float64) / 255
    return img[70: img.shape[0] - 70]


def stats(img: np.ndarray) -> dict:
    """Fractions of pixels that are foreground (not the background) and strongly colored."""
    background = np.array([0x1C, 0x1E, 0x22]) / 255
    fg = np.abs(img - background).sum(axis=2) > 0.06
    sat = img.max(axis=2) - img.min(axis=2)
    colored = fg & (sat > 0.25)
    return {"foreground": fg.mean(), "colored": colored.sum() / max(fg.sum(), 1),
            "fg_mask": fg, "colored_mask": colored}


def save(page, name: str) -> None:
    if SHOTS:
        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(SHOTS) / name))


def drop_file(page, selector: str, path: Path) -> None:
    """A real drop event carrying the file (what dragging it from a file manager does)."""
    data = base64.b64encode(path.read_bytes()).decode()
    transfer = page.evaluate_handle(
        """([name, b64]) => {
            const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
            const dt = new DataTransfer();
            dt.items.add(new File([bytes], name, {type: "text/plain"}));
            return dt;
        }""", [path.name, data])
    page.dispatch_event(selector, "dragover", {"dataTransfer": transfer})
    page.dispatch_event(selector, "drop", {"dataTransfer": transfer})


def pick_two(page) -> list[str]:
    """Click the canvas until two vertices are picked; returns the picks' texts."""
    box = page.locator("#view canvas").bounding_box()
    cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    for dx, dy in [(0, 0), (0.12, 0.0), (-0.12, 0.0), (0.0, 0.1), (0.08, -0.08), (-0.2, 0.05)]:
        if page.locator("#picks li").count() >= 2:
            break
        page.mouse.click(cx + dx * box["width"], cy + dy * box["height"])
    texts = page.locator("#picks li").all_inner_texts()
    assert len(texts) == 2, texts
    return texts


def run_and_wait(page, operation_id: str) -> None:
    page.select_option("#operation", operation_id)
    page.click("#run")
    page.wait_for_selector("#progress[data-state=succeeded]", timeout=TIMEOUT)
    page.wait_for_selector("#legend:not([hidden])", timeout=TIMEOUT)


def open_viewer(page, api, path: str = "/") -> None:
    """Open the page; it asks for the API key (the server wants one) and lists the domains."""
    page.goto(api.url + path)
    page.wait_for_selector("#key-dialog[open]", timeout=TIMEOUT)
    page.fill("#key-input", api.key)
    page.click("#key-dialog button[value=ok]")
    page.wait_for_selector("body[data-ready='1']", timeout=TIMEOUT)


def picked_vertices(texts: list[str]) -> list[int]:
    return [int(re.search(r"vertex (\d+)", t).group(1)) for t in texts]
