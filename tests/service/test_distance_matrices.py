"""``/distance-matrices``: the matrix through HTTP equals the library's single pairs, its
.npy file, progress over pairs, cancellation keeping finished rows, refusals at submission."""

from __future__ import annotations

import io
import threading
import time

import numpy as np
import pytest
from service_testing import assert_error, bump_masses, upload_mesh

from solvers.convolutional import wasserstein_distance

BUMPS = [{"vertex": v, "radius": 0.3} for v in (0, 100, 300, 500)]
SHARED = {"gamma": 0.01, "substeps": 8, "debiased": True}


def _matrix(client, job_id) -> np.ndarray:
    r = client.get(f"/v1/jobs/{job_id}/arrays/matrix.npy")
    assert r.status_code == 200 and r.headers["content-type"] == "application/x-npy"
    return np.load(io.BytesIO(r.content))


def test_symmetric_matrix_equals_single_pairs(client, woody):
    mesh, mid = woody
    job = client.post(f"/v1/domains/{mid}/distance-matrices",
                      json={"distributions": BUMPS, **SHARED}).json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    values = result["values"]
    assert values["shape"] == [4, 4] and values["symmetric"] and values["complete"]
    assert values["finished_rows"] == [0, 1, 2, 3] and values["pairs_solved"] == 6
    assert values["methods"] == {"convolutional": 6} and values["converged"]
    assert values["kernels"] == [{"gamma": 0.01, "t": 0.0025, "substeps": 8, "debiased": True}]
    inline = np.array(result["arrays"]["matrix"])
    D = _matrix(client, job["id"])
    assert np.array_equal(inline, D) and np.array_equal(D, D.T) and np.all(np.diag(D) == 0)
    masses = [bump_masses(mesh, b["vertex"], b["radius"]) for b in BUMPS]
    for i, j in ((0, 1), (1, 3), (2, 3)):
        single = wasserstein_distance(mesh, masses[i], masses[j], **SHARED)
        assert abs(D[i, j] - single.value) <= 1e-6 * abs(single.value)
    assert client.get(f"/v1/jobs/{job['id']}").json()["progress"]["iteration"] == 6


def test_templates_default_route_and_large_result_as_file(make_client, meshes_dir,
                                                           shared_mesh):
    client = make_client(result_json_bytes=2000)  # the matrix only as .npy
    mesh = shared_mesh("woody.obj")
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    rows = [{"vertex": v, "radius": 0.08} for v in (0, 200, 400)]
    templates = [{"vertex": v, "radius": 0.08} for v in (650, 50)]
    job = client.post(f"/v1/domains/{mid}/distance-matrices",
                      json={"distributions": rows, "others": templates}).json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    assert "matrix" not in result["arrays"] and result["array_files"]["matrix"]["shape"] == [3, 2]
    assert result["values"]["methods"] == {"exact": 6} and not result["values"]["symmetric"]
    D = _matrix(client, job["id"])
    m0 = bump_masses(mesh, 200, 0.08)
    m1 = bump_masses(mesh, 50, 0.08)
    single = wasserstein_distance(mesh, m0, m1)
    assert single.method == "exact"
    assert abs(D[1, 1] - single.value) <= 1e-6 * single.value


def test_w1_matrix_triangle_inequality(client, woody):
    _, mid = woody
    job = client.post(f"/v1/domains/{mid}/distance-matrices",
                      json={"distributions": BUMPS[:3], "metric": "w1"}).json()
    assert job["state"] == "succeeded", job
    D = _matrix(client, job["id"])
    assert D[0, 2] <= (D[0, 1] + D[1, 2]) * (1 + 3e-4)
    assert D[0, 1] <= (D[0, 2] + D[2, 1]) * (1 + 3e-4)
    assert np.all(D[np.triu_indices(3, 1)] > 0)


def test_cancelled_matrix_keeps_finished_rows(make_client, meshes_dir):
    client = make_client(queue="sqlite", heartbeat_interval=0.05)
    rt = client.app.state.runtime
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    body = {"distributions": [{"vertex": v, "radius": 0.3} for v in range(0, 690, 23)],
            "metric": "w1"}  # 30 distributions, 435 W1 pairs in row order
    job = client.post(f"/v1/domains/{mid}/distance-matrices", json=body).json()
    worker = threading.Thread(target=rt.runner.run, args=(job["id"],))
    worker.start()
    deadline = time.monotonic() + 60
    while (client.get(f"/v1/jobs/{job['id']}").json()["progress"]["iteration"] or 0) < 60:
        assert time.monotonic() < deadline and worker.is_alive()
        time.sleep(0.02)
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 200
    worker.join(timeout=60)
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["state"] == "cancelled" and done["error"]["code"] == "cancelled"
    result = client.get(f"/v1/jobs/{job['id']}/result").json()
    values = result["values"]
    assert not values["complete"] and not values["converged"]
    assert values["finished_rows"][:2] == [0, 1]  # rows 0 and 1: 29 + 28 pairs
    assert 57 <= values["pairs_solved"] < 435
    D = _matrix(client, job["id"])
    assert np.all(np.isfinite(D[0])) and np.all(np.isfinite(D[:, 0]))
    assert np.isnan(D[-2, -1])


def test_memory_refused_at_submission_naming_the_size(make_client, meshes_dir):
    client = make_client(job_memory_bytes=50 * 2**20)
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    small = client.post(f"/v1/domains/{mid}/distance-matrices",
                        json={"distributions": BUMPS[:2], **SHARED})
    assert small.status_code in (200, 202), small.text
    many = [{"vertex": v % 690, "radius": 0.3} for v in range(2000)]
    r = client.post(f"/v1/domains/{mid}/distance-matrices",
                    json={"distributions": many, "others": many[:1500], **SHARED})
    err = assert_error(r, 413, "distributions")
    assert "GiB" in err["message"]


def test_one_distribution_is_its_zero_diagonal(client, woody):
    """A symmetric matrix of one distribution has no pair to solve: [[0]] (a fuzz run sent
    one and the decision's reason, taken from the pairs, raised a server error; with W1 the
    decision's route count differed from the run's and the job failed)."""
    _, mid = woody
    for body in ({"distributions": [BUMPS[0]]},
                 {"distributions": [{"indices": [0], "masses": [1.7e189]}]},
                 {"distributions": [BUMPS[0]], "metric": "w1"}):
        job = client.post(f"/v1/domains/{mid}/distance-matrices", json=body).json()
        assert job["state"] == "succeeded", job
        assert job["decision"]["pairs"] == 0 and not job["decision"]["methods"]
        values = client.get(f"/v1/jobs/{job['id']}/result").json()["values"]
        assert values["shape"] == [1, 1] and values["pairs_solved"] == 0
        assert _matrix(client, job["id"]).tolist() == [[0.0]]


def test_bad_inputs_name_the_field(client, woody):
    _, mid = woody
    url = f"/v1/domains/{mid}/distance-matrices"
    assert_error(client.post(url, json={"distributions": [{"vertex": 10_000, "radius": 0.2}]}),
                 422, "distributions[0].vertex")
    assert_error(client.post(url, json={"distributions": []}), 422, "distributions")
    grid = client.post("/v1/domains", json={"kind": "grid", "shape": [8, 8]}).json()["id"]
    assert_error(client.post(f"/v1/domains/{grid}/distance-matrices",
                             json={"distributions": [[1.0] * 64], "metric": "w1"}),
                 422, "metric")


def test_decision_recorded_at_submission_and_reported(make_client, meshes_dir, shared_mesh):
    """The 202 carries the matrix's decision (per-pair routes and kernels by the library's
    decide_method on the stored domain), the job stores it and the result reports it; what
    ran (routes, kernels) equals it."""
    from solvers.regularization import sketch_of
    from solvers.transport.decision import decide_method

    client = make_client(queue="sqlite")
    rt = client.app.state.runtime
    mesh = shared_mesh("woody.obj")
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    body = {"distributions": BUMPS[:3], "method": "convolutional"}
    r = client.post(f"/v1/domains/{mid}/distance-matrices", json=body)
    assert r.status_code == 202, r.text
    job = r.json()
    decision = job["decision"]
    masses = [bump_masses(mesh, b["vertex"], b["radius"]) for b in BUMPS[:3]]
    expected = [decide_method(sketch_of(mesh), masses[i], masses[j], method="convolutional")
                for i, j in ((0, 1), (0, 2), (1, 2))]
    assert decision["per_pair"] and decision["zero_diagonal"] and decision["pairs"] == 3
    assert decision["methods"] == {"convolutional": 3}
    kernels = {(d.t, d.substeps) for d in expected}
    assert decision["kernel_count"] == len(kernels)
    listed = sorted((k["t"], k["substeps"]) for k in decision["kernels"])
    assert len(listed) == len(kernels)
    for (t, s), (t_ref, s_ref) in zip(listed, sorted(kernels), strict=True):
        assert s == s_ref and t == pytest.approx(t_ref, rel=1e-12)
    rt.runner.run(job["id"])
    result = client.get(f"/v1/jobs/{job['id']}/result").json()["values"]
    assert result["decision"] == decision
    assert result["methods"] == decision["methods"]
    assert len(result["kernels"]) == decision["kernel_count"]


def test_submission_resolves_the_distributions_once(make_client, meshes_dir, monkeypatch):
    """Validation, the memory estimate (route auto without gamma: the exact route's terms
    count the supports) and the decision of one submission share one resolution of the
    request's distributions; the next request is resolved anew."""
    import service.operations.matrices as matrices

    calls = []
    resolve_all = matrices.resolve_all
    monkeypatch.setattr(matrices, "resolve_all",
                        lambda *args: calls.append(len(args[1])) or resolve_all(*args))
    client = make_client(queue="sqlite")  # recorded, not run
    mid = upload_mesh(client, meshes_dir / "woody.obj").json()["id"]
    url = f"/v1/domains/{mid}/distance-matrices"
    first = client.post(url, json={"distributions": BUMPS})
    assert first.status_code == 202 and first.json()["decision"]["pairs"] == 6, first.text
    assert calls == [4]
    second = client.post(url, json={"distributions": BUMPS[:3], "others": BUMPS[3:]})
    assert second.status_code == 202 and second.json()["decision"]["pairs"] == 3
    assert calls == [4, 4]


def test_uniform_decision_runs_as_explicit_arguments(client, woody):
    _, mid = woody
    job = client.post(f"/v1/domains/{mid}/distance-matrices",
                      json={"distributions": BUMPS[:3], **SHARED}).json()
    assert job["state"] == "succeeded", job
    d = job["decision"]
    assert d["solver_arguments"] == {"method": "convolutional", "gamma": 0.01, "t": None,
                                     "substeps": 8, "debiased": True}
    assert d["kernel_count"] == 1 and d["methods"] == {"convolutional": 3}
    exact = client.post(f"/v1/domains/{mid}/distance-matrices",
                        json={"distributions": [{"vertex": v, "radius": 0.08}
                                                for v in (0, 200, 400)]}).json()
    assert exact["state"] == "succeeded", exact
    assert exact["decision"]["solver_arguments"] == {"method": "exact"}
    assert exact["decision"]["methods"] == {"exact": 3}
    w1 = client.post(f"/v1/domains/{mid}/distance-matrices",
                     json={"distributions": BUMPS[:2], "metric": "w1"}).json()
    assert w1["decision"]["w1_method"] == "ipm" and w1["decision"]["methods"] == {"w1": 1}


def _traced_peak(fn) -> int:
    """This process's peak of traced allocations while ``fn()`` runs. A process forked
    meanwhile (the all-pairs geodesics' solvers) stops tracing at once: its allocations are
    never in this process's figure, and tracing them made the solves ~3x slower (11.0
    instead of 3.3 CPU-s for the 642-vertex sphere's all-pairs geodesics)."""
    import os
    import tracemalloc

    if not _FORK_HOOK:  # a fork hook cannot be removed: registered once per process
        os.register_at_fork(after_in_child=tracemalloc.stop)  # a no-op where not tracing
        _FORK_HOOK.append(True)
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


_FORK_HOOK: list[bool] = []


def _go(where: str) -> None:  # a matrix's stop(): never cancelled
    pass


def _sparse_masses(n, k, per, seed):
    rng = np.random.default_rng(seed)
    M = np.zeros((n, k))
    for j in range(k):
        M[rng.choice(n, per, replace=False), j] = rng.random(per) + 0.5
    return M / M.sum(axis=0)


@pytest.fixture(scope="module")
def icosphere():
    """The 642-vertex icosphere of the two memory tests below, one mesh for both: the first
    leaves its all-pairs geodesics stored (~4 CPU-s of MMP solves), which the second would
    otherwise build again in its warm-up run (which builds them where they are missing:
    either test alone, or in either order, measures from the state it describes)."""
    import trimesh

    from solvers import TriangleMesh

    ico = trimesh.creation.icosphere(subdivisions=3)  # 642 vertices
    return TriangleMesh(ico.vertices, ico.faces)


def test_exact_matrix_memory_estimate_counts_what_the_route_builds(icosphere):
    """The estimate's ground distances cover the measured peak of building them with the
    supports covering the domain (tracemalloc, warm: the geodesic pieces are the domain's
    cached operators): a small mesh's stored all-pairs geodesics (counted once: the route
    builds them instead of the supports' matrix, not beside it), the pairwise geodesics of
    supports covering less than half of it, a point cloud's squared distances and the
    coordinate differences they are summed from; and the whole job's estimate covers the
    whole exact matrix in both mesh cases."""
    from service.operations.base import view_of_domain
    from service.operations.matrices import (
        DistanceMatrixRequest,
        estimate_bytes,
        ground_distance_bytes,
    )
    from solvers import PointCloud
    from solvers.convolutional.matrix import (
        SHARED_COST_ENTRIES,
        _support_distances,
        distance_matrix,
    )
    from solvers.domains.mesh import STORED_GEODESICS_VERTICES

    assert STORED_GEODESICS_VERTICES**2 <= SHARED_COST_ENTRIES  # stored: below the cap
    mesh = icosphere
    mesh.operators.discard(("exact_geodesics",))  # built below, traced
    n, everything = mesh.n, np.arange(mesh.n)
    counted = ground_distance_bytes(view_of_domain(mesh))
    assert counted < 2 * 8 * n * n  # the n x n geodesics once
    mesh.ground_distances([0], [1])  # the geodesic pieces (cached operators)
    stored = _traced_peak(lambda: _support_distances(mesh, everything, everything, _go))
    assert mesh.operators.peek(("exact_geodesics",)) is not None
    assert 8 * n * n <= stored <= counted, (stored, counted)
    # one MMP solve per point of the smaller side, traced ~3x slower: 160 rows against all
    # 642 columns (not 300 x 342) give the same 0.82 MB matrix of pairwise geodesics with
    # 160 solves instead of 300. An n x n matrix built beside it still exceeds the count.
    half = _traced_peak(lambda: _support_distances(mesh, everything[:160], everything, _go))
    assert mesh.operators.peek(("exact_geodesics",)) is not None and half <= counted

    rng = np.random.default_rng(0)
    p = rng.normal(size=(n, 3))
    cloud = PointCloud(p / np.linalg.norm(p, axis=1, keepdims=True))
    cloud_peak = _traced_peak(lambda: _support_distances(cloud, everything, everything, _go))
    assert 4 * 8 * n * n <= cloud_peak <= ground_distance_bytes(view_of_domain(cloud))

    geodesics = ("exact_geodesics",)
    for per, keeps in ((80, True), (10, False)):  # supports over / under half the mesh
        M = _sparse_masses(n, 8, per, seed=per)
        distance_matrix(mesh, M, method="exact")  # warm (imports, compiled kernels)
        built = mesh.operators.peek(geodesics)
        mesh.operators.discard(geodesics)
        peak = _traced_peak(lambda M=M: distance_matrix(mesh, M, method="exact"))
        assert (mesh.operators.peek(geodesics) is not None) == keeps
        req = DistanceMatrixRequest(distributions=_listed(M), method="exact")
        assert estimate_bytes(view_of_domain(mesh), req) >= peak
    # stored again (those of the 80-point run) for the next test's warm-up run
    mesh.operators.get(geodesics, lambda: built)


def _listed(M) -> list[dict]:
    """The columns of ``M`` as a request's sparse distributions."""
    return [{"indices": np.flatnonzero(c).tolist(), "masses": c[c > 0].tolist()} for c in M.T]


def test_exact_matrix_memory_estimate_counts_row_blocks_and_lps(icosphere):
    """Where the rows' cost blocks and the LPs dominate (a small mesh, supports of half of
    it overlapping from row to row, two threads), the estimate covers the measured peak of
    the whole exact matrix (tracemalloc, warm; the network simplex's own per-arc arrays,
    outside tracemalloc, are in the estimate too) and stays within 3x of it; the terms
    counted before (ground distances and n^2 entries of blocks) were short of it."""
    from service.operations.base import view_of_domain
    from service.operations.matrices import (
        DistanceMatrixRequest,
        estimate_bytes,
        ground_distance_bytes,
    )
    from solvers.convolutional.matrix import EXACT_THREADS, distance_matrix

    assert EXACT_THREADS == 2  # the threads the estimate counts LPs for
    mesh = icosphere
    n = mesh.n
    M = _sparse_masses(n, 6, n // 2, seed=3)  # 6 rows of 321 points: rows overlap
    distance_matrix(mesh, M, method="exact", threads=2)  # warm: stored geodesics, imports
    peak = _traced_peak(lambda: distance_matrix(mesh, M, method="exact", threads=2))
    view = view_of_domain(mesh)
    estimate = estimate_bytes(view, DistanceMatrixRequest(distributions=_listed(M),
                                                          method="exact"))
    assert ground_distance_bytes(view) + 8 * n * n < peak <= estimate <= 3 * peak, (
        peak, estimate)


def test_w1_spectral_matrix_records_its_decision(client, woody):
    """metric w1, method spectral: the library's d_W^k matrix with its certified lower
    bounds; the decision (method, k) taken at submission, from the sizes alone."""
    from solvers.emd.dwk_matrix import dwk_matrix

    mesh, mid = woody
    url = f"/v1/domains/{mid}/distance-matrices"
    job = client.post(url, json={"distributions": BUMPS[:3], "metric": "w1",
                                 "method": "spectral", "k": 5}).json()
    assert job["state"] == "succeeded", job
    decision = job["decision"]
    assert decision["w1_matrix_method"] == "spectral" and decision["k"] == 5
    assert decision["methods"] == {"spectral": 3}
    D = _matrix(client, job["id"])
    masses = np.stack([bump_masses(mesh, b["vertex"], b["radius"]) for b in BUMPS[:3]], axis=1)
    ref = dwk_matrix(mesh, masses, k=5)
    np.testing.assert_allclose(D, ref.values, rtol=1e-12)
    lower = np.load(io.BytesIO(client.get(
        f"/v1/jobs/{job['id']}/arrays/lower_bounds.npy").content))
    assert np.all(lower <= D + 1e-15) and np.all(np.diag(lower) == 0)
    values = client.get(f"/v1/jobs/{job['id']}/result").json()["values"]
    assert values["methods"] == {"spectral": 3} and values["converged"]
    auto = client.post(url, json={"distributions": BUMPS[:3], "metric": "w1"}).json()
    assert auto["decision"]["w1_matrix_method"] == "interior_point"
    assert auto["decision"]["k"] is None


def test_w1_method_and_k_refused_naming_the_field(client, woody):
    _, mid = woody
    url = f"/v1/domains/{mid}/distance-matrices"
    base = {"distributions": BUMPS[:2]}
    for extra, name in (({"k": 5}, "k"), ({"method": "spectral"}, "method"),
                        ({"metric": "w1", "method": "interior_point", "k": 5}, "k"),
                        ({"metric": "w1", "k": -1}, "k"),
                        ({"metric": "w1", "k": 10_000}, "k"),
                        ({"metric": "w1", "method": "convolutional"}, "method")):
        assert_error(client.post(url, json={**base, **extra}), 422, name)
