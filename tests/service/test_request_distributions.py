"""Distribution inputs: full vectors, sparse masses, bumps, densities; normalization report."""

from __future__ import annotations

import numpy as np
import pytest

from service.errors import InvalidInput
from service.operations.base import (
    BumpDistribution,
    SparseDistribution,
    resolve_distribution,
    view_of_domain,
)
from solvers.domains import Graph, Grid


def test_bump_on_grid_matches_brute_force():
    grid = Grid((15, 11), bounds=[(0, 2), (0, 1)])
    view = view_of_domain(grid)
    masses, report = resolve_distribution(view, BumpDistribution(vertex=40, radius=0.35), "mu")
    d = np.linalg.norm(grid.points - grid.points[40], axis=1)
    expected = grid.areas * np.clip(1 - d / 0.35, 0, None)
    assert np.allclose(masses, expected / expected.sum(), rtol=1e-12, atol=0)
    assert report["given_total"] == pytest.approx(expected.sum())
    assert report["normalized"] and report["scale"] == pytest.approx(1 / expected.sum())
    # The k-d tree is memoized on the domain: a second bump reuses it.
    tree = view.memo["tree"]
    assert view_of_domain(grid).memo["tree"] is tree


def test_bump_memo_returns_independent_copies_and_stays_bounded(monkeypatch):
    import service.operations.base as base

    grid = Grid((15, 11), bounds=[(0, 2), (0, 1)])

    def bump(vertex, radius, field="mu"):
        return resolve_distribution(view_of_domain(grid), BumpDistribution(vertex=vertex,
                                                                           radius=radius), field)

    first, report = bump(40, 0.35, "mu0")
    expected = first.copy()
    first[:] = -1.0  # callers own their array: the memo is not affected
    again, report2 = bump(40, 0.35, "mu1")
    assert np.array_equal(again, expected) and again is not first
    assert report2["field"] == "mu1" and report2["given_total"] == report["given_total"]
    # a different radius is a different bump
    wider, _ = bump(40, 0.5)
    assert np.count_nonzero(wider) > np.count_nonzero(expected)
    # bounded by bytes: room for 2 vectors of this domain, the oldest is dropped
    monkeypatch.setattr(base, "BUMP_MEMO_BYTES", 2 * 8 * grid.n)
    for v in (1, 2, 3):
        bump(v, 0.3)
    assert list(view_of_domain(grid).memo["bumps"]) == [(2, 0.3), (3, 0.3)]
    with pytest.raises(InvalidInput):  # errors are raised every time, never memoized
        bump(grid.n, 1.0)


def test_bump_on_graph_counts_hops():
    graph = Graph(6, [[0, 1], [1, 2], [2, 3], [3, 4], [4, 5]])
    masses, _ = resolve_distribution(view_of_domain(graph), BumpDistribution(vertex=2, radius=2),
                                     "mu")
    weights = np.array([0, 0.5, 1, 0.5, 0, 0])
    assert np.allclose(masses, weights / weights.sum())


def test_sparse_repeated_indices_add_and_density_input():
    grid = Grid((4, 4), bounds=[(0, 1), (0, 2)])
    view = view_of_domain(grid)
    masses, report = resolve_distribution(
        view, SparseDistribution(indices=[3, 3, 7], masses=[1.0, 2.0, 1.0]), "mu")
    assert masses[3] == pytest.approx(0.75) and masses[7] == pytest.approx(0.25)
    assert report["given_total"] == pytest.approx(4.0)
    density = np.full(16, 2.0)  # a^T mu = 2 with a = 1/16
    masses, report = resolve_distribution(view, density.tolist(), "mu", input_kind="density")
    assert np.allclose(masses, grid.areas) and report["given_total"] == pytest.approx(2.0)
    unnormalized, report = resolve_distribution(view, (grid.areas * 1.0).tolist(), "mu")
    assert not report["normalized"] and np.allclose(unnormalized, grid.areas)


@pytest.mark.parametrize("spec,field", [
    ([1.0] * 15, "mu"),
    ([1.0] * 15 + [float("inf")], "mu"),
    ([0.0] * 16, "mu"),
    (SparseDistribution(indices=[0, 16], masses=[1, 1]), "mu.indices"),
    (SparseDistribution(indices=[0, -1], masses=[1, 1]), "mu.indices"),
    (SparseDistribution(indices=[0, 1], masses=[1, -1]), "mu.masses"),
    (SparseDistribution(indices=[0, 1], masses=[1]), "mu.masses"),
    (BumpDistribution(vertex=16, radius=1), "mu.vertex"),
])
def test_invalid_distributions_name_the_field(spec, field):
    view = view_of_domain(Grid((4, 4)))
    with pytest.raises((InvalidInput, ValueError)) as info:
        resolve_distribution(view, spec, "mu")
    assert info.value.field == field
