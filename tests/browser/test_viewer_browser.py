"""The viewer in a real browser: upload spot by drag and drop, pick two vertices on the canvas,
run a barycenter and an interpolation from their generated forms, follow the progress bar to
the end and check the rendered canvas by pixel statistics of screenshots; a failing request
shows the server's error message.

``OTGEO_VIEWER_SCREENSHOTS=docs`` also writes the screenshots shown in the README."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np
from PIL import Image
from shared_meshes import MESHES_DIR
from viewerpage import (
    TIMEOUT,
    canvas_pixels,
    drop_file,
    open_viewer,
    pick_two,
    picked_vertices,
    run_and_wait,
    save,
    stats,
)


def test_page_is_served_with_its_assets(page, live_api):
    open_viewer(page, live_api, "/viewer")
    assert page.evaluate("sessionStorage.getItem('otgeo.apiKey')") == live_api.key
    page.reload()  # the tab keeps the key: asked once
    page.wait_for_selector("body[data-ready='1']", timeout=TIMEOUT)
    assert page.locator("#key-dialog[open]").count() == 0
    assert page.locator("#error").is_hidden()
    ops = page.locator("#operation option").all_inner_texts()
    # every operation of the OpenAPI schema has a form, none is hard-coded in the page
    for name in ("barycenters", "interpolations", "distances", "flows", "pointwise-distances"):
        assert name in ops
    assert page.js_errors == []


def test_barycenter_colors_the_surface(spot_page):
    page = spot_page
    before = stats(canvas_pixels(page))
    assert before["foreground"] > 0.05  # spot is drawn
    assert before["colored"] < 0.05  # in neutral gray (pick markers aside)
    picks = pick_two(page)
    assert picks[0] != picks[1]
    run_and_wait(page, "createBarycenterJob")
    text = page.inner_text("#progress-text")
    assert "succeeded" in text and "iteration" in text and "residual" in text
    assert page.locator("#field").input_value() == "density"
    after = stats(canvas_pixels(page))
    # the surface now shows the viridis ramp: most of it strongly colored, with several hues
    assert after["colored"] > 0.5, after["colored"]
    img = canvas_pixels(page)[after["colored_mask"]]
    assert img[:, 1].std() > 0.05  # not one flat color: low (purple) to high (green/yellow)
    lo, hi = (float(page.get_attribute("#legend", k)) for k in ("data-lo", "data-hi"))
    assert 0 <= lo < hi
    values = page.inner_text("#values")
    assert "converged" in values and "iterations" in values
    save(page, "viewer-barycenter.png")
    # downloads of the result
    with page.expect_download() as dl:
        page.click("#downloads button:text('JSON')")
    assert dl.value.suggested_filename.endswith(".json")
    with page.expect_download() as dl:
        page.click("#downloads button:text('GLB')")
    glb = Path(dl.value.path()).read_bytes()
    assert glb[:4] == b"glTF"
    assert page.js_errors == []


def test_interpolation_slider_changes_frames(spot_page):
    page = spot_page
    pick_two(page)
    run_and_wait(page, "createInterpolationJob")
    page.wait_for_selector("#frames:not([hidden])")
    first = canvas_pixels(page)
    assert "1/5" in page.inner_text("#frame-label")
    page.focus("#frame")
    page.keyboard.press("End")
    page.wait_for_function("document.getElementById('frame').dataset.frame === '4'")
    last = canvas_pixels(page)
    assert "5/5" in page.inner_text("#frame-label")
    fg = stats(first)["fg_mask"] & stats(last)["fg_mask"]
    diff = np.abs(first - last).sum(axis=2)[fg]
    # mass moved from one pick to the other: a real part of the surface changed color
    assert (diff > 0.15).mean() > 0.02, (diff > 0.15).mean()
    assert stats(last)["colored"] > 0.5
    page.keyboard.press("Home")
    page.wait_for_function("document.getElementById('frame').dataset.frame === '0'")
    page.keyboard.press("ArrowRight")
    page.keyboard.press("ArrowRight")
    save(page, "viewer-interpolation.png")
    assert page.js_errors == []


def test_failing_request_shows_the_error(spot_page):
    page = spot_page
    pick_two(page)
    page.select_option("#operation", "createInterpolationJob")
    page.fill("#op-form input[name=times]", "0, 2")
    page.click("#run")
    error = page.locator("#error")
    error.wait_for(state="visible", timeout=TIMEOUT)
    # the server's validation message, naming the field, not a generic failure
    assert "times[1]" in error.inner_text() and "less than or equal to 1" in error.inner_text()
    assert page.locator(".field.bad[data-field=times]").count() == 1
    assert page.locator("#job-panel").is_hidden()  # no job was created
    save(page, "viewer-error.png")


def test_flow_arrows_and_histogram_plots(spot_page):
    page = spot_page
    vertices = picked_vertices(pick_two(page))
    run_and_wait(page, "createFlowJob")
    assert page.locator("#field").input_value() == "potential"
    with_arrows = canvas_pixels(page)
    page.uncheck("#show-arrows")
    without = canvas_pixels(page)
    changed = np.abs(with_arrows - without).sum(axis=2) > 0.3
    # the arrows are white strokes over the colored surface, drawn between the two picks
    assert changed.mean() > 0.002, changed.mean()
    # white strokes brighten every channel where they are drawn (antialiased: partly)
    assert (with_arrows[changed] - without[changed]).min(axis=1).mean() > 0.1
    page.check("#show-arrows")
    save(page, "viewer-flow.png")
    page.select_option("#field", "flow_magnitude")  # a per-face field
    faces = canvas_pixels(page)
    assert stats(faces)["colored"] > 0.5
    assert np.abs(faces - with_arrows).sum(axis=2).mean() > 0.02  # not the potential's colors

    page.select_option("#operation", "createHistogramPropagationJob")
    # "from picks" alone makes a valid request: one label per pick (its vertex and a sample
    # spread over the bins, which it fills when empty)
    page.click("#op-form .field[data-field=labeled] button:text('from picks')")
    labeled = json.loads(page.input_value("#op-form textarea[name=labeled]"))
    bins = json.loads(page.input_value("#op-form textarea[name=bins]"))
    assert [item["node"] for item in labeled] == vertices
    samples = [item["samples"] for item in labeled]
    assert all(len(x) == 1 and bins["lo"] <= x[0] <= bins["hi"] for x in samples), (bins, samples)
    assert samples[0] != samples[1]  # two different labels
    page.click("#run")
    page.wait_for_function("document.getElementById('job-title').textContent"
                           ".startsWith('histogram-propagations')")
    page.wait_for_selector("#progress[data-state=succeeded]", timeout=TIMEOUT)
    page.wait_for_selector("#legend:not([hidden])", timeout=TIMEOUT)
    assert page.locator("#field").input_value() == "mean"
    assert page.locator("#plots canvas").count() == 2  # one small histogram per pick
    assert re.search(r"n_nodes\s+2930", page.inner_text("#values"))  # numbers as they are
    assert re.search(r"n_labeled\s+2", page.inner_text("#values"))
    assert stats(canvas_pixels(page))["colored"] > 0.5
    save(page, "viewer-histograms.png")
    assert page.js_errors == []


def test_grid_domain_is_an_image(page, live_api, tmp_path):
    open_viewer(page, live_api)
    grid = tmp_path / "grid.json"
    grid.write_text(json.dumps({"kind": "grid", "shape": [40, 40]}))
    drop_file(page, "#drop", grid)
    page.wait_for_function("document.getElementById('status').textContent.startsWith('grid')",
                           timeout=TIMEOUT)
    before = stats(canvas_pixels(page))
    assert before["foreground"] > 0.2 and before["colored"] < 0.05  # a neutral square
    pick_two(page)
    run_and_wait(page, "createBarycenterJob")
    img = canvas_pixels(page)
    after = stats(img)
    assert after["colored"] > 0.9  # every cell has a color of the ramp
    bright = img[after["colored_mask"]].mean(axis=1) > 0.45  # the green/yellow barycenter
    assert 0.005 < bright.mean() < 0.5, bright.mean()
    save(page, "viewer-grid.png")
    assert page.js_errors == []


def open_color_transfer(page, live_api, tmp_path):
    """The viewer with the color-transfer form filled in with two small gradient images."""
    y, x = np.mgrid[0:36, 0:48]
    warm = np.stack([200 + 0 * x, 60 + x, 40 + y], -1).astype(np.uint8)
    cool = np.stack([30 + 0 * x, 80 + y, 150 + x], -1).astype(np.uint8)
    for name, img in (("warm.png", warm), ("cool.png", cool)):
        Image.fromarray(img).save(tmp_path / name)
    open_viewer(page, live_api)
    page.select_option("#operation", "createColorTransfer")
    page.set_input_files("#op-form input[name=images]",
                         [str(tmp_path / "warm.png"), str(tmp_path / "cool.png")])


def test_color_transfer_images_side_by_side(page, live_api, tmp_path):
    """A global operation with a multipart form (files): inputs and results side by side."""
    open_color_transfer(page, live_api, tmp_path)
    page.click("#op-form details > summary")  # optional fields are folded under "options"
    page.fill("#op-form input[name=bins]", "32")
    page.click("#run")
    # the first color transfer of a fresh checkout compiles the numba color kernels (~10-60 s
    # by load); later runs load them from numba's cache
    page.wait_for_selector("#progress[data-state=succeeded]", timeout=4 * TIMEOUT)
    captions = ["warm.png", "cool.png", "image-0-0.png", "image-0-1.png"]
    shown = {}
    for caption in captions:
        img = page.locator(f"#gallery figure:has(figcaption:text-is('{caption}')) img")
        img.wait_for(timeout=TIMEOUT)
        page.wait_for_function("(el) => el.complete && el.naturalWidth > 0",
                               arg=img.element_handle())
        png = np.asarray(Image.open(io.BytesIO(img.screenshot())).convert("RGB"), float) / 255
        shown[caption] = png.reshape(-1, 3).mean(axis=0)
    # both recolored images moved towards the colors' barycenter: closer to each other
    before = np.abs(shown["warm.png"] - shown["cool.png"]).sum()
    after = np.abs(shown["image-0-0.png"] - shown["image-0-1.png"]).sum()
    assert after < 0.5 * before, (before, after)
    assert np.abs(shown["image-0-0.png"] - shown["warm.png"]).sum() > 0.1
    assert page.locator("#downloads button:text('image-0-0.png')").count() == 1
    save(page, "viewer-color-transfer.png")
    assert page.js_errors == []


def test_color_transfer_histogram_row(page, live_api, tmp_path):
    """The ab histograms of inputs, outputs and target in one row under the results: every
    picture is shown, and each output's histogram looks like the target's, not like its
    input's."""
    open_color_transfer(page, live_api, tmp_path)
    page.click("#run")
    page.wait_for_selector("#progress[data-state=succeeded]", timeout=4 * TIMEOUT)
    # the gallery renders after the progress bar flips: wait for its third row's heading
    page.locator("#gallery h3").nth(2).wait_for(timeout=TIMEOUT)
    heads = page.locator("#gallery h3").all_inner_texts()
    assert [h.split(" ")[0] for h in heads] == ["inputs", "results", "ab"], heads
    row = page.locator("#gallery .strip").nth(2)  # the histogram row, after the results
    captions = row.locator("figcaption").all_inner_texts()
    names = ["histogram-0.png", "histogram-1.png", "histogram-0-0.png", "histogram-0-1.png",
             "barycenter-0.png"]
    assert sorted(captions) == sorted(names), captions
    shown = {}
    for caption in names:
        img = row.locator(f"figure:has(figcaption:text-is('{caption}')) img")
        page.wait_for_function("(el) => el.complete && el.naturalWidth > 0",
                               arg=img.element_handle(), timeout=TIMEOUT)
        box = img.bounding_box()
        assert box["width"] > 20 and box["height"] > 20
        png = np.asarray(Image.open(io.BytesIO(img.screenshot())).convert("L"), float) / 255
        shown[caption] = np.asarray(Image.fromarray(png).resize((64, 64)), float)
    # side by side: the histograms share one row (same top within a few pixels)
    tops = [row.locator(f"figure:has(figcaption:text-is('{c}'))").bounding_box()["y"]
            for c in names]
    assert max(tops) - min(tops) < 5, tops
    target = shown["barycenter-0.png"]
    for i in (0, 1):
        before = np.abs(shown[f"histogram-{i}.png"] - target).mean()
        after = np.abs(shown[f"histogram-0-{i}.png"] - target).mean()
        assert after < before, (i, before, after)
    save(page, "viewer-color-histograms.png")
    assert page.js_errors == []


def test_live_progress_and_cancel(spot_page):
    """A long W1 flow (ADMM: the default interior point ends in tens of iterations): the bar
    follows the job's events while it runs; Cancel stops it."""
    page = spot_page
    pick_two(page)
    page.select_option("#operation", "createFlowJob")
    page.click("#op-form details > summary")
    page.select_option("#op-form select[name=method]", "admm")
    page.fill("#op-form input[name=tol]", "1e-12")
    page.fill("#op-form input[name=max_iter]", "100000")
    page.click("#run")
    page.wait_for_selector("#progress[data-state=running]", timeout=TIMEOUT)
    iteration_above = """(n) => {
        const m = /iteration (\\d+)/.exec(document.getElementById("progress-text").textContent);
        return m !== null && Number(m[1]) > n;
    }"""
    page.wait_for_function(iteration_above, arg=-1, timeout=TIMEOUT)
    first = int(re.search(r"iteration (\d+)", page.inner_text("#progress-text")).group(1))
    page.wait_for_function(iteration_above, arg=first, timeout=TIMEOUT)  # live: it goes on
    assert "residual" in page.inner_text("#progress-text")
    width = page.evaluate("document.getElementById('progress').style.width")
    assert width.endswith("%") and 0 < float(width[:-1]) < 100
    page.click("#cancel")
    page.wait_for_selector("#progress[data-state=cancelled]", timeout=TIMEOUT)
    assert page.locator("#result-panel").is_hidden()
    assert page.locator("#cancel").is_hidden()  # a finished job has nothing to cancel
    assert page.js_errors == []


def test_graph_and_point_cloud_are_points(page, live_api, tmp_path):
    open_viewer(page, live_api)
    n = 40
    angles = 2 * np.pi * np.arange(n) / n
    graph = {"kind": "graph", "n_nodes": n, "edges": [[i, (i + 1) % n] for i in range(n)],
             "positions": np.stack([np.cos(angles), np.sin(angles)], 1).tolist()}
    points = np.random.default_rng(0).normal(size=(300, 3))
    cloud = {"kind": "pointcloud", "points": (points / np.linalg.norm(points, axis=1,
                                                                        keepdims=True)).tolist()}
    fractions = {}
    volume = {"kind": "grid", "shape": [8, 8, 8]}  # a 3-D grid is drawn as points too
    for name, spec in (("volume.json", volume), ("ring.json", graph), ("sphere.json", cloud)):
        (tmp_path / name).write_text(json.dumps(spec))
        drop_file(page, "#drop", tmp_path / name)
        page.wait_for_function(f"document.getElementById('status').textContent"
                               f".startsWith('{spec['kind']}')", timeout=TIMEOUT)
        fractions[name] = stats(canvas_pixels(page))["foreground"]
        assert 0.002 < fractions[name] < 0.3, fractions  # points (and edges), not a surface
    box = page.locator("#view canvas").bounding_box()
    for dx in np.linspace(-0.1, 0.1, 21):  # a click on a point of the cloud picks it
        page.mouse.click(box["x"] + box["width"] * (0.5 + dx), box["y"] + box["height"] / 2)
        if page.locator("#picks li").count():
            break
    assert page.locator("#picks li").count() >= 1
    assert page.js_errors == []


def test_soft_map_view_with_a_stubbed_job(page, live_api, tmp_path):
    """The soft-map view (two meshes side by side, hovering a source vertex colors the target
    with its sample's row). A real soft-map job takes ~50 s here, so the job's routes (events,
    result, jobs list, rows) are stubbed in the browser in the shapes of POST /v1/soft-maps
    (domain_id = the source, values.source_id/target_id name both meshes, values.rows names
    the (samples, n_target) array, labels[x] is the row of source vertex x); the meshes and
    their geometry come from the live server. The target is the one the result names, not
    another mesh with as many vertices (cow.obj, uploaded first); a result that names no
    target shows the source alone and says why."""
    import httpx

    open_viewer(page, live_api)
    headers = {"X-API-Key": live_api.key}
    ids = {}
    for name in ("spot.obj", "cow.obj"):
        drop_file(page, "#drop", MESHES_DIR / name)
        page.wait_for_function(f"document.getElementById('status').textContent"
                               f".startsWith('{name}')", timeout=TIMEOUT)
        ids[name] = page.evaluate("otgeo.domain.id")
    cow = httpx.get(f"{live_api.url}/v1/domains/{ids['cow.obj']}/geometry", headers=headers,
                    timeout=30).json()
    cow_points = np.asarray(cow["positions"]).reshape(-1, 3) * [1.6, 1.0, 0.7]
    target_file = tmp_path / "long-cow.json"  # another mesh with cow's vertex count
    target_file.write_text(json.dumps({"kind": "mesh", "vertices": cow_points.tolist(),
                                       "faces": np.reshape(cow["faces"], (-1, 3)).tolist()}))
    drop_file(page, "#drop", target_file)
    page.wait_for_function("otgeo.domain.kind === 'mesh' && !otgeo.domain.source.filename",
                           timeout=TIMEOUT)
    ids["target"] = page.evaluate("otgeo.domain.id")
    assert page.evaluate("otgeo.domain.n") == cow["n"]
    job_id, unnamed_id = "5" * 32, "6" * 32
    job = {"id": job_id, "operation": "soft-maps", "domain_id": ids["spot.obj"],
           "state": "succeeded", "progress": {"iteration": 12, "residual": 1e-6},
           "attempts": 1, "error": None, "cancel_requested": False, "time_limit": 600,
           "created_at": "2026-12-01T19:00:00Z", "duration_seconds": 1.5, "links": {}}
    unnamed_job = {**job, "id": unnamed_id}
    n_source = page.evaluate("otgeo.domains.find((d) => d.source.filename === 'spot.obj').n")
    labels = [x % 17 for x in range(n_source)]  # 17 source samples
    values = {"rows": "soft_map", "iterations": 12, "samples": 17,
              "source_id": ids["spot.obj"], "target_id": ids["target"]}
    results = {jid: {"job_id": jid, "operation": "soft-maps", "domain_id": ids["spot.obj"],
                     "values": v, "arrays": {"labels": labels, "samples": list(range(17))},
                     "export": {}, "files": {}}
               for jid, v in ((job_id, values),
                              (unnamed_id, {k: x for k, x in values.items()
                                            if k != "target_id"}))}
    served_rows = []

    x = cow_points[:, 0]

    def row(i: int) -> list[float]:  # a band across the cow that moves with the source vertex
        center = x.min() + (x.max() - x.min()) * ((0.2 + 0.37 * i) % 1.0)
        m = np.exp(-((x - center) ** 2) / (0.02 * np.ptp(x) ** 2))
        return (m / m.sum()).tolist()

    def handle(route):
        url = route.request.url
        jid = re.search(r"/v1/jobs/(\w+)/", url).group(1)
        if url.endswith("/events"):
            shown = job if jid == job_id else unnamed_job
            body = (f"event: progress\ndata: {json.dumps(shown)}\n\n"
                    f"event: end\ndata: {json.dumps({'state': 'succeeded'})}\n\n")
            return route.fulfill(status=200, body=body, content_type="text/event-stream")
        if url.endswith("/result"):
            return route.fulfill(status=200, json=results[jid])
        match = re.search(r"/arrays/soft_map/rows/(\d+)$", url)
        if match:
            served_rows.append(int(match.group(1)))
            return route.fulfill(status=200, json={"name": "soft_map", "row": served_rows[-1],
                                                   "values": row(served_rows[-1])})
        return route.fulfill(status=404, json={"error": {"code": "not_found",
                                                         "message": "stub", "field": None}})

    for jid in (job_id, unnamed_id):
        page.route(f"**/v1/jobs/{jid}/**", handle)
    page.route("**/v1/jobs?*", lambda route: route.fulfill(status=200, json={
        "jobs": [job, unnamed_job, *route.fetch().json()["jobs"]], "next_cursor": None}))
    page.click("#refresh-jobs")
    page.click(f"#jobs li[data-id='{unnamed_id}']")
    page.wait_for_function("document.getElementById('hover').textContent"
                           ".includes('does not name its target')", timeout=TIMEOUT)
    assert page.evaluate("otgeo.view.items.length") == 1 and served_rows == []
    page.click("#refresh-jobs")
    page.click(f"#jobs li[data-id='{job_id}']")
    page.wait_for_function("otgeo.softMap && otgeo.result && otgeo.result.job_id === "
                           f"'{job_id}'", timeout=TIMEOUT)
    assert page.evaluate("otgeo.view.items.length") == 2
    assert page.evaluate("otgeo.softMap.targetId") == ids["target"]  # named, not cow.obj
    assert page.evaluate("otgeo.view.items[1].geom.n") == cow["n"]
    before = canvas_pixels(page)
    width = before.shape[1]
    right = slice(width // 2, width)
    assert stats(before[:, right])["colored"] < 0.05  # the target waits for a hover
    box = page.locator("#view canvas").bounding_box()
    hovered = []
    for fx in np.linspace(0.05, 0.48, 20):  # over the source (left)
        page.mouse.move(box["x"] + fx * box["width"], box["y"] + 0.5 * box["height"])
        page.wait_for_timeout(150)
        vertex = page.get_attribute("#hover", "data-vertex")
        if vertex is not None and labels[int(vertex)] not in {labels[int(v)] for v in hovered}:
            hovered.append(vertex)
            page.wait_for_function("(v) => otgeo.softMap && document.getElementById('legend')"
                                   ".dataset.hi && document.getElementById('hover')"
                                   ".dataset.vertex === v", arg=vertex)
            shot = canvas_pixels(page)
            if len(hovered) == 1:
                first = shot
            else:
                break
    assert len(hovered) >= 2, hovered
    assert labels[int(hovered[0])] in served_rows
    colored = stats(first[:, right])["colored"]
    assert colored > 0.3, colored  # the target shows the hovered vertex's distribution
    changed = np.abs(first[:, right] - shot[:, right]).sum(axis=2) > 0.15
    assert changed.mean() > 0.005  # another source vertex, another distribution
    assert page.js_errors == []


def test_soft_map_form_pairs_landmarks_from_picks(page, live_api):
    """The soft-map form (generated like every other) pairs picks on the source with picks on
    the target shown beside it; the request is not run (a real job takes too long here)."""
    open_viewer(page, live_api)
    ids = {}
    for name in ("cow.obj", "spot.obj"):
        drop_file(page, "#drop", MESHES_DIR / name)
        page.wait_for_function(f"document.getElementById('status').textContent"
                               f".startsWith('{name}')", timeout=TIMEOUT)
        ids[name] = page.evaluate("otgeo.domain.id")
    page.select_option("#operation", "createSoftMapJob")
    assert page.input_value("#op-form select[name=source_id]") == ids["spot.obj"]
    page.select_option("#op-form select[name=target_id]", ids["cow.obj"])
    page.click("#op-form .field[data-field=landmarks] button:text('pick on target')")
    page.wait_for_function("otgeo.view.items.length === 2")
    box = page.locator("#view canvas").bounding_box()
    y = box["y"] + 0.5 * box["height"]

    def click_until(xs, count_js, n):
        for fx in xs:
            page.mouse.click(box["x"] + fx * box["width"], y)
            if page.evaluate(count_js) >= n:
                return
        raise AssertionError(f"{count_js} < {n}")

    click_until(np.linspace(0.15, 0.4, 12), "otgeo.picks.length", 2)  # source (left)
    click_until(np.linspace(0.6, 0.9, 12), "otgeo.targetPicks.length", 2)  # target (right)
    page.click("#op-form .field[data-field=landmarks] button:text('from picks')")
    pairs = json.loads(page.input_value("#op-form textarea[name=landmarks]"))
    source = page.evaluate("otgeo.picks.map((p) => p.vertex)")
    target = page.evaluate("otgeo.targetPicks.map((p) => p.vertex)")
    assert pairs == [{"source": s, "target": t} for s, t in zip(source, target, strict=True)]
    assert "→ target" in page.inner_text("#picks")
    assert page.js_errors == []
