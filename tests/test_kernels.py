"""Heat kernels: the exact grid Gaussian against its closed form, log-domain application,
and the implicit-Euler kernel's algebra (against dense linear algebra on small systems)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from solvers.domains import Graph, Grid
from solvers.errors import InputError
from solvers.kernels import (
    GaussianGridHeatKernel,
    ImplicitEulerHeatKernel,
    heat_time,
)


def test_heat_time_matches_varadhan():
    """exp(-d^2 / gamma) is the R^d heat kernel's exponent exp(-d^2 / 4t) at t = gamma / 4."""
    gamma = 0.02
    t = heat_time(gamma)
    d = np.linspace(0, 0.3, 7)
    np.testing.assert_allclose(np.exp(-d**2 / (4 * t)), np.exp(-d**2 / gamma))


def test_gaussian_1d_delta_matches_closed_form():
    g = Grid((401,), bounds=[(-2.0, 2.0)])
    t = 0.01
    h = g.spacing[0]
    delta = np.zeros(g.n)
    delta[200] = 1.0
    y = g.heat_kernel(t).apply(delta)
    x = g.points[:, 0]
    np.testing.assert_allclose(y, h * (4 * np.pi * t) ** -0.5 * np.exp(-x**2 / (4 * t)),
                               rtol=1e-12, atol=1e-300)
    # Interior delta, sqrt(2t) >> h: the Riemann sum of the Gaussian is 1 to round-off,
    # so mass (a^T H x = a^T x) is conserved.
    assert g.areas @ y == pytest.approx(g.areas @ delta, rel=1e-12)


def test_gaussian_is_separable_and_symmetric_in_2d_and_3d():
    rng = np.random.default_rng(0)
    for shape in [(9, 12), (5, 6, 7)]:
        g = Grid(shape, bounds=[(0.0, 1.0)] * len(shape))
        t = 0.005
        kernel = g.heat_kernel(t)
        # Dense reference: product of 1-D factors = Gaussian of the Euclidean distance.
        d2 = ((g.points[:, None, :] - g.points[None, :, :]) ** 2).sum(-1)
        dense = np.prod(g.spacing) * (4 * np.pi * t) ** (-len(shape) / 2) * np.exp(-d2 / (4 * t))
        x = rng.random((g.n, 3))
        np.testing.assert_allclose(kernel.apply(x), dense @ x, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(kernel.apply(x[:, 1]), dense @ x[:, 1], rtol=1e-10)
        # Symmetric in the area-weighted inner product (uniform areas: plain symmetry).
        y = rng.random(g.n)
        assert y @ (g.areas * kernel.apply(x[:, 0])) == pytest.approx(
            x[:, 0] @ (g.areas * kernel.apply(y)), rel=1e-12)


def test_gaussian_periodic_axis_wraps():
    n = 20
    g = Grid((n,), bounds=[(0.0, 1.0)], periodic=True)
    delta = np.zeros(n)
    delta[0] = 1.0
    y = g.heat_kernel(0.002).apply(delta)
    # Node n-1 is one step from node 0 through the wrap: same value as node 1.
    assert y[n - 1] == pytest.approx(y[1], rel=1e-12)
    assert y[n - 2] == pytest.approx(y[2], rel=1e-12)
    non_periodic = Grid((n,), bounds=[(0.0, 1.0 - 1.0 / n)]).heat_kernel(0.002).apply(delta)
    assert non_periodic[n - 1] < 1e-12 * y[n - 1]


def test_log_apply_equals_log_of_apply_where_finite():
    rng = np.random.default_rng(1)
    g = Grid((13, 10), bounds=[(0.0, 1.0), (0.0, 2.0)], periodic=[False, True])
    kernel = g.heat_kernel(0.003)
    assert kernel.supports_log
    log_x = rng.normal(scale=3.0, size=(g.n, 4))
    expected = np.log(kernel.apply(np.exp(log_x)))
    np.testing.assert_allclose(kernel.log_apply(log_x), expected, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(kernel.log_apply(log_x[:, 2]), expected[:, 2], rtol=1e-10,
                               atol=1e-10)


def test_log_apply_is_finite_where_apply_underflows():
    """Tiny t and very negative log-inputs: exp underflows to 0, log_apply does not."""
    g = Grid((50,), bounds=[(0.0, 1.0)])
    t = 1e-5  # kernel between neighbours ~exp(-h^2/4t) = exp(-10); across the grid e^-25000
    kernel = GaussianGridHeatKernel(g, t)
    log_x = np.full(g.n, -800.0)
    log_x[10] = -790.0
    with np.errstate(divide="ignore"):
        naive = np.log(kernel.apply(np.exp(log_x)))
    assert np.all(np.isneginf(naive))
    out = kernel.log_apply(log_x)
    assert np.all(np.isfinite(out))
    # Closed form: log sum_j K_ij exp(x_j), with log K from the Gaussian formula.
    x = g.points[:, 0]
    h = g.spacing[0]
    log_k = np.log(h) - 0.5 * np.log(4 * np.pi * t) - (x[:, None] - x[None, :]) ** 2 / (4 * t)
    terms = log_k + log_x[None, :]
    top = terms.max(axis=1)
    reference = top + np.log(np.exp(terms - top[:, None]).sum(axis=1))
    np.testing.assert_allclose(out, reference, rtol=1e-12)
    # -inf inputs (zero mass) are allowed; one finite entry reaches every node (log K > -inf).
    with np.errstate(divide="ignore"):
        zero_mass = kernel.log_apply(np.log(np.eye(g.n)[:, 0] + 0.0))
    assert np.isfinite(zero_mass).all()


def test_implicit_euler_matches_dense_inverse_and_substeps():
    rng = np.random.default_rng(2)
    n = 30
    w = sp.random(n, n, density=0.2, random_state=3)
    w = w + w.T
    lap = sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w
    mass = rng.random(n) + 0.1
    t = 0.3
    dense = np.linalg.solve(np.diag(mass) + t * lap.toarray(), np.diag(mass))
    x = rng.random((n, 5))
    one = ImplicitEulerHeatKernel(mass, lap, t)
    np.testing.assert_allclose(one.apply(x), dense @ x, rtol=1e-10)
    step = np.linalg.solve(np.diag(mass) + (t / 3) * lap.toarray(), np.diag(mass))
    three = ImplicitEulerHeatKernel(mass, lap, t, substeps=3)
    np.testing.assert_allclose(three.apply(x), np.linalg.matrix_power(step, 3) @ x, rtol=1e-10)
    assert not one.supports_log
    with pytest.raises(NotImplementedError):
        one.log_apply(x)


@pytest.mark.parametrize(("t", "substeps"), [(0.0, 1), (-1.0, 1), (np.nan, 1), (1.0, 0)])
def test_invalid_heat_times_are_refused(t, substeps):
    field = "t" if substeps == 1 else "substeps"
    lap = sp.csr_matrix(np.array([[1.0, -1.0], [-1.0, 1.0]]))
    with pytest.raises(InputError) as info:
        ImplicitEulerHeatKernel(np.ones(2), lap, t, substeps)
    assert info.value.field == field
    graph = Graph(2, [[0, 1]])
    with pytest.raises(InputError) as info:
        graph.heat_kernel(t, substeps=substeps)
    assert info.value.field == field
    if substeps == 1:
        with pytest.raises(InputError) as info:
            GaussianGridHeatKernel(Grid((4,)), t)
        assert info.value.field == "t"
