"""What the viewer sends and shows is what the user asked for: a request carries only the
fields the user set (so its value is the API's default for the same picks), a distance with
one pick is refused in the page instead of being sent with mu0 = mu1, a finished job shows no
Cancel, and a change of domain closes the job panels of the previous one."""

from __future__ import annotations

import json

import httpx
from shared_meshes import MESHES_DIR
from viewerpage import TIMEOUT, drop_file, pick_two


def sent_bodies(page, path_part: str) -> list[dict]:
    """JSON bodies of the page's POSTs whose URL contains ``path_part`` (recorded from now)."""
    bodies: list[dict] = []

    def record(request):
        if request.method == "POST" and path_part in request.url:
            bodies.append(json.loads(request.post_data or "null"))

    page.on("request", record)
    return bodies


def test_distance_is_the_api_default_for_the_same_picks(spot_page, live_api):
    page = spot_page
    pick_two(page)
    bodies = sent_bodies(page, "/distances")
    page.select_option("#operation", "createDistanceJob")
    page.click("#run")
    page.wait_for_selector("#progress[data-state=succeeded]", timeout=2 * TIMEOUT)
    page.wait_for_function("otgeo.result !== null && otgeo.result.values.value !== undefined")
    # only the picks: no "debiased": false, no method, metric or w1_method left at a default
    assert len(bodies) == 1 and set(bodies[0]) == {"mu0", "mu1"}, bodies
    shown = page.evaluate("otgeo.result.values")
    r = httpx.post(f"{live_api.url}/v1/domains/{page.evaluate('otgeo.domain.id')}/distances",
                   params={"wait": 60}, json={"mu0": bodies[0]["mu0"], "mu1": bodies[0]["mu1"]},
                   headers={"X-API-Key": live_api.key}, timeout=90)
    assert r.status_code == 200, r.text
    api = httpx.get(f"{live_api.url}/v1/jobs/{r.json()['id']}/result",
                    headers={"X-API-Key": live_api.key}, timeout=30).json()["values"]
    assert shown["value"] == api["value"] and shown["method"] == api["method"], (shown, api)
    if shown["method"] == "convolutional":
        assert shown["debiased"] is True  # the policy's default, as in the API
    # a finished job has nothing to cancel
    assert page.locator("#cancel").is_hidden()
    assert page.locator("#job-panel").is_visible() and page.locator("#result-panel").is_visible()
    # another domain: the job panels of spot's job are gone, the job itself stays listed
    drop_file(page, "#drop", MESHES_DIR / "woody.obj")
    page.wait_for_function("document.getElementById('status').textContent"
                           ".startsWith('woody.obj')", timeout=TIMEOUT)
    assert page.locator("#job-panel").is_hidden() and page.locator("#result-panel").is_hidden()
    assert page.evaluate("otgeo.job") is None
    assert page.locator("#jobs li.active").count() == 0
    assert page.js_errors == []


def test_distance_with_one_pick_is_refused(spot_page):
    page = spot_page
    bodies = sent_bodies(page, "/distances")
    box = page.locator("#view canvas").bounding_box()
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.wait_for_function("otgeo.picks.length === 1")
    page.select_option("#operation", "createDistanceJob")
    assert page.input_value("#op-form select[name=mu0]") == "0"
    assert page.input_value("#op-form select[name=mu1]") == ""  # not pick 1 again
    page.click("#run")
    error = page.locator("#error")
    error.wait_for(state="visible", timeout=TIMEOUT)
    assert "mu1" in error.inner_text() and "pick 2" in error.inner_text()
    assert page.locator(".field.bad[data-field=mu1]").count() == 1
    assert bodies == [] and page.locator("#job-panel").is_hidden()  # nothing was sent
    pick_two(page)  # a second pick fills mu1
    page.wait_for_function("document.querySelector('#op-form select[name=mu1]').value === '1'")
    assert page.js_errors == []


def test_the_selected_operation_links_its_guide_page(spot_page):
    """The form of an operation links the user-guide page that explains it (``x-guide``)."""
    page = spot_page
    for op_id, page_name in (("createFlowJob", "emd"), ("createSoftMapJob", "softmaps")):
        page.select_option("#operation", op_id)
        link = page.locator("#op-guide")
        assert link.is_visible()
        assert link.get_attribute("href") == f"/guide/guide/{page_name}.html"
        assert "thesis" in link.text_content()
    assert page.js_errors == []
