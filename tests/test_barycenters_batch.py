"""Batched barycenters: a grid of weight vectors as one block, equal to single calls."""

from __future__ import annotations

import numpy as np
import pytest

from solvers import Grid
from solvers.convolutional import barycenter, barycenters
from solvers.errors import CancelledError, InputError


def _gaussians(grid: Grid, centers) -> np.ndarray:
    pts = np.asarray(grid.points)
    cols = [np.exp(-np.sum((pts - c) ** 2, axis=1) / 0.01) for c in centers]
    return np.stack([c / c.sum() for c in cols], axis=1)


@pytest.fixture(scope="module")
def inputs():
    grid = Grid((24, 24))
    lo, hi = grid.bounds[:, 0], grid.bounds[:, 1]
    centers = [lo + f * (hi - lo) for f in ((0.25, 0.25), (0.75, 0.3), (0.5, 0.75))]
    return grid, _gaussians(grid, centers)


ALPHAS = np.array([[1.0, 0.0, 0.0], [0.5, 0.5, 0.0], [0.2, 0.3, 0.5], [1 / 3, 1 / 3, 1 / 3],
                   [0.0, 0.25, 0.75]])


@pytest.mark.parametrize("options", [{}, {"gamma": 0.004, "debiased": True},
                                     {"gamma": 0.004, "sharpen": True}])
def test_batch_equals_single_barycenters(inputs, options):
    grid, mus = inputs
    batch = barycenters(grid, mus, ALPHAS, **options)
    assert batch.masses.shape == (grid.n, len(ALPHAS)) and batch.converged
    for b, w in enumerate(ALPHAS):
        single = barycenter(grid, mus, w, **options)
        gap = np.abs(batch.masses[:, b] - single.masses).sum()
        assert gap <= 1e-6, (b, gap)
        assert batch.problem_iterations[b] == single.iterations
        assert batch.problem_residuals[b] == pytest.approx(single.residual, rel=1e-6, abs=1e-12)
        assert batch.entropies[b] == pytest.approx(single.entropy, rel=1e-9)
    assert batch.iterations == batch.problem_iterations.sum()
    # Distinct weights give distinct barycenters (the block does not mix problems).
    assert np.abs(batch.masses[:, 1] - batch.masses[:, 2]).sum() > 1e-2


def test_batch_progress_cancel_and_errors(inputs):
    grid, mus = inputs
    seen = []
    barycenters(grid, mus, ALPHAS[:3], gamma=0.004, progress=lambda d, w: seen.append(d))
    assert seen == [1, 2, 3]
    with pytest.raises(CancelledError):
        barycenters(grid, mus, ALPHAS, gamma=0.004, should_cancel=lambda: True)
    with pytest.raises(InputError) as info:
        barycenters(grid, mus, [[1.0, 0.0]])
    assert info.value.field == "weights"
    with pytest.raises(InputError):
        barycenters(grid, mus, [[1.0, -1.0, 0.5]])
    with pytest.raises(InputError) as info:
        barycenters(grid, mus, ALPHAS, block=0)
    assert info.value.field == "block"


@pytest.mark.parametrize("options", [{"gamma": 0.004}, {"gamma": 0.004, "debiased": True}])
def test_block_size_does_not_change_results(inputs, options):
    # One problem per block, a few, and all in one block: the same masses, iterations and
    # residuals (each problem's arithmetic is its own; the block only shares kernel solves).
    grid, mus = inputs
    runs = [barycenters(grid, mus, ALPHAS, block=b, **options) for b in (1, 2, len(ALPHAS))]
    default = barycenters(grid, mus, ALPHAS, **options)
    for other in runs[1:] + [default]:
        assert np.abs(other.masses - runs[0].masses).sum(axis=0).max() <= 1e-12
        np.testing.assert_array_equal(other.problem_iterations, runs[0].problem_iterations)
        np.testing.assert_allclose(other.problem_residuals, runs[0].problem_residuals,
                                   rtol=1e-9, atol=1e-15)
