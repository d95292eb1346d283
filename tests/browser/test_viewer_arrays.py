"""The viewer reads result arrays that the JSON result only links (``array_files``): a result
that inlines no per-vertex array (what a server with a small JSON budget sends) colors the
surface from the .npy files; and the page's .npy reader gives the values numpy stored, for
every dtype results use."""

from __future__ import annotations

import base64
import io

import numpy as np
from shared_meshes import MESHES_DIR
from viewerpage import TIMEOUT, canvas_pixels, drop_file, open_viewer, pick_two, stats


def links_only(route) -> None:
    """The result as the server sends it when no array fits its JSON size budget: every array
    linked, none inline (``?arrays=false``; the budget itself: tests/service/
    test_result_budget.py). Asked of the shared server instead of starting another one with a
    tiny OTGEO_RESULT_JSON_BYTES (~9 CPU-s)."""
    route.continue_(url=route.request.url + "?arrays=false")


def test_linked_arrays_color_the_surface(page, live_api):
    fetched = []
    page.route("**/v1/jobs/*/result", links_only)
    page.on("request", lambda r: fetched.append(r.url) if r.url.endswith(".npy") else None)
    open_viewer(page, live_api)
    drop_file(page, "#drop", MESHES_DIR / "spot.obj")
    page.wait_for_selector("#domains li.active", timeout=TIMEOUT)
    pick_two(page)
    page.select_option("#operation", "createBarycenterJob")
    page.click("#run")
    page.wait_for_selector("#progress[data-state=succeeded]", timeout=TIMEOUT)
    page.wait_for_selector("#legend:not([hidden])", timeout=TIMEOUT)
    assert page.locator("#field").input_value() == "density"
    assert any(url.endswith("/arrays/density.npy") for url in fetched), fetched
    assert stats(canvas_pixels(page))["colored"] > 0.5
    page.select_option("#field", "masses")  # another linked array, fetched on selection
    page.wait_for_function("document.getElementById('legend').dataset.hi !== undefined")
    page.wait_for_function("() => performance.getEntriesByType('resource')"
                           ".some((e) => e.name.endsWith('/arrays/masses.npy'))",
                           timeout=TIMEOUT)
    assert page.js_errors == []


ARRAYS = {
    "f8": np.array([[1.5, np.inf], [np.nan, -2.0], [3.0, 1e-300]]),
    "f4": np.arange(7, dtype=np.float32) / 3,
    "i8": np.array([-(2**40), 0, 5], dtype=np.int64),
    "i4": np.arange(-3, 3, dtype=np.int32).reshape(2, 3),
    "bool": np.array([True, False, True]),
    "fortran": np.asfortranarray(np.arange(12.0).reshape(3, 4)),
    "scalar": np.float64(2.5),
}


def test_npy_reader_matches_numpy(page, live_api):
    page.goto(live_api.url + "/viewer")
    for name, array in ARRAYS.items():
        buf = io.BytesIO()
        np.save(buf, array)
        data = base64.b64encode(buf.getvalue()).decode()
        parsed = page.evaluate("""async (b64) => {
            const api = await import("/static/api.js");
            const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
            const npy = api.parseNpy(bytes.buffer);
            return { shape: npy.shape, values: api.nested(npy) };
        }""", data)
        assert parsed["shape"] == list(np.shape(array)), name
        expected = np.where(np.isfinite(array), array, np.nan) if array.dtype.kind == "f" \
            else array
        got = np.array(parsed["values"], dtype=float if array.dtype.kind == "f" else None)
        np.testing.assert_array_equal(got, expected, err_msg=name)
