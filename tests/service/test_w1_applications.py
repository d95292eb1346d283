"""POST .../w1-barycenters (eq. 2.7) and .../path-plans (eq. 2.6, Fig. 2.12) through HTTP.

Ground truth: the library's own solvers on the same mesh and masses (the service only
resolves inputs and serializes), a barycenter with all weight on one input (that input
itself, value 0), path planning with epsilon = 0 by both solvers (interior point and
Clarabel), and refusals at submission naming the field.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from service_testing import assert_error, job_result, upload_arrays

from service.operations.w1_applications import PathPlanValues, W1BarycenterValues
from solvers import TriangleMesh
from solvers.emd import w1_barycenter
from solvers.emd.interior_point_barycenter import MAX_ESTIMATED_SECONDS, estimated_cost
from solvers.emd.path_planning import w1_path_planning


def _sphere(client, tmp_path, subdivisions):
    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    return (upload_arrays(client, tmp_path, s.vertices, s.faces, f"ball{subdivisions}.obj"),
            TriangleMesh(s.vertices, s.faces))


@pytest.fixture
def small(client, tmp_path):
    return _sphere(client, tmp_path, 2)  # 162 vertices


@pytest.fixture
def ball(client, tmp_path):
    return _sphere(client, tmp_path, 3)  # 642 vertices


def _dirac(i):
    return {"indices": [i], "masses": [1.0]}


def test_w1_barycenter_matches_the_library(client, small):
    sid, mesh = small
    sources = [0, 60, 120]
    body = {"distributions": [_dirac(i) for i in sources], "weights": [1.0, 2.0, 1.0]}
    _, res = job_result(client, client.post(f"/v1/domains/{sid}/w1-barycenters?wait=60",
                                            json=body))
    v, a = res["values"], res["arrays"]
    W1BarycenterValues.model_validate(v)
    mus = np.zeros((mesh.n, 3))
    mus[sources, [0, 1, 2]] = 1.0
    lib = w1_barycenter(mesh, mus, [1.0, 2.0, 1.0])
    assert v["converged"] and lib.converged
    assert v["weights"] == pytest.approx([0.25, 0.5, 0.25])
    assert v["value"] == pytest.approx(lib.value, rel=1e-6)
    assert v["distances"] == pytest.approx(lib.distances.tolist(), rel=1e-5, abs=1e-9)
    masses = np.asarray(a["masses"])
    assert masses.sum() == pytest.approx(1.0) and masses.min() >= 0
    assert np.abs(masses - lib.masses).sum() < 1e-5
    # eq. 2.7 at the optimum: value = sum_i alpha_i W1(rho_i, rho)^2 with its own distances
    assert v["value"] == pytest.approx(float(np.dot(v["weights"], np.square(v["distances"]))),
                                       rel=1e-9)
    assert v["residual"] < 1e-6


def test_w1_barycenter_with_all_weight_on_one_input_is_that_input(client, small):
    sid, mesh = small
    body = {"distributions": [{"vertex": 5, "radius": 0.2}, _dirac(100)],
            "weights": [1.0, 0.0]}
    _, res = job_result(client, client.post(f"/v1/domains/{sid}/w1-barycenters?wait=60",
                                            json=body))
    v, masses = res["values"], np.asarray(res["arrays"]["masses"])
    assert v["converged"] and v["value"] < 1e-6
    # the bump, as the service resolves it: a_j max(0, 1 - d_j / r) around vertex 5
    d = np.linalg.norm(mesh.vertices - mesh.vertices[5], axis=1)
    bump = mesh.areas * np.clip(1 - d / 0.2, 0, None)
    # interior-point solution: ~1e-6 left on every vertex off the support (2e-4 in L1 measured)
    assert np.abs(masses - bump / bump.sum()).sum() < 1e-3


def test_path_plan_matches_the_library_and_both_solvers_agree(client, small):
    sid, mesh = small
    rho0 = np.zeros(mesh.n)
    rho0[[3, 40, 90]] = [0.5, 0.3, 0.2]
    targets = [10, 150]
    body = {"rho0": rho0.tolist(), "targets": targets}
    _, res = job_result(client, client.post(f"/v1/domains/{sid}/path-plans?wait=60",
                                            json=body))
    v, a = res["values"], res["arrays"]
    PathPlanValues.model_validate(v)
    lib = w1_path_planning(mesh, rho0, targets)
    assert v["method"] == "ipm" == lib.method and v["converged"]
    assert v["value"] == pytest.approx(lib.value, rel=1e-6)
    assert v["objective"] == pytest.approx(v["value"])  # epsilon = 0
    arrivals = np.asarray(a["arrivals"])
    assert arrivals.sum() == pytest.approx(1.0, abs=1e-6)
    assert np.abs(np.delete(arrivals, targets)).max() < 1e-9
    assert a["targets"] == targets and v["n_targets"] == 2
    assert np.shape(a["flow"]) == (mesh.n_faces, 3) and np.shape(a["potential"]) == (mesh.n,)
    assert np.shape(a["hodge_f"]) == (mesh.n,) and np.shape(a["hodge_g"]) == (len(mesh.edges),)
    assert v["hodge_residual"] < 1e-6  # a sphere: no harmonic part
    socp = job_result(client, client.post(f"/v1/domains/{sid}/path-plans?wait=60",
                                          json={**body, "method": "socp"}))[1]["values"]
    assert socp["method"] == "socp" and socp["converged"]
    assert socp["value"] == pytest.approx(v["value"], rel=1e-4)


def test_congestion_spreads_the_arrivals(client, small):
    sid, mesh = small
    body = {"rho0": _dirac(0), "targets": [10, 150]}
    url = f"/v1/domains/{sid}/path-plans?wait=60"
    _, free = job_result(client, client.post(url, json=body))
    _, jam = job_result(client, client.post(url, json={**body, "epsilon": 10.0}))
    lib = w1_path_planning(mesh, np.eye(mesh.n)[0], [10, 150], epsilon=10.0)
    assert jam["values"]["objective"] == pytest.approx(lib.objective, rel=1e-5)
    spread = [np.sort(np.asarray(r["arrays"]["arrivals"])[[10, 150]]) for r in (free, jam)]
    assert spread[1][0] > spread[0][0] + 1e-3  # the less used exit gets more with congestion
    assert jam["values"]["value"] >= free["values"]["value"] - 1e-9


@pytest.mark.parametrize("body, field", [
    ({"distributions": [_dirac(0), _dirac(1)], "weights": [1.0]}, "weights"),
    ({"distributions": [_dirac(0), _dirac(1)], "weights": [1.0, -1.0]}, "weights"),
    ({"distributions": [_dirac(0), _dirac(1)], "weights": [0.0, 0.0]}, "weights"),
    ({"distributions": [_dirac(0), {"vertex": 10**6, "radius": 0.1}]},
     "distributions[1].vertex"),
    ({"distributions": [_dirac(0), [1.0, 2.0]]}, "distributions[1]"),
    ({"distributions": []}, "distributions"),
    ({"distributions": [_dirac(0)], "tol": 0}, "tol"),
])
def test_w1_barycenters_refuse_bad_input(client, small, body, field):
    assert_error(client.post(f"/v1/domains/{small[0]}/w1-barycenters", json=body), 422, field)


@pytest.mark.parametrize("body, field", [
    ({"rho0": _dirac(0), "targets": [10**6]}, "targets"),
    ({"rho0": _dirac(0), "targets": [-1]}, "targets"),
    ({"rho0": _dirac(0), "targets": []}, "targets"),
    ({"rho0": _dirac(0), "targets": [1], "epsilon": -1.0}, "epsilon"),
    ({"rho0": [1.0, 2.0], "targets": [1]}, "rho0"),
    ({"rho0": {"vertex": 10**6, "radius": 0.1}, "targets": [1]}, "rho0.vertex"),
    ({"rho0": _dirac(0), "targets": [1], "method": "admm"}, "method"),
])
def test_path_plans_refuse_bad_input(client, small, body, field):
    assert_error(client.post(f"/v1/domains/{small[0]}/path-plans", json=body), 422, field)


def test_path_plans_need_an_exit_on_every_loaded_component(client, tmp_path):
    s = trimesh.creation.icosphere(subdivisions=1)
    n = len(s.vertices)
    v = np.r_[s.vertices, s.vertices + [3.0, 0, 0]]
    f = np.r_[s.faces, s.faces + n]
    two = upload_arrays(client, tmp_path, v, f, "two.obj")
    body = {"rho0": {"indices": [0, n], "masses": [1.0, 1.0]}, "targets": [5]}
    assert_error(client.post(f"/v1/domains/{two}/path-plans", json=body), 422, "targets")
    # distributions with different mass per component cannot be averaged
    bary = {"distributions": [_dirac(0), {"indices": [0, n], "masses": [1.0, 1.0]}]}
    assert_error(client.post(f"/v1/domains/{two}/w1-barycenters", json=bary), 422,
                 "distributions[1]")
    ok = job_result(client, client.post(f"/v1/domains/{two}/path-plans?wait=60",
                                        json={**body, "targets": [5, n + 5]}))[1]["values"]
    assert ok["converged"]


def test_size_caps_of_the_exact_solver_are_413s(client, tmp_path, ball):
    bid, _ = ball  # 642 vertices: 18 inputs make 642 x 19 > 12000 coupled unknowns
    many = {"distributions": [_dirac(i) for i in range(18)], "method": "socp"}
    assert_error(client.post(f"/v1/domains/{bid}/w1-barycenters", json=many), 413,
                 "distributions")
    big, mesh = _sphere(client, tmp_path, 5)  # 10242 vertices
    assert_error(client.post(f"/v1/domains/{big}/w1-barycenters",
                             json={"distributions": [_dirac(0), _dirac(1)],
                                   "method": "socp"}), 413, "domain_id")
    assert_error(client.post(f"/v1/domains/{big}/path-plans",
                             json={"rho0": _dirac(0), "targets": [1], "method": "socp"}),
                 413, "method")
    # the interior point: no vertex cap; refused when its modelled run time is too long
    k = next(k for k in range(2, 65)
             if estimated_cost(mesh.n, mesh.n_faces, k).seconds > MAX_ESTIMATED_SECONDS)
    assert_error(client.post(f"/v1/domains/{big}/w1-barycenters",
                             json={"distributions": [_dirac(i) for i in range(k)]}), 413,
                 "distributions")


def test_w1_barycenter_above_the_conic_cap(client, tmp_path):
    """10242 vertices: beyond Clarabel's 5,000, solved by the interior point with its
    certificate."""
    big, _ = _sphere(client, tmp_path, 5)
    _, res = job_result(client, client.post(
        f"/v1/domains/{big}/w1-barycenters?wait=60",
        json={"distributions": [_dirac(0), _dirac(5000)], "weights": [0.5, 0.5]}))
    v = res["values"]
    assert v["method"] == "ipm" and v["converged"] and v["gap"] <= 1e-6
    assert v["lower_bound"] <= v["value"] and v["residual"] < 1e-6


def test_only_meshes(client):
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [8, 8]})
    assert grid.status_code == 201, grid.text
    gid = grid.json()["id"]
    assert_error(client.post(f"/v1/domains/{gid}/path-plans",
                             json={"rho0": _dirac(0), "targets": [1]}), 422, "domain_id")
    assert_error(client.post(f"/v1/domains/{gid}/w1-barycenters",
                             json={"distributions": [_dirac(0)]}), 422, "domain_id")
