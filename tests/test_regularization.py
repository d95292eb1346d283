"""The regularization policy (solvers.regularization) and stagnation stops."""

from __future__ import annotations

import numpy as np
import ot
import pytest

from solvers import Grid
from solvers.convolutional import barycenter, wasserstein_distance
from solvers.errors import InputError
from solvers.geodesics import geodesic_distances
from solvers.regularization import (
    MAX_SUBSTEPS,
    VALUE_FACTOR,
    VALUE_SUBSTEPS,
    choose_regularization,
    shape_regularization,
    transport_distance_estimate,
    value_substeps,
)


def _dirac(n, i):
    m = np.zeros(n)
    m[i] = 1.0
    return m


def test_grid_diracs_estimate_is_their_distance():
    grid = Grid((32, 32))
    i, j = 3 * 32 + 4, 20 * 32 + 25  # (3, 4) and (20, 25) in index units
    d = float(np.linalg.norm(grid.points[i] - grid.points[j]))
    m0, m1 = _dirac(grid.n, i), _dirac(grid.n, j)
    assert transport_distance_estimate(grid, m0, m1) == pytest.approx(d, rel=1e-12)
    reg = choose_regularization(grid, m0, m1, purpose="values")
    h = max(grid.spacing)
    assert reg.gamma == pytest.approx(VALUE_FACTOR * h * d) and reg.t == pytest.approx(
        reg.gamma / 4)
    assert reg.debiased and reg.substeps == 1 and reg.distance == pytest.approx(d)
    shapes = choose_regularization(grid, purpose="shapes")
    assert shapes.gamma == pytest.approx((2 * h) ** 2) and not shapes.debiased


def test_explicit_arguments_win_and_bad_ones_are_refused():
    grid = Grid((8, 8))
    m = np.full(grid.n, 1.0 / grid.n)
    reg = choose_regularization(grid, m, m, gamma=0.3, substeps=5, debiased=False)
    assert (reg.gamma, reg.substeps, reg.debiased) == (0.3, 5, False)
    assert shape_regularization(grid, 0.2, None, None)[1:] == (0.2, 1)
    with pytest.raises(InputError) as err:
        choose_regularization(grid, m, m, purpose="speed")
    assert err.value.field == "purpose"
    with pytest.raises(InputError) as err:
        choose_regularization(grid, purpose="values")  # auto gamma needs the inputs
    assert err.value.field == "gamma"


class _Big:
    kind, n = "mesh", 50_000


def test_substeps_follow_distance_and_fit_the_budget():
    small = type("Small", (), {"kind": "mesh", "n": 1000})()
    near, _ = value_substeps(small, 0.1, 0.25 * VALUE_FACTOR * 0.02 * 0.1)
    far, _ = value_substeps(small, 1.5, 0.25 * VALUE_FACTOR * 0.02 * 1.5)
    assert near == VALUE_SUBSTEPS and VALUE_SUBSTEPS < far <= MAX_SUBSTEPS
    assert far & (far - 1) == 0  # a power of two
    big, why = value_substeps(_Big(), 1.5, 0.25 * VALUE_FACTOR * 0.005 * 1.5)
    assert big < MAX_SUBSTEPS and "budget" in why


def test_estimate_close_to_the_lp_on_woody(shared_mesh):
    mesh = shared_mesh("woody.obj")

    def bump(i):
        d = np.linalg.norm(mesh.vertices - mesh.vertices[i], axis=1)
        m = mesh.areas * np.clip(1 - d / 0.1, 0, None)
        return m / m.sum()

    m0, m1 = bump(0), bump(500)
    s0, s1 = np.flatnonzero(m0), np.flatnonzero(m1)
    lp = ot.emd2(m0[s0], m1[s1], geodesic_distances(mesh, s0, s1) ** 2)
    est = transport_distance_estimate(mesh, m0, m1)
    assert est == pytest.approx(np.sqrt(lp), rel=0.10)
    res = wasserstein_distance(mesh, m0, m1, method="convolutional")
    assert res.regularization is not None and res.regularization.distance == pytest.approx(est)
    assert res.debiased and res.substeps == res.regularization.substeps >= VALUE_SUBSTEPS


def test_unreachable_tolerance_stops_as_stalled():
    """A tolerance below float precision: the residual stops falling, the loop stops long
    before max_iter and says so (converged False, measured residual)."""
    grid = Grid((24, 24))
    x = np.linspace(0, 1, grid.n)
    m0, m1 = 1.0 + x, 2.0 - x
    res = wasserstein_distance(grid, m0, m1, gamma=0.05, tol=1e-300, max_iter=50_000)
    assert not res.converged and res.iterations < 2000
    assert 0 < res.residual < 1e-10
    # The debiased barycenter's sublinear tail (the runaway at tol 1e-9): with the
    # default cap it stops once tol is out of reach at the measured rate.
    bary = barycenter(grid, np.stack([m0, m1], 1), gamma=0.05, debiased=True, tol=1e-9)
    assert not bary.converged and bary.iterations < 1000 and 1e-9 < bary.residual < 1e-4


def test_long_pointwise_runs_are_refused_up_front(shared_mesh):
    """A d_W^k run estimated above the limit is refused before it starts, naming the limit
    and the faster option; a small target set still runs."""
    from solvers.emd import pointwise_distances
    from solvers.emd.pointwise import estimate_seconds

    mesh = shared_mesh("spot.obj")
    limit = estimate_seconds(mesh.n, mesh.n_faces, 50, mesh.n, False) / 2
    with pytest.raises(InputError) as err:
        pointwise_distances(mesh, 0, k=50, max_seconds=limit)
    assert err.value.field == "k" and f"{limit:.0f} s" in str(err.value)
    assert "smaller k" in str(err.value)
    res = pointwise_distances(mesh, 0, k=4, targets=np.arange(1, 9))
    assert res.converged and np.all(res.distances > 0)
