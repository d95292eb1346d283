"""The exact W2 route for sparse supports (solvers.transport.exact) and the exact
geodesics under it (solvers.geodesics), including non-manifold meshes."""

from __future__ import annotations

import numpy as np
import ot
import pytest
from scipy.sparse.csgraph import dijkstra

from solvers import Graph, Grid
from solvers.convolutional import wasserstein_distance
from solvers.errors import InputError
from solvers.geodesics import geodesic_distances
from solvers.transport.exact import ExactTransportResult, exact_wasserstein_distance


def _points(n, idx, rng=None):
    m = np.zeros(n)
    m[idx] = 1.0 if rng is None else rng.random(len(idx)) + 0.5
    return m / m.sum()


def test_grid_diracs_give_the_squared_distance():
    grid = Grid((20, 20))
    i, j = 2 * 20 + 3, 15 * 20 + 11
    d2 = float(np.sum((grid.points[i] - grid.points[j]) ** 2))
    res = wasserstein_distance(grid, _points(grid.n, [i]), _points(grid.n, [j]))
    assert isinstance(res, ExactTransportResult) and res.method == "exact"
    assert res.value == pytest.approx(d2, rel=1e-12) and res.converged
    # Two points each, crossing assignment is worse: the LP picks the parallel one.
    a, b = _points(grid.n, [0, 19]), _points(grid.n, [5 * 20, 5 * 20 + 19])
    shift = float(np.sum((grid.points[0] - grid.points[100]) ** 2))
    assert exact_wasserstein_distance(grid, a, b).value == pytest.approx(shift, rel=1e-12)


def test_periodic_grid_wraps():
    grid = Grid((16,), periodic=True)
    near_edges = exact_wasserstein_distance(grid, _points(16, [0]), _points(16, [15]))
    assert near_edges.value == pytest.approx(grid.spacing[0] ** 2, rel=1e-12)


def test_exact_route_matches_the_lp_and_routes_automatically(shared_mesh):
    mesh = shared_mesh("woody.obj")
    rng = np.random.default_rng(3)
    s0, s1 = rng.choice(mesh.n, 12, replace=False), rng.choice(mesh.n, 9, replace=False)
    m0, m1 = _points(mesh.n, s0, rng), _points(mesh.n, s1, rng)
    res = wasserstein_distance(mesh, m0, m1)  # defaults: point masses take the exact route
    assert res.method == "exact" and res.converged and res.residual < 1e-12
    i0, i1 = np.flatnonzero(m0), np.flatnonzero(m1)
    # Independent oracle: potpourri3d's edge-flip paths (never shorter than the exact
    # MMP geodesic, so the LP on them bounds the exact value from above).
    flip = geodesic_distances(mesh, i0, i1, method="edge-flip")
    lp_flip = ot.emd2(m0[i0], m1[i1], flip**2)
    assert res.value <= lp_flip * (1 + 1e-12) and res.value == pytest.approx(lp_flip, rel=0.01)
    assert res.plan.shape == (12, 9) and np.allclose(res.plan.sum(axis=1), m0[i0])
    conv = wasserstein_distance(mesh, m0, m1, method="convolutional")
    assert conv.method == "convolutional" and conv.regularization is not None


def test_routes_refuse_what_they_cannot_do():
    graph = Graph(4, [(0, 1), (1, 2), (2, 3)])
    with pytest.raises(InputError) as err:
        wasserstein_distance(graph, _points(4, [0]), _points(4, [3]), method="exact")
    assert err.value.field == "method"
    with pytest.raises(InputError) as err:
        wasserstein_distance(graph, _points(4, [0]), _points(4, [3]), method="fast")
    assert err.value.field == "method"
    # auto on a graph: convolutional with the policy
    res = wasserstein_distance(graph, _points(4, [0]), _points(4, [3]))
    assert res.method == "convolutional" and res.regularization.debiased


@pytest.mark.parametrize("name", ["cow.obj", "beetle.obj"])
def test_geodesics_on_non_manifold_meshes(shared_mesh, name):
    """cow (one hourglass vertex) and beetle (non-manifold edges, two components) used to
    raise "mesh not manifold": exact distances are bounded by the straight line below and
    edge paths above, symmetric, and infinite only across components."""
    mesh = shared_mesh(name)
    rng = np.random.default_rng(0)
    s, t = rng.choice(mesh.n, 6, replace=False), rng.choice(mesh.n, 7, replace=False)
    d = geodesic_distances(mesh, s, t)
    labels = mesh.component_labels
    same = labels[s][:, None] == labels[t][None, :]
    assert np.all(np.isfinite(d[same])) and np.all(np.isinf(d[~same]))
    assert np.allclose(geodesic_distances(mesh, t, s), d.T, rtol=1e-9, equal_nan=True)
    e = np.asarray(mesh.edges)
    w = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)
    import scipy.sparse as sp

    graph = sp.csr_matrix((w, (e[:, 0], e[:, 1])), shape=(mesh.n, mesh.n))
    upper = dijkstra(graph, directed=False, indices=s)[:, t]
    lower = np.linalg.norm(mesh.vertices[s][:, None] - mesh.vertices[t][None], axis=2)
    assert np.all(d[same] <= upper[same] * (1 + 1e-9))
    assert np.all(d[same] >= lower[same] * (1 - 1e-9))


@pytest.mark.parametrize("name", ["woody.obj", "cow.obj", "beetle.obj"])
def test_local_bounded_solves_equal_whole_surface_solves(shared_mesh, name, monkeypatch):
    """A bounded MMP solve runs on the faces near its source only (solvers.geodesics.
    _ball_faces): the distances within the bound are bitwise those of the solve on the whole
    (fan-split) surface, on a manifold mesh, on cow's hourglass vertex and on beetle's
    non-manifold edges (with the junction closure), from sources near the junctions too."""
    import solvers.geodesics as g
    from solvers.geodesics import geodesic_distances_within

    mesh = shared_mesh(name)
    pieces = g._pieces(mesh)
    rng = np.random.default_rng(7)
    sources = list(rng.choice(mesh.n, 6, replace=False)) + list(pieces.junctions[:2])
    paths = g.edge_path_distances(mesh, sources)
    local_solves = 0
    for s, row in zip(sources, paths, strict=True):
        finite = np.sort(row[np.isfinite(row)])
        for q in (0.02, 0.1, 0.3):
            bound = float(finite[int(q * (len(finite) - 1))])
            monkeypatch.setattr(g, "LOCAL_SOLVE_FRACTION", 1.0)  # always the faces near s
            local = geodesic_distances_within(mesh, int(s), bound)
            keep = g._ball_faces(pieces, int(pieces.first_copy[s]), bound * (1 + 1e-9))
            local_solves += bool(keep.mean() < 1.0)
            monkeypatch.setattr(g, "LOCAL_SOLVE_FRACTION", 0.0)  # always the whole surface
            whole = geodesic_distances_within(mesh, int(s), bound)
            assert np.array_equal(local, whole)
            assert np.isfinite(whole).sum() > 1
    assert local_solves >= 12  # the comparison ran on proper sub-meshes


@pytest.mark.parametrize(("name", "size", "seeds"), [("woody.obj", 25, (0, 1, 2)),
                                                     ("cow.obj", 8, (0,))])
def test_bounded_solves_give_the_full_lp(shared_mesh, name, size, seeds):
    """The exact route solves each geodesic only out to the radius its plan needs (module
    docstring of solvers.transport.exact): its value must still be the LP on the full
    exact cost matrix, on a manifold mesh and on cow's junction vertex."""
    mesh = shared_mesh(name)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        s0, s1 = (rng.choice(mesh.n, size, replace=False) for _ in range(2))
        m0, m1 = _points(mesh.n, s0, rng), _points(mesh.n, s1, rng)
        res = exact_wasserstein_distance(mesh, m0, m1)
        i0, i1 = np.flatnonzero(m0), np.flatnonzero(m1)
        full = ot.emd2(m0[i0], m1[i1], geodesic_distances(mesh, i0, i1) ** 2)
        assert res.value == pytest.approx(full, rel=1e-10) and res.converged
        assert np.all(np.isfinite(res.plan)) and np.allclose(res.plan.sum(axis=0), m1[i1])


def test_pivot_bounds_keep_the_lp_exact_and_cut_its_rounds(shared_mesh, monkeypatch):
    """Above TRIANGLE_ENTRIES the rows' bounds go through their nearest pivot rows only
    (solvers.transport.exact._pivot_bounds): still lower bounds, so the value is the LP
    on the full exact cost matrix, in fewer LP rounds than with no such bounds."""
    import solvers.transport.exact as ex

    mesh = shared_mesh("woody.obj")
    rng = np.random.default_rng(3)
    s0, s1 = (rng.choice(mesh.n, 60, replace=False) for _ in range(2))
    m0, m1 = _points(mesh.n, s0, rng), _points(mesh.n, s1, rng)
    i0, i1 = np.flatnonzero(m0), np.flatnonzero(m1)
    full = ot.emd2(m0[i0], m1[i1], geodesic_distances(mesh, i0, i1) ** 2)
    rounds, lp, pivot_bounds = [], ex._network_simplex, ex._pivot_bounds
    monkeypatch.setattr(ex, "_network_simplex", lambda *a, **k: rounds.append(1) or lp(*a, **k))
    monkeypatch.setattr(ex, "TRIANGLE_ENTRIES", 0)  # every run above the cap
    counts = {}
    for pivots in (0, 1, 8):  # 0: no bounds through other rows, as before the pivots
        monkeypatch.setattr(ex, "_pivot_bounds", pivot_bounds if pivots else
                            lambda near, dist, p: np.zeros(dist.shape))
        monkeypatch.setattr(ex, "PIVOT_ROWS", pivots)
        rounds.clear()
        res = exact_wasserstein_distance(mesh, m0, m1)
        assert res.value == pytest.approx(full, rel=1e-10) and res.converged
        counts[pivots] = len(rounds)
    assert counts[8] < counts[0], counts


def test_decision_is_a_pure_function_of_the_stored_domain(shared_mesh, monkeypatch):
    """The default decision reads the inputs and the stored domain only: the library's sketch
    of the built mesh and the service's sketch of the stored arrays give the same decision,
    solves run in between (process history) change nothing, no operator is built for it; a
    budget below the model takes the convolutional route and says why; no clock fallback."""
    import solvers.transport.decision as decision
    from solvers.domains.sketch import DomainSketch
    from solvers.errors import CancelledError
    from solvers.geodesics import mmp_solve_seconds
    from solvers.transport.decision import EXACT_BUDGET_SECONDS, decide_distance
    from solvers.transport.exact import exact_route_estimate, lp_seconds

    mesh = shared_mesh("cow.obj")  # one junction vertex: its closure is in the model
    rng = np.random.default_rng(5)
    m0 = _points(mesh.n, rng.choice(mesh.n, 25, replace=False))
    m1 = _points(mesh.n, rng.choice(mesh.n, 25, replace=False))
    stored = DomainSketch.from_stored("mesh", mesh.to_arrays(), mesh.vertices.copy(),
                                      mesh.component_labels.copy(),
                                      mesh.diagnostics.nonmanifold_vertices)
    built = set(mesh.operators.keys())  # (the fixture's mesh is shared between tests)
    first = decide_distance(stored, m0, m1)
    assert set(mesh.operators.keys()) == built  # a sketch of stored arrays builds nothing
    assert first.method == "exact" and first.exact_seconds <= EXACT_BUDGET_SECONDS
    floor = 25 * mmp_solve_seconds(mesh.n, 0.0) + lp_seconds(25, 25)
    assert floor < first.exact_seconds == exact_route_estimate(stored, m0, m1)
    res = wasserstein_distance(mesh, m0, m1)
    assert res.method == "exact" and res.decision == first
    assert set(mesh.operators.keys()) - built <= {("geodesic-pieces",), ("edge-length-graph",)}
    assert decide_distance(mesh, m0, m1) == first  # after solves: the same decision
    with pytest.raises(CancelledError):
        exact_wasserstein_distance(mesh, m0, m1, should_cancel=lambda: True)
    monkeypatch.setattr(decision, "EXACT_BUDGET_SECONDS", 0.0)
    conv = decide_distance(mesh, m0, m1)
    assert conv.method == "convolutional" and "above its 0 s budget" in conv.reason
    # above the budget the size-only lower bound is enough (no planning)
    assert conv.exact_seconds == pytest.approx(floor + mesh.diagnostics.nonmanifold_vertices
                                               * mmp_solve_seconds(mesh.n, 1.0))
    assert conv.regularization is not None
    assert (conv.gamma, conv.substeps, conv.debiased) == (
        conv.regularization.gamma, conv.regularization.substeps, True)


def test_ground_distances_per_domain_kind(monkeypatch):
    """The exact route's ground metric, owned by each domain: squared straight distances on
    point clouds, squared with periodic axes wrapped on grids, exact geodesics (not
    squared) on meshes, the all-pairs ones kept only on small meshes; none on graphs."""
    import trimesh
    from scipy.spatial.distance import cdist

    import solvers.domains.mesh as mesh_module
    from solvers import PointCloud, TriangleMesh

    rng = np.random.default_rng(0)
    grid = Grid((8, 6), bounds=[(0.0, 2.0), (0.0, 3.0)], periodic=(True, False))
    src, dst = rng.choice(grid.n, 9, replace=False), rng.choice(grid.n, 11, replace=False)
    d, squared = grid.ground_distances(src, dst)
    diff = np.abs(grid.points[src][:, None, :] - grid.points[dst][None, :, :])
    assert (diff[..., 0] > 1.0).any()  # some pairs are nearer across the period
    diff[..., 0] = np.minimum(diff[..., 0], 2.0 - diff[..., 0])
    assert squared and np.allclose(d, (diff**2).sum(axis=2), rtol=1e-12, atol=1e-15)
    assert grid.stored_ground_distances() is None

    sphere = rng.normal(size=(120, 3))
    cloud = PointCloud(sphere / np.linalg.norm(sphere, axis=1, keepdims=True))
    d, squared = cloud.ground_distances(src[:5], dst[:7])
    want = cdist(cloud.points[src[:5]], cloud.points[dst[:7]], "sqeuclidean")
    assert squared and np.allclose(d, want, rtol=1e-12, atol=1e-15)

    ico = trimesh.creation.icosphere(subdivisions=2)  # 162 vertices
    mesh = TriangleMesh(ico.vertices, ico.faces)
    src, dst = rng.choice(mesh.n, 4, replace=False), rng.choice(mesh.n, 6, replace=False)
    d, squared = mesh.ground_distances(src, dst)
    assert not squared and np.array_equal(d, geodesic_distances(mesh, src, dst))
    monkeypatch.setattr(mesh_module, "STORED_GEODESICS_VERTICES", mesh.n - 1)
    assert mesh.stored_ground_distances() is None
    assert mesh.operators.peek(("exact_geodesics",)) is None
    monkeypatch.undo()
    every, squared = mesh.stored_ground_distances()
    assert not squared and every.shape == (mesh.n, mesh.n)
    assert mesh.stored_ground_distances()[0] is every  # kept in the operator store
    np.testing.assert_allclose(every[np.ix_(src, dst)], d, rtol=1e-9)

    graph = Graph(3, [[0, 1], [1, 2]])
    assert graph.stored_ground_distances() is None
    with pytest.raises(NotImplementedError, match="graph"):
        graph.ground_distances([0], [2])


@pytest.mark.parametrize("masses", [np.zeros(0), np.zeros(3), np.array([np.nan, 1.0, 0.0])])
def test_the_lp_refuses_empty_or_massless_supports_instead_of_crashing(masses):
    """POT's network simplex on an empty support read out of bounds: a segfault of the API
    process (its client saw the connection close), reached when an overflowing sum had
    zeroed the masses. Such a call now raises."""
    from solvers.transport.exact import _network_simplex

    other = np.full(len(masses), 1.0 / max(len(masses), 1))
    with pytest.raises(ValueError, match="empty or massless"):
        _network_simplex(masses, other, np.ones((len(masses), len(masses))))
