"""Distance matrices: equal to single-pair calls, symmetric, W1 metric, progress, cancel."""

from __future__ import annotations

import numpy as np
import pytest
from shared_meshes import hat_bump as _bump
from shared_meshes import load_shared_mesh

from solvers import Grid
from solvers.convolutional import distance_matrix, wasserstein_distance
from solvers.emd import earth_movers_distance
from solvers.errors import CancelledError, InputError


@pytest.fixture(scope="module")
def woody():
    mesh = load_shared_mesh("woody.obj")
    wide = np.stack([_bump(mesh, i, 0.3) for i in (0, 100, 300, 500, 650)], axis=1)
    return mesh, wide


def _relative_gap(a: float, b: float) -> float:
    return abs(a - b) / max(abs(b), 1e-300)


def test_block_matrix_equals_single_pairs_one_kernel(woody):
    """Explicit gamma: all 10 pairs share one kernel and run as one block."""
    mesh, wide = woody
    args = dict(gamma=0.01, substeps=8, debiased=True)
    res = distance_matrix(mesh, wide, **args)
    assert res.kernels == [(0.01, 0.0025, 8, True)]
    for i in range(5):
        for j in range(i + 1, 5):
            single = wasserstein_distance(mesh, wide[:, i], wide[:, j], **args)
            assert _relative_gap(res.values[i, j], single.value) <= 1e-6
            assert res.pair_iterations[i, j] == single.iterations
            assert res.pair_converged[i, j] == single.converged
    assert np.array_equal(res.values, res.values.T)
    assert np.all(np.diag(res.values) == 0.0)
    assert set(np.diag(res.methods)) == {"identical"}
    assert res.converged and res.residual <= 1e-5


def test_default_matrix_equals_default_single_pairs(woody):
    """Defaults: each pair takes its own single-pair decision (per-pair gamma on the
    convolutional route; the exact LP for sparse supports from one shared cost matrix)."""
    mesh, wide = woody
    small = np.stack([_bump(mesh, i, 0.08) for i in (0, 300, 650)], axis=1)
    for masses, method in ((wide[:, :3], "convolutional"), (small, "auto")):
        res = distance_matrix(mesh, masses, method=method)
        for i in range(3):
            for j in range(i + 1, 3):
                single = wasserstein_distance(mesh, masses[:, i], masses[:, j], method=method)
                assert res.methods[i, j] == single.method
                assert _relative_gap(res.values[i, j], single.value) <= 1e-6
        assert np.array_equal(res.values, res.values.T)
        assert np.all(np.diag(res.values) == 0.0)
    assert set(res.methods[np.triu_indices(3, 1)]) == {"exact"}


def test_rectangular_matrix_against_templates(woody):
    mesh, wide = woody
    args = dict(gamma=0.01, substeps=8, debiased=False)
    res = distance_matrix(mesh, wide[:, :3], wide[:, 3:], **args)
    assert res.values.shape == (3, 2) and not res.symmetric
    for i in range(3):
        for j in range(2):
            single = wasserstein_distance(mesh, wide[:, i], wide[:, 3 + j], **args)
            assert _relative_gap(res.values[i, j], single.value) <= 1e-6


def test_not_debiased_diagonal_is_solved(woody):
    mesh, wide = woody
    res = distance_matrix(mesh, wide[:, :2], gamma=0.01, substeps=8, debiased=False)
    own = wasserstein_distance(mesh, wide[:, 0], wide[:, 0], gamma=0.01, substeps=8)
    assert res.methods[0, 0] == "convolutional"
    assert _relative_gap(res.values[0, 0], own.value) <= 1e-6


def test_grid_exact_matrix_matches_lp():
    grid = Grid((12, 12))
    rng = np.random.default_rng(3)
    masses = np.zeros((grid.n, 4))
    for k in range(4):
        masses[rng.choice(grid.n, 5, replace=False), k] = rng.random(5) + 0.1
    res = distance_matrix(grid, masses)
    for i in range(4):
        for j in range(i + 1, 4):
            single = wasserstein_distance(grid, masses[:, i], masses[:, j])
            assert single.method == "exact" and res.methods[i, j] == "exact"
            assert _relative_gap(res.values[i, j], single.value) <= 1e-9


def _grid_points(count: int, seed: int):
    grid = Grid((12, 12))
    rng = np.random.default_rng(seed)
    masses = np.zeros((grid.n, count))
    for k in range(count):
        masses[rng.choice(grid.n, 5, replace=False), k] = rng.random(5) + 0.1
    return grid, masses


def test_exact_lps_in_threads_equal_one_thread(monkeypatch):
    """The exact pairs' LPs run in threads, in chunks: same values with 1 or 3 threads."""
    import solvers.convolutional.matrix as matrix

    monkeypatch.setattr(matrix, "EXACT_CHUNK", 4)
    grid, masses = _grid_points(7, 5)
    one = distance_matrix(grid, masses, threads=1)
    three = distance_matrix(grid, masses, threads=3)
    assert set(one.methods[np.triu_indices(7, 1)]) == {"exact"}
    assert np.array_equal(one.values, three.values) and three.converged
    with pytest.raises(InputError):
        distance_matrix(grid, masses, threads=0)


def test_exact_cancellation_between_chunks_keeps_finished_rows(monkeypatch):
    import solvers.convolutional.matrix as matrix

    monkeypatch.setattr(matrix, "EXACT_CHUNK", 3)
    grid, masses = _grid_points(4, 6)
    done = []
    with pytest.raises(CancelledError) as info:
        distance_matrix(grid, masses, threads=2, progress=lambda d, w: done.append(d),
                        should_cancel=lambda: len(done) >= 3)
    partial = info.value.partial
    assert list(partial.finished_rows) == [0]  # pairs (0, 1), (0, 2), (0, 3): one chunk
    assert np.isnan(partial.values[1, 2]) and not partial.computed[2, 3]


def test_w1_matrix_triangle_inequality_and_single_pairs():
    mesh = load_shared_mesh("woody.obj")
    masses = np.stack([_bump(mesh, i, 0.2) for i in (0, 200, 400, 650)], axis=1)
    res = distance_matrix(mesh, masses, metric="w1")
    assert set(res.methods[np.triu_indices(4, 1)]) == {"w1"}
    single = earth_movers_distance(mesh, masses[:, 1], masses[:, 2])
    assert _relative_gap(res.values[1, 2], single.value) <= 1e-6
    D = res.values
    assert np.all(D[np.triu_indices(4, 1)] > 0)
    for i in range(4):
        for j in range(4):
            for k in range(4):
                # solver tolerance: certified relative gap 1e-4 per value
                assert D[i, k] <= (D[i, j] + D[j, k]) * (1 + 3e-4)


def test_progress_over_pairs_and_cancel_keeps_finished_rows(woody):
    mesh, wide = woody
    seen = []
    distance_matrix(mesh, wide, gamma=0.01, substeps=8, debiased=True,
                    progress=lambda done, worst, frac: seen.append((done, frac)))
    assert [d for d, _ in seen] == list(range(1, 11)) and seen[-1][1] == 1.0

    # One pair per row first: cancel once row 0's four pairs are done.
    done = []
    with pytest.raises(CancelledError) as info:
        distance_matrix(mesh, wide, metric="w1", progress=lambda d, w: done.append(d),
                        should_cancel=lambda: len(done) >= 4)
    partial = info.value.partial
    assert 0 in partial.finished_rows and partial.computed[0].all()
    assert np.isnan(partial.values[2, 3]) and not partial.computed[2, 3]
    assert np.all(np.isfinite(partial.values[0]))
    assert not partial.converged


def test_block_cancellation_keeps_finished_pairs(woody):
    mesh, wide = woody
    calls = []

    def cancel() -> bool:
        calls.append(1)
        return len(calls) > 3

    with pytest.raises(CancelledError) as info:
        distance_matrix(mesh, wide, gamma=0.01, substeps=8, debiased=True,
                        should_cancel=cancel)
    partial = info.value.partial
    assert partial.values.shape == (5, 5)
    assert np.all(np.diag(partial.values) == 0.0)
    assert np.isnan(partial.values[0, 1])  # nothing finished in three steps


def test_input_errors(woody):
    mesh, wide = woody
    with pytest.raises(InputError) as info:
        distance_matrix(mesh, wide, metric="w3")
    assert info.value.field == "metric"
    with pytest.raises(InputError) as info:
        distance_matrix(mesh, wide[:-1])
    assert info.value.field == "distributions"
    with pytest.raises(InputError) as info:
        distance_matrix(mesh, wide, -wide)
    assert info.value.field == "others"


def test_quick_route_decision_agrees_with_the_default(woody):
    from solvers.regularization import sketch_of
    from solvers.transport.decision import decide_distance, decide_method

    mesh, wide = woody
    small = [_bump(mesh, i, 0.08) for i in (0, 650)]
    sketch = sketch_of(mesh)
    for m0, m1 in ((small[0], small[1]), (wide[:, 0], wide[:, 4]), (small[0], wide[:, 2])):
        quick, full = decide_method(sketch, m0, m1), decide_distance(sketch, m0, m1)
        assert quick.method == full.method
        if full.method == "exact":
            assert quick.estimated_seconds >= full.estimated_seconds
        else:
            assert quick == full


def test_exact_matrix_over_most_vertices_keeps_the_geodesic_matrix():
    mesh = load_shared_mesh("woody.obj")
    masses = np.stack([_bump(mesh, i, 0.15) for i in range(0, 694, 30)], axis=1)
    assert 2 * np.count_nonzero(masses.sum(axis=1)) >= mesh.n
    res = distance_matrix(mesh, masses, method="exact")
    assert mesh.operators.peek(("exact_geodesics",)) is not None
    for i, j in ((0, 5), (3, 17)):
        single = wasserstein_distance(mesh, masses[:, i], masses[:, j], method="exact")
        assert _relative_gap(res.values[i, j], single.value) <= 1e-9


def test_support_lp_core_equals_ot_emd():
    """The exact pairs' LP calls POT's compiled core directly: same value, marginals and
    status as ``ot.emd`` on random problems (unequal sizes, rescaled masses, and costs with
    infinite entries that no plan uses)."""
    import ot

    from solvers.convolutional.matrix import _support_lp
    from solvers.transport.exact import _finite_cost

    rng = np.random.default_rng(11)
    for k in range(30):
        n, m = rng.integers(1, 40, size=2)
        a, b = rng.random(n) + 1e-3, rng.random(m) + 1e-3
        a, b = a / a.sum(), b / b.sum()
        cost = rng.random((n, m)) ** 2 * 10
        if k % 5 == 0 and n > 1 and m > 1:  # a second component: one point on each side
            cost[0, :], cost[:, 0] = np.inf, np.inf
            cost[0, 0] = 0.5
            b[1:] *= (1 - a[0]) / b[1:].sum()
            b[0] = a[0]
        else:  # masses equal to rounding: ot.emd rescales b to the mass of a
            b = b * (1 + 1e-12 * (k % 3))
        value, iterations, residual, converged = _support_lp(a, b, cost)
        plan = ot.emd(a, b, _finite_cost(cost), numItermax=10_000_000)
        expected = float(np.sum(plan[plan > 0] * cost[plan > 0]))
        assert np.isfinite(value) and _relative_gap(value, expected) <= 1e-12
        assert converged and iterations == 1 and residual <= 1e-10  # b rescaled by 1e-12


def test_exact_row_blocks_evicted_give_the_same_values(monkeypatch):
    """Each pair's costs are cut from its row's block; keeping one block at a time (rows
    recomputed) gives identical values, on a grid and on a mesh's geodesics."""
    import solvers.convolutional.matrix as matrix

    grid, masses = _grid_points(6, 8)
    mesh = load_shared_mesh("woody.obj")
    bumps = np.stack([_bump(mesh, i, 0.08) for i in (0, 200, 400, 650)], axis=1)
    kept = [distance_matrix(grid, masses), distance_matrix(mesh, bumps, method="exact")]
    monkeypatch.setattr(matrix, "ROW_BLOCK_ENTRIES", 1)
    for before, now in zip(kept, [distance_matrix(grid, masses, threads=2),
                                  distance_matrix(mesh, bumps, method="exact", threads=2)],
                           strict=True):
        assert np.array_equal(before.values, now.values) and now.converged
    single = wasserstein_distance(mesh, bumps[:, 1], bumps[:, 3], method="exact")
    assert _relative_gap(kept[1].values[1, 3], single.value) <= 1e-9


def test_w1_spectral_matrix_is_dwk_with_its_decision(woody):
    """metric="w1", method="spectral": the d_W^k matrix (values, certified gaps as the
    residuals, lower bounds), the decision recorded; "auto" keeps the interior point for a
    small collection and records why."""
    from solvers.emd.dwk_matrix import dwk_matrix

    mesh, wide = woody
    res = distance_matrix(mesh, wide, metric="w1", method="spectral", k=5)
    ref = dwk_matrix(mesh, wide, k=5)
    assert res.w1_matrix_method == "spectral" and res.k == 5 and "requested" in res.reason
    off = ~np.eye(5, dtype=bool)
    np.testing.assert_array_equal(res.values[off], ref.values[off])
    assert set(res.methods[off]) == {"spectral"} and set(np.diag(res.methods)) == {"identical"}
    assert np.all(res.lower[off] <= res.values[off]) and res.converged
    np.testing.assert_allclose(res.pair_residuals[off], ref.gaps[off])
    small = distance_matrix(mesh, wide[:, :3], metric="w1")
    assert small.w1_matrix_method == "interior_point" and small.k is None
    assert "estimated" in small.reason
    assert set(small.methods[np.triu_indices(3, 1)]) == {"w1"}
    upper = np.triu_indices(3, 1)
    assert np.all(small.lower[upper] <= small.values[upper])
    # d_W^k is an upper bound of W1: above the interior point's certified lower bounds
    assert np.all(res.values[:3, :3][upper] >= small.lower[upper])


def test_w1_method_and_k_refused_where_they_do_not_apply(woody):
    mesh, wide = woody
    for kwargs, name in (({"metric": "w2", "k": 5}, "k"),
                         ({"metric": "w1", "method": "exact"}, "method"),
                         ({"metric": "w2", "method": "spectral"}, "method"),
                         ({"metric": "w1", "method": "interior_point", "k": 5}, "k"),
                         ({"metric": "w1", "method": "spectral", "k": -2}, "k"),
                         ({"metric": "w1", "method": "spectral",
                           "w1_options": {"method": "admm"}}, "w1_options")):
        with pytest.raises(InputError) as err:
            distance_matrix(mesh, wide[:, :3], **kwargs)
        assert err.value.field == name, kwargs


def _merged(domain, A, B, blocks, **args) -> tuple[np.ndarray, int]:
    """The matrix from its row blocks (``rows=``), and the pairs the blocks solved."""
    merged = np.full((A.shape[1], (A if B is None else B).shape[1]), np.nan)
    solved = 0
    for block in blocks:
        res = distance_matrix(domain, A, B, rows=block, **args)
        rows = np.zeros(A.shape[1], bool)
        rows[block[0]:block[1]] = True
        if B is not None:  # templates: only the block's rows
            assert not res.computed[~rows].any() and res.computed[rows].all()
        merged[res.computed] = res.values[res.computed]
        upper = res.computed if B is not None else np.triu(res.computed)
        solved += int(np.count_nonzero(upper[rows]))
    return merged, solved


def _same(merged: np.ndarray, whole: np.ndarray, method: str) -> None:
    """Exact pairs: bit for bit.  Convolutional pairs on a mesh: the multi-column sparse
    solve rounds a column differently with other columns beside it (a pair's batch mates
    differ between a block and the whole matrix, as they differ between two orders of the
    same pairs): a few ulps per step, which the accelerated iteration carries to ~1e-11
    relative (measured), far below the solver's tolerance."""
    if method == "convolutional":
        np.testing.assert_allclose(merged, whole, rtol=1e-9, atol=0)
    else:
        assert np.array_equal(merged, whole)


@pytest.mark.parametrize("method", ["auto", "exact", "convolutional"])
def test_row_blocks_equal_the_whole_matrix(woody, method):
    """``rows=``: a block's entries are the whole call's (each pair decided as in the whole
    matrix; exact geodesic costs from the block's supports), and blocks are deterministic:
    the same block twice gives the same bits."""
    mesh, _ = woody
    rng = np.random.default_rng(3)
    A = np.zeros((mesh.n, 8))
    for k, size in enumerate([3, 3, 3, 12, 12, 12, 40, 40]):
        A[rng.choice(mesh.n, size, replace=False), k] = rng.random(size)
    args = {"method": method} if method != "convolutional" else {
        "method": method, "gamma": 0.01, "substeps": 4}
    whole = distance_matrix(mesh, A, **args)
    merged, solved = _merged(mesh, A, None, [(0, 3), (3, 5), (5, 8)], **args)
    _same(merged, whole.values, method)
    assert solved == int(np.count_nonzero(np.triu(whole.computed)))  # each pair once
    again, _ = _merged(mesh, A, None, [(0, 3), (3, 5), (5, 8)], **args)
    assert np.array_equal(again, merged)
    templates, solved = _merged(mesh, A, A[:, :3], [(0, 4), (4, 8)], **args)
    _same(templates, distance_matrix(mesh, A, A[:, :3], **args).values, method)
    assert solved == 24


def test_row_blocks_on_a_grid_are_bit_identical():
    """A grid's kernel applies column by column (exact log-domain convolution): blocks
    give the whole matrix's bits, convolutional pairs included."""
    grid = Grid((16, 16))
    rng = np.random.default_rng(5)
    A = rng.random((grid.n, 9)) * (rng.random((grid.n, 9)) < 0.3)
    args = {"gamma": 0.02, "substeps": 4, "debiased": True}
    whole = distance_matrix(grid, A, **args)
    merged, _ = _merged(grid, A, None, [(0, 2), (2, 6), (6, 9)], **args)
    assert np.array_equal(merged, whole.values)


def test_row_block_progress_and_refusals(woody):
    mesh, wide = woody
    seen = []
    res = distance_matrix(mesh, wide, gamma=0.01, substeps=8, debiased=True, rows=(3, 5),
                          progress=lambda done, worst, fraction: seen.append(fraction))
    assert seen[-1] == 1.0 and len(seen) == 1  # row 3: pair (3, 4); row 4: none
    assert res.computed[3, 4] and res.computed[4, 3] and not res.computed[0, 1]
    for rows in [(2, 2), (0, 6), (-1, 2), "ab"]:
        with pytest.raises(InputError) as err:
            distance_matrix(mesh, wide, gamma=0.01, rows=rows)
        assert err.value.field == "rows"
    with pytest.raises(InputError, match="w2"):
        distance_matrix(mesh, wide, metric="w1", rows=(0, 2))
