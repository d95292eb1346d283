"""What the viewer offers and shows around a job: distances first, only the operations the
shown domain's kind supports, no stale job panel after a refused request, an exact job's
estimated run time instead of "iteration 0", 0 (not round-off) at a density legend's
minimum, and the names the user gave uploads."""

from __future__ import annotations

import json
import re

from shared_meshes import MESHES_DIR
from viewerpage import TIMEOUT, drop_file, open_viewer, pick_two


def offered(page) -> list[str]:
    return page.locator("#operation option").all_inner_texts()


def wait_status(page, prefix: str) -> None:
    page.wait_for_function(f"document.getElementById('status').textContent"
                           f".startsWith({json.dumps(prefix)})", timeout=TIMEOUT)


def test_distances_first_and_only_what_the_domain_supports(page, live_api, tmp_path):
    open_viewer(page, live_api)
    assert page.input_value("#operation") == "createDistanceJob"  # not the first by name
    grid = tmp_path / "grid.json"
    grid.write_text(json.dumps({"kind": "grid", "shape": [12, 12]}))
    drop_file(page, "#drop", grid)
    wait_status(page, "grid")
    on_grid = offered(page)
    for mesh_only in ("flows", "pointwise-distances", "anisotropic-distances",
                      "histogram-propagations"):
        assert mesh_only not in on_grid, on_grid
    assert "distances" in on_grid and "barycenters" in on_grid
    assert "color-transfers (global)" in on_grid  # global operations stay
    assert page.input_value("#operation") == "createDistanceJob"
    page.select_option("#operation", "createBarycenterJob")
    drop_file(page, "#drop", MESHES_DIR / "spot.obj")
    wait_status(page, "spot.obj")
    assert "flows" in offered(page) and "anisotropic-distances" in offered(page)
    assert page.input_value("#operation") == "createBarycenterJob"  # still offered: kept
    assert page.js_errors == []


def test_a_refused_request_leaves_no_previous_job_shown(spot_page):
    page = spot_page
    pick_two(page)
    page.select_option("#operation", "createDistanceJob")
    page.click("#run")
    page.wait_for_selector("#progress[data-state=succeeded]", timeout=2 * TIMEOUT)
    assert page.locator("#job-panel").is_visible()
    page.select_option("#operation", "createInterpolationJob")
    page.fill("#op-form input[name=times]", "0, 2")
    page.click("#run")
    page.locator("#error").wait_for(state="visible", timeout=TIMEOUT)  # the server's 422
    assert "times[1]" in page.inner_text("#error")
    assert page.locator("#job-panel").is_hidden()  # not the distance job's "succeeded"
    assert page.evaluate("otgeo.job") is None
    assert page.js_errors == []


def show_running_job(page, job_id: str, operation: str, progress: dict,
                     decision: dict | None) -> None:
    """Open a running job whose routes (list, events) are stubbed in the browser."""
    job = {"id": job_id, "operation": operation, "domain_id": "", "state": "running",
           "progress": {"iteration": None, "residual": None, "fraction": None,
                        "eta_seconds": None, "stage": None, **progress},
           "decision": decision, "attempts": 1, "error": None, "cancel_requested": False,
           "time_limit": 600, "created_at": "2026-12-01T19:00:00Z",
           "started_at": "2026-12-01T19:00:01Z", "duration_seconds": None, "links": {}}
    events = f"event: progress\ndata: {json.dumps(job)}\n\n"  # still running: no end event
    page.route(f"**/v1/jobs/{job_id}/events", lambda route: route.fulfill(
        status=200, body=events, content_type="text/event-stream"))
    page.route("**/v1/jobs?*", lambda route: route.fulfill(status=200, json={
        "jobs": [job, *route.fetch().json()["jobs"]], "next_cursor": None}))
    page.click("#refresh-jobs")
    page.click(f"#jobs li[data-id='{job_id}']")


def test_an_exact_job_shows_its_estimated_run_time(page, live_api):
    """A running exact-method job reports no iterations; its decision's estimate gives the
    text and a bar that fills with time."""
    open_viewer(page, live_api)
    show_running_job(page, "7" * 32, "distances", {"iteration": 0},
                     {"method": "exact", "reason": "small domain", "estimated_seconds": 20.0})
    page.wait_for_function("document.getElementById('progress-text').textContent"
                           ".includes('about 20 s')", timeout=TIMEOUT)
    assert "iteration 0" not in page.inner_text("#progress-text")

    def width() -> float:
        return float(page.evaluate("document.getElementById('progress').style.width")[:-1])

    first = width()
    # ~5% a second: wait for it to grow (not a fixed pause), never full while running
    page.wait_for_function("(w) => parseFloat(document.getElementById('progress').style"
                           ".width) > w", arg=first, timeout=TIMEOUT)
    assert first < width() < 95, (first, width())
    assert page.js_errors == []


def test_a_job_waiting_for_its_kernels_says_so(page, live_api):
    open_viewer(page, live_api)
    stage = "preparing compiled kernels (the first run compiles them)"
    show_running_job(page, "8" * 32, "color-transfers", {"stage": stage}, None)
    page.wait_for_function("(s) => document.getElementById('progress-text').textContent"
                           ".includes(s)", arg=stage, timeout=TIMEOUT)
    assert "iteration" not in page.inner_text("#progress-text")
    assert page.js_errors == []


def test_a_density_legend_starts_at_zero(page, live_api):
    page.goto(live_api.url + "/viewer")
    lo, hi = page.evaluate("""async () => {
        const { range } = await import("/static/colormap.js");
        return range([1.469e-17, 0.25, 0.003, 0.5]);
    }""")
    assert (lo, hi) == (0, 0.5)
    kept = page.evaluate("""async () => (await import("/static/colormap.js"))
        .range([0.2, 0.7, 0.4])""")
    assert kept == [0.2, 0.7]  # a real minimum stays
    signed = page.evaluate("""async () => (await import("/static/colormap.js"))
        .range([-2, 3])""")
    assert signed == [-2, 3]


def test_an_upload_of_a_stored_mesh_is_listed_under_its_new_name(page, live_api, tmp_path):
    open_viewer(page, live_api)
    drop_file(page, "#drop", MESHES_DIR / "spot.obj")
    wait_status(page, "spot.obj")
    first = page.evaluate("otgeo.domain.id")
    again = tmp_path / "my-cow.obj"  # the same mesh under another name: the same domain
    again.write_bytes((MESHES_DIR / "spot.obj").read_bytes())
    drop_file(page, "#drop", again)
    wait_status(page, "my-cow.obj")
    assert page.evaluate("otgeo.domain.id") == first
    assert re.match(r"my-cow\.obj · mesh", page.inner_text("#domains li.active"))
    page.reload()  # the name is kept by the page
    page.wait_for_selector("body[data-ready='1']", timeout=TIMEOUT)
    assert "my-cow.obj" in page.inner_text(f"#domains li[data-id='{first}']")
    assert page.js_errors == []
