"""Grid: node layout, finite-difference Laplacian against exact derivatives, periodicity."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from solvers.domains import Grid, domain_from_arrays
from solvers.errors import DomainError


def test_nodes_follow_linspace_and_c_order():
    g = Grid((4, 3), bounds=[(0.0, 3.0), (-1.0, 1.0)])
    np.testing.assert_allclose(g.axis_coordinates[0], np.linspace(0, 3, 4))
    np.testing.assert_allclose(g.axis_coordinates[1], np.linspace(-1, 1, 3))
    assert g.spacing == pytest.approx((1.0, 1.0))
    img = np.arange(12.0).reshape(4, 3)
    # Flattened index of node (i, j) is i * 3 + j (C order): img.ravel() is the vector.
    i, j = 2, 1
    np.testing.assert_allclose(g.points[i * 3 + j], [2.0, 0.0])
    assert img.ravel()[i * 3 + j] == img[i, j]
    assert g.n == 12 and g.ndim == 2
    np.testing.assert_allclose(g.areas, 1 / 12)
    json.dumps(g.summary())


def test_periodic_axis_spacing_excludes_endpoint():
    g = Grid((8,), bounds=[(0.0, 2 * np.pi)], periodic=True)
    np.testing.assert_allclose(g.axis_coordinates[0], 2 * np.pi * np.arange(8) / 8)
    assert g.spacing[0] == pytest.approx(2 * np.pi / 8)


@pytest.mark.parametrize("shape", [(7,), (5, 6), (4, 3, 5)])
@pytest.mark.parametrize("periodic", [False, True])
def test_laplacian_symmetric_psd_kills_constants(shape, periodic):
    g = Grid(shape, periodic=periodic)
    lap = g.laplacian
    assert abs(lap - lap.T).max() < 1e-12
    np.testing.assert_allclose(lap @ np.ones(g.n), 0, atol=1e-9)
    eig = np.linalg.eigvalsh(lap.toarray())
    assert eig[0] > -1e-9 * eig[-1] and abs(eig[0]) < 1e-9 * eig[-1]
    assert eig[1] > 1e-6 * eig[-1]  # connected: constants are the only null vectors
    assert connected_components(lap, directed=False)[0] == 1


def test_laplacian_is_finite_differences_on_quadratic():
    """-Delta of x^2 + 2 y^2 - x y is -6, and central differences are exact on quadratics."""
    g = Grid((9, 11), bounds=[(-1.0, 2.0), (0.0, 1.5)])
    x, y = g.points.T
    f = x**2 + 2 * y**2 - x * y
    strong = -(g.laplacian @ f) * g.n  # weak form is (1/N)(-Delta_h)
    interior = np.ones(g.shape, dtype=bool)
    interior[[0, -1], :] = False
    interior[:, [0, -1]] = False
    np.testing.assert_allclose(strong[interior.ravel()], 6.0, rtol=1e-9)
    # Boundary rows are one-sided (Neumann): not the interior value.
    assert not np.allclose(strong[~interior.ravel()], 6.0)


def test_periodic_laplacian_wraps_fourier_modes():
    """On a periodic axis cos(2 pi k x / P) is an exact eigenvector of the FD Laplacian,
    eigenvalue (2 - 2 cos(2 pi k / n)) / h^2, including at the wrapped ends."""
    n, period, k = 16, 3.0, 3
    g = Grid((n, 5), bounds=[(0.0, period), (0.0, 1.0)], periodic=[True, False])
    x = g.points[:, 0]
    f = np.cos(2 * np.pi * k * x / period)
    h = period / n
    eigen = (2 - 2 * np.cos(2 * np.pi * k / n)) / h**2
    np.testing.assert_allclose(g.laplacian @ f * g.n, eigen * f, atol=1e-9 * eigen)
    # The same mode on a non-periodic axis is not an eigenvector at the ends.
    open_grid = Grid((n, 5), bounds=[(0.0, period - h), (0.0, 1.0)])
    residual = open_grid.laplacian @ f * g.n - eigen * f
    assert np.abs(residual).max() > 1e-3 * eigen


def test_implicit_grid_kernel_converges_to_gaussian_with_substeps():
    g = Grid((201,), bounds=[(-1.0, 1.0)])
    delta = np.zeros(g.n)
    delta[100] = 1.0
    exact = g.heat_kernel(0.01).apply(delta)
    errors = []
    for substeps in (1, 10, 100):
        approx = g.heat_kernel(0.01, substeps=substeps, kernel="implicit").apply(delta)
        assert approx.min() >= 0
        assert g.areas @ approx == pytest.approx(g.areas @ delta, rel=1e-12)
        errors.append(np.abs(approx - exact).max() / exact.max())
    # Measured 0.77, 0.040, 0.0044: first order in the step once steps are small.
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-2 and errors[1] / errors[2] > 5


def test_heat_kernel_is_cached_and_validates_kind():
    g = Grid((6, 6))
    assert g.heat_kernel(0.01) is g.heat_kernel(0.01)
    assert g.heat_kernel(0.01) is not g.heat_kernel(0.01, kernel="implicit")
    with pytest.raises(DomainError) as info:
        g.heat_kernel(0.01, kernel="fft")
    assert info.value.field == "kernel"


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"shape": (1, 4)}, "shape"),
        ({"shape": (2, 2, 2, 2)}, "shape"),
        ({"shape": ("a", 3)}, "shape"),
        ({"shape": (3, 3), "bounds": [(0, 1)]}, "bounds"),
        ({"shape": (3,), "bounds": [(1, 0)]}, "bounds"),
        ({"shape": (3,), "bounds": [(0, np.nan)]}, "bounds"),
        ({"shape": (3, 3), "periodic": [True]}, "periodic"),
    ],
)
def test_invalid_grids_raise_typed_errors(kwargs, field):
    with pytest.raises(DomainError) as info:
        Grid(**kwargs)
    assert info.value.field == field


def test_round_trip_through_arrays_keeps_hash():
    g = Grid((5, 7), bounds=[(0.0, 1.0), (-2.0, 2.0)], periodic=[False, True])
    rebuilt = domain_from_arrays("grid", g.to_arrays(), g.parameters())
    assert rebuilt.content_hash() == g.content_hash()
    assert rebuilt.periodic == g.periodic and rebuilt.shape == g.shape
    assert Grid((5, 7)).content_hash() != g.content_hash()
