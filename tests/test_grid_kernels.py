"""GaussianGridHeatKernel: fast apply/log_apply against dense and exact log-sum-exp references."""

from __future__ import annotations

import numpy as np
import pytest

from solvers import Grid
from solvers.kernels import _LOG_SPREAD, _stabilized_row_blocks


def dense_kernel(kernel) -> np.ndarray:
    """The full n×n kernel matrix as the Kronecker product of the per-axis factors."""
    dense = np.ones((1, 1))
    for factor in kernel.factors:
        dense = np.kron(dense, factor)
    return dense


def wild_logs(grid: Grid, n_cols: int, scale: float, rng) -> np.ndarray:
    """Log-domain inputs spanning thousands of nats, with -inf entries (zero mass)."""
    pts = grid.points
    cols = []
    for _ in range(n_cols):
        center = rng.random(grid.ndim)
        cols.append(-scale * ((pts - center) ** 2).sum(axis=1) + 50 * rng.normal(size=grid.n))
    logs = np.stack(cols, axis=1)
    logs[rng.random(grid.n) < 0.2, 0] = -np.inf
    return logs


def assert_log_close(fast, exact):
    finite = np.isfinite(exact)
    np.testing.assert_array_equal(np.isfinite(fast), finite)
    np.testing.assert_array_equal(fast[~finite], exact[~finite])
    err = np.abs(fast[finite] - exact[finite]) / np.maximum(1.0, np.abs(exact[finite]))
    assert err.max() < 1e-12


@pytest.mark.parametrize(
    "shape, periodic, t",
    [
        ((24, 20), False, 1e-3),  # one stabilized block per axis (gamma = 0.004)
        ((24, 20), False, 2e-5),  # tiny t: many row blocks per axis
        ((10, 9, 8), (True, False, True), 3e-4),
        ((50,), True, 1e-6),  # kernel far below float64 range off the diagonal
    ],
)
def test_log_apply_matches_exact_logsumexp(shape, periodic, t):
    rng = np.random.default_rng(1)
    grid = Grid(shape, periodic=periodic)
    kernel = grid.heat_kernel(t)
    logs = wild_logs(grid, 3, scale=1.0 / (4 * t), rng=rng)
    assert_log_close(kernel.log_apply(logs), kernel.log_apply_exact(logs))
    # and against the dense definition, entry by entry
    dense_log = np.log(dense_kernel(kernel)) if t >= 1e-3 else None
    if dense_log is not None:
        from scipy.special import logsumexp

        brute = logsumexp(dense_log[:, :, None] + logs[None, :, :], axis=1)
        assert_log_close(kernel.log_apply(logs), brute)


def test_log_apply_exact_where_naive_exp_fails():
    """Small t and potentials of size 1/t: exp under/overflows, the shifted BLAS path does not."""
    rng = np.random.default_rng(2)
    grid = Grid((32, 32))
    t = 2e-4
    kernel = grid.heat_kernel(t)
    logs = wild_logs(grid, 2, scale=1.0 / (2 * t), rng=rng)
    logs[:, 1] += 900.0  # exp overflows
    with np.errstate(all="ignore"):
        naive = np.log(kernel.apply(np.exp(logs)))
    exact = kernel.log_apply_exact(logs)
    assert not np.allclose(naive[np.isfinite(exact)], exact[np.isfinite(exact)], rtol=1e-6)
    assert np.ptp(exact[np.isfinite(exact)]) > 1500  # beyond float64 exp range (~1454)
    assert_log_close(kernel.log_apply(logs), exact)


def test_log_apply_agrees_with_apply_in_range():
    rng = np.random.default_rng(3)
    grid = Grid((16, 12, 6), periodic=(False, True, False))
    kernel = grid.heat_kernel(5e-3)
    x = rng.random((grid.n, 4)) + 1e-3
    np.testing.assert_allclose(kernel.log_apply(np.log(x)), np.log(kernel.apply(x)), rtol=1e-13)


def test_all_minus_inf_column_gives_minus_inf():
    grid = Grid((8, 9))
    kernel = grid.heat_kernel(1e-3)
    logs = np.zeros((grid.n, 2))
    logs[:, 0] = -np.inf
    out = kernel.log_apply(logs)
    assert np.all(out[:, 0] == -np.inf) and np.all(np.isfinite(out[:, 1]))


@pytest.mark.parametrize("shape, periodic", [((7,), False), ((9, 8), True), ((5, 6, 4), False)])
def test_apply_is_the_dense_kronecker_kernel(shape, periodic):
    rng = np.random.default_rng(4)
    grid = Grid(shape, periodic=periodic)
    kernel = grid.heat_kernel(0.01)
    dense = dense_kernel(kernel)
    np.testing.assert_allclose(dense, dense.T)
    x = rng.random((grid.n, 3))
    np.testing.assert_allclose(kernel.apply(x), dense @ x, rtol=1e-13)
    np.testing.assert_allclose(kernel.apply(x[:, 1]), dense @ x[:, 1], rtol=1e-13)


def test_apply_matches_pot_image_convolution():
    """Same Gaussian as POT's convolutional barycenter (reg = 4t), up to the cell factor."""
    from ot.backend import get_backend
    from ot.bregman._convolutional import _get_convol_img_fn

    rng = np.random.default_rng(5)
    grid = Grid((20, 20))
    reg = 0.004
    kernel = grid.heat_kernel(reg / 4)
    images = rng.random((4, 20, 20))
    convolve = _get_convol_img_fn(get_backend(images), 20, 20, reg, type_as=images)
    cell = kernel.factors[0][0, 0] * kernel.factors[1][0, 0]  # h^2 / (4 pi t)
    ours = kernel.apply(images.reshape(4, -1).T).T.reshape(4, 20, 20)
    np.testing.assert_allclose(ours, cell * convolve(images), rtol=1e-13)


@pytest.mark.parametrize("layout", ["C", "F", "vector"])
def test_inputs_are_not_modified(layout):
    rng = np.random.default_rng(6)
    grid = Grid((10, 11))
    kernel = grid.heat_kernel(1e-3)
    logs = rng.normal(size=(grid.n, 3)) * 100
    logs = {"C": logs, "F": np.asfortranarray(logs), "vector": logs[:, 0].copy()}[layout]
    before = logs.copy()
    out = kernel.log_apply(logs)
    kernel.apply(np.exp(logs / 100))
    np.testing.assert_array_equal(logs, before)
    assert out.shape == logs.shape
    assert_log_close(out, kernel.log_apply_exact(logs))
    with pytest.raises(ValueError):
        kernel.apply(np.ones(grid.n + 1))


def test_row_blocks_bound_the_log_spread():
    grid = Grid((300,))
    for t, expect_single in ((1e-3, True), (1e-5, False)):
        log_k = grid.heat_kernel(t).log_factors[0]
        blocks = _stabilized_row_blocks(log_k)
        assert (len(blocks) == 1) == expect_single
        assert blocks[0][0] == 0 and blocks[-1][1] == 300
        for (start, stop, shift, scaled, width), nxt in zip(blocks, blocks[1:] + [None],
                                                            strict=True):
            assert nxt is None or nxt[0] == stop
            rows = log_k[start:stop]
            assert np.max(rows.max(axis=0) - rows.min(axis=0)) == width <= _LOG_SPREAD
            np.testing.assert_allclose(np.log(scaled) + shift - width, rows, atol=1e-9)
            # kernel entries in [1, e^width]: products with normal inputs stay normal
            assert scaled.min() >= 1 - 1e-12 and scaled.max() <= np.exp(width) * (1 + 1e-12)


def test_kernel_factors_have_no_subnormal_entries():
    """Subnormal operands slow BLAS 5-10x; entries below the normal range are flushed to 0."""
    tiny = np.finfo(float).tiny
    kernel = Grid((200,)).heat_kernel(1e-4)  # exp(-d^2/4t) reaches e^-2500
    factor = kernel.factors[0]
    assert np.any(factor == 0.0)
    assert not np.any((factor > 0) & (factor < tiny))
    log_k = kernel.log_factors[0]
    np.testing.assert_array_equal(factor == 0.0, log_k < np.log(tiny))
