"""``/distances``: the default against the exact LP, the decision taken at submission (shown in
the 202, stored with the job, executed by a re-run), and what every metric and algorithm
reports.

The oracle is independent of the service: POT ``ot.emd2`` between the two bumps' supports
with squared exact geodesics from :mod:`solvers.geodesics`.  Larger meshes and all cases:
``bench/distance_routes.py`` (accuracy table in ``bench/results/distance_routes.md``).
"""

from __future__ import annotations

import time

import numpy as np
import ot
import pytest
from service_testing import assert_error, upload_mesh

from solvers.geodesics import geodesic_distances

# The request: two workers answered it by different routes (0.020168 / 0.019618).
SPOT_REQUEST = {"mu0": {"vertex": 935, "radius": 0.15}, "mu1": {"vertex": 615, "radius": 0.15}}


def _bump(mesh, vertex, radius=0.1):
    d = np.linalg.norm(mesh.vertices - mesh.vertices[vertex], axis=1)
    m = mesh.areas * np.clip(1 - d / radius, 0, None)
    return m / m.sum()


def _lp(mesh, m0, m1) -> float:
    s0, s1 = np.flatnonzero(m0), np.flatnonzero(m1)
    cost = geodesic_distances(mesh, s0, s1) ** 2
    return float(ot.emd2(m0[s0], m1[s1], cost, numItermax=10**7))


def _targets(mesh, fractions):
    """Vertices at the given fractions of the largest geodesic distance from vertex 0."""
    d0 = geodesic_distances(mesh, [0])[0]
    return [int(np.argmin(np.abs(d0 - f * d0.max()))) for f in fractions]


def _run(client, mid, body) -> tuple[dict, dict]:
    job = client.post(f"/v1/domains/{mid}/distances", json=body).json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()
    assert result["decision"] == job["decision"] == result["values"]["decision"]
    return job, result["values"]


def test_default_distance_is_the_exact_lp_on_woody(client, meshes_dir, shared_mesh):
    mesh = shared_mesh("woody.obj")
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    for j in _targets(mesh, (0.15, 0.5, 0.9)):
        job, values = _run(client, mid, {"mu0": {"vertex": 0, "radius": 0.1},
                                         "mu1": {"vertex": j, "radius": 0.1}})
        lp = _lp(mesh, _bump(mesh, 0), _bump(mesh, j))
        decision = job["decision"]
        assert decision["metric"] == "w2" and decision["method"] == values["method"] == "exact"
        assert decision["exact_seconds"] == decision["estimated_seconds"] < 1.0
        assert values["value"] == pytest.approx(lp, rel=1e-9) and values["converged"]
        assert values["support_sizes"] == [int(np.count_nonzero(_bump(mesh, k)))
                                           for k in (0, j)]


def test_convolutional_route_reports_the_policy_it_ran(client, meshes_dir, shared_mesh):
    mesh = shared_mesh("woody.obj")
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    (j,) = _targets(mesh, (0.5,))
    job, values = _run(client, mid, {"mu0": {"vertex": 0, "radius": 0.1},
                                     "mu1": {"vertex": j, "radius": 0.1},
                                     "method": "convolutional"})
    decision, reg = job["decision"], values["regularization"]
    assert values["method"] == decision["method"] == "convolutional" and values["converged"]
    assert reg == decision["regularization"] and reg["purpose"] == "values" and reg["debiased"]
    for key in ("gamma", "t", "substeps", "debiased"):
        assert values[key] == decision[key] == reg[key]
    lp = _lp(mesh, _bump(mesh, 0), _bump(mesh, j))
    assert values["value"] == pytest.approx(lp, rel=0.15)  # woody: 694 vertices, coarse


def test_explicit_gamma_reports_no_policy(client, meshes_dir):
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    body = {"mu0": {"vertex": 0, "radius": 0.1}, "mu1": {"vertex": 500, "radius": 0.1},
            "gamma": 0.01}
    job, values = _run(client, mid, body)
    assert values["method"] == "convolutional" and values["regularization"] is None
    assert values["gamma"] == 0.01 and values["substeps"] == 1 and values["debiased"] is False
    assert job["decision"]["reason"] == "gamma given"


@pytest.mark.parametrize(("algorithm", "ran"), [("auto", "ipm"), ("ipm", "ipm"),
                                                ("admm", "admm"), ("weiszfeld", "weiszfeld")])
def test_w1_reports_the_algorithm_that_ran_and_its_residual(client, meshes_dir, shared_mesh,
                                                            algorithm, ran):
    """W1 on /distances: the algorithm that ran (never "auto") and its own stopping quantity
    as the residual (the interior point's certified relative gap, as /flows reports it)."""
    from solvers.emd import earth_movers_distance

    mesh = shared_mesh("woody.obj")
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    body = {"mu0": {"vertex": 0, "radius": 0.15}, "mu1": {"vertex": 500, "radius": 0.15},
            "metric": "w1", "w1_method": algorithm}
    job, values = _run(client, mid, body)
    assert values["w1_method"] == job["decision"]["w1_method"] == ran
    assert values["method"] == "beckmann" and job["decision"]["basis"] == "flow"
    direct = earth_movers_distance(mesh, _bump(mesh, 0, 0.15), _bump(mesh, 500, 0.15),
                                   method=ran)
    assert values["residual"] == pytest.approx(direct.residual, rel=1e-6)
    assert values["value"] == pytest.approx(direct.value, rel=1e-9)
    if ran == "ipm":  # the certified gap, below the interior point's tolerance
        assert values["converged"] and values["residual"] <= 1e-4
        flows = client.post(f"/v1/domains/{mid}/flows", json={
            "mu0": body["mu0"], "mu1": body["mu1"], "method": body["w1_method"]}).json()
        flow_values = client.get(f"/v1/jobs/{flows['id']}/result?arrays=false").json()
        assert flow_values["values"]["residual"] == pytest.approx(values["residual"])


def test_w1_refuses_an_impossible_algorithm_at_submission(client, meshes_dir):
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    body = {"mu0": {"vertex": 0, "radius": 0.15}, "mu1": {"vertex": 500, "radius": 0.15},
            "metric": "w1", "w1_method": "ipm", "basis": "full"}
    assert_error(client.post(f"/v1/domains/{mid}/distances", json=body), 422, "w1_method")


def test_decision_is_taken_at_submission_and_kept_by_a_rerun(make_client, meshes_dir,
                                                             shared_mesh, monkeypatch):
    """The 202 carries the decision; the library decides the same from the built mesh; a
    worker that dies leaves the job to the reaper, and the re-run executes the stored
    decision even where deciding again would now choose otherwise."""
    import solvers.transport.decision as decision_module
    from service.jobs.db import JobRow
    from solvers.transport.decision import decide_distance

    # no consumer: jobs stay queued; the reaper runs only when called (a background pass could
    # take the re-run for dead under load: heartbeats every 2 s against stale_after 1 s)
    client = make_client(queue="sqlite", stale_after=1.0, reaper_interval=3600)
    rt = client.app.state.runtime
    rt.reaper.enqueue = lambda job_id, queue=None: None
    mesh = shared_mesh("spot.obj")
    mid = upload_mesh(client, meshes_dir / "spot.obj").json()["id"]
    response = client.post(f"/v1/domains/{mid}/distances", json=SPOT_REQUEST)
    assert response.status_code == 202
    job = response.json()
    decision = job["decision"]
    assert decision["method"] == "exact" and decision["exact_seconds"] <= \
        decision_module.EXACT_BUDGET_SECONDS
    assert client.get(f"/v1/jobs/{job['id']}").json()["decision"] == decision
    library = decide_distance(mesh, _bump(mesh, 935, 0.15), _bump(mesh, 615, 0.15))
    assert {"metric": "w2", **library.as_dict()} == decision

    claim = rt.repo.claim(job["id"], "dead-worker")  # a worker takes it and dies
    assert claim is not None and claim.job.decision == decision
    rt.repo._update((JobRow.id == job["id"],), heartbeat_at=time.time() - 10)
    assert rt.reaper.run_once()["requeued"] == [job["id"]]
    monkeypatch.setattr(decision_module, "EXACT_BUDGET_SECONDS", 0.0)  # would now differ
    assert decide_distance(mesh, _bump(mesh, 935, 0.15), _bump(mesh, 615, 0.15)).method == \
        "convolutional"
    rt.runner.run(job["id"])
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["state"] == "succeeded" and done["attempts"] == 2
    result = client.get(f"/v1/jobs/{job['id']}/result?arrays=false").json()
    assert result["decision"] == decision and result["values"]["method"] == "exact"
    assert result["values"]["value"] == pytest.approx(0.020168, abs=5e-7)


def test_submission_resolves_and_decides_once(make_client, meshes_dir, monkeypatch):
    """Validation, the memory estimate (on the exact route it counts the supports), the
    decision and the cost estimate of one submission share one resolution of mu0 and mu1
    and one decision; the next request, even with the same body, is resolved and decided
    anew."""
    import service.operations.transport as transport

    resolved, decided = [], []
    resolve_all, decide = transport.resolve_all, transport.decide_distance
    monkeypatch.setattr(transport, "resolve_all",
                        lambda *args: resolved.append(sorted(args[1])) or resolve_all(*args))
    monkeypatch.setattr(transport, "decide_distance",
                        lambda *args, **kw: decided.append(kw["method"]) or decide(*args, **kw))
    client = make_client(queue="sqlite")  # recorded, not run
    mid = upload_mesh(client, meshes_dir / "spot.obj").json()["id"]
    url = f"/v1/domains/{mid}/distances"
    first = client.post(url, json=SPOT_REQUEST)
    assert first.status_code == 202 and first.json()["decision"]["method"] == "exact", first.text
    assert resolved == [["mu0", "mu1"]] and decided == ["auto"]
    again = client.post(url, json=SPOT_REQUEST)
    assert again.status_code == 202 and again.json()["decision"] == first.json()["decision"]
    assert len(resolved) == 2 and decided == ["auto", "auto"]
    w1 = client.post(url, json={**SPOT_REQUEST, "metric": "w1"})
    assert w1.status_code == 202 and w1.json()["decision"]["method"] == "beckmann", w1.text
    assert len(resolved) == 3 and len(decided) == 2


def test_pointwise_cost_is_checked_at_submission(client, meshes_dir):
    mid = upload_mesh(client, meshes_dir / "spot.obj").json()["id"]
    err = assert_error(client.post(f"/v1/domains/{mid}/pointwise-distances",
                                   json={"source": 0, "k": 2500}), 422, "k")
    assert "limit" in err["message"]
    # d_W^50 to all of spot was refused by the Weiszfeld cost model; the batched spectral
    # ADMM is estimated well inside the limit, so it is accepted
    from solvers.emd.pointwise import MAX_ESTIMATED_SECONDS, estimate_seconds

    assert estimate_seconds(2930, 5856, 50, 2930, False) < MAX_ESTIMATED_SECONDS / 10
