"""d_W^k matrices (thesis §2.5): one-to-all d_W^k on Diracs, bounds against W1, monotone in k."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from shared_meshes import hat_bump as _bump
from shared_meshes import load_shared_mesh

from solvers.emd import earth_movers_distance, pointwise_distances
from solvers.emd.dwk_matrix import (
    decide_w1_method,
    default_k,
    dwk_matrix,
    estimate_seconds,
    working_bytes,
)
from solvers.errors import CancelledError, InputError


@pytest.fixture(scope="module")
def woody():
    mesh = load_shared_mesh("woody.obj")
    rng = np.random.default_rng(3)
    centres = rng.choice(mesh.n, 5, replace=False)
    radii = rng.uniform(0.1, 0.25, 5)
    bumps = np.stack([_bump(mesh, int(c), float(r)) for c, r in zip(centres, radii,
                                                                       strict=True)], axis=1)
    return mesh, bumps


def _overlap(lo_a, up_a, lo_b, up_b, slack=1e-6):
    """Certified intervals [lo, up] of the same quantity must intersect."""
    return np.all(lo_a <= up_b * (1 + slack)) and np.all(lo_b <= up_a * (1 + slack))


@pytest.mark.parametrize("k", [0, 5])
def test_dirac_entries_equal_one_to_all(woody, k):
    mesh, _ = woody
    idx = np.array([3, 50, 200, 400, 650])
    diracs = np.zeros((mesh.n, len(idx)))
    diracs[idx, np.arange(len(idx))] = 1.0
    res = dwk_matrix(mesh, diracs, k=k)
    assert res.k == k and res.method == "spectral" and res.converged
    assert np.all(np.diag(res.values) == 0) and np.allclose(res.values, res.values.T)
    for a, source in enumerate(idx):
        one = pointwise_distances(mesh, int(source), k=k, targets=idx)
        if k == 0:  # direct evaluations both, float32 rounding apart
            np.testing.assert_allclose(res.values[a], one.distances, rtol=1e-5, atol=1e-9)
        else:
            assert _overlap(res.lower[a], res.values[a], one.lower_bounds, one.distances)


def test_entries_bound_interior_point_w1(woody):
    """d_W^k >= W1 for every k: each certified d_W^k value lies above the certified
    interior-point lower bound; k = 0 needs no optimization and is above it too."""
    mesh, bumps = woody
    ipm = {(i, j): earth_movers_distance(mesh, bumps[:, i], bumps[:, j])
           for i in range(5) for j in range(i + 1, 5)}
    for k in (0, 10, 40):
        res = dwk_matrix(mesh, bumps, k=k)
        for (i, j), w1 in ipm.items():
            assert w1.converged
            assert res.values[i, j] >= w1.lower_bound
            assert res.values[i, j] == res.values[j, i]


def test_entries_match_single_pair_spectral_w1(woody):
    """The embedding is eq. 2.4's particular flow: a pair's entry is the single-pair W1 over
    the same spectral basis (ADMM, its own tolerance) within the certified gap."""
    mesh, bumps = woody
    res = dwk_matrix(mesh, bumps, k=10, tol=1e-4, max_iter=20000)
    for i, j in ((0, 1), (2, 4)):
        single = earth_movers_distance(mesh, bumps[:, i], bumps[:, j], method="admm",
                                       basis="spectral", k=10, tol=1e-6, max_iter=20000)
        assert abs(single.value - res.values[i, j]) <= 2e-3 * res.values[i, j]


def test_monotone_in_k(woody):
    mesh, bumps = woody
    previous = None
    for k in (0, 5, 20, 50):
        res = dwk_matrix(mesh, bumps, k=k)
        assert res.converged and res.k == k
        if previous is not None:
            # true d^k <= values_k and d^k >= lower_k: nested subspaces give
            # lower_k <= d^k <= d^{k'} <= values_{k'} (k > k')
            assert np.all(res.lower <= previous.values * (1 + 1e-6))
            assert np.all(res.values <= previous.values * (1 + 2 * res.tol))
        previous = res
    assert np.all(previous.values[~np.eye(5, dtype=bool)] > 0)


def test_rows_and_columns_select_entries(woody):
    mesh, bumps = woody
    full = dwk_matrix(mesh, bumps, k=0)
    part = dwk_matrix(mesh, bumps, k=0, rows=[4, 1], columns=[0, 2, 3])
    np.testing.assert_allclose(part.values, full.values[np.ix_([4, 1], [0, 2, 3])],
                               rtol=1e-6)
    other = dwk_matrix(mesh, bumps[:, :2], bumps[:, 2:], k=5)
    assert other.values.shape == (2, 3) and other.computed.all()
    sym = dwk_matrix(mesh, bumps, k=5)
    assert _overlap(other.lower, other.values, sym.lower[:2, 2:], sym.values[:2, 2:])


def test_bad_inputs_name_the_field(woody):
    mesh, bumps = woody
    for bad in (-1, 2.5, True):
        with pytest.raises(InputError) as err:
            dwk_matrix(mesh, bumps, k=bad)
        assert err.value.field == "k"
    with pytest.raises(InputError) as err:
        dwk_matrix(mesh, bumps, k=mesh.n)
    assert err.value.field == "k"
    with pytest.raises(InputError) as err:
        dwk_matrix(mesh, bumps, rows=[0, 9])
    assert err.value.field == "rows"


def test_cancel_keeps_the_finished_row_blocks(woody, monkeypatch):
    module = importlib.import_module("solvers.emd.dwk_matrix")  # the name is also a function
    mesh, bumps = woody
    monkeypatch.setattr(module, "ROW_BLOCK", 2)
    reports = []
    with pytest.raises(CancelledError) as err:
        dwk_matrix(mesh, bumps, bumps[:, :3], k=5, progress=lambda *a: reports.append(a),
                   should_cancel=lambda: len(reports) >= 1)
    partial = err.value.partial
    assert reports[0][0] == 6  # the first block: 2 rows x 3 columns
    assert partial.computed[:2].all() and not partial.computed[2:].any()
    full = dwk_matrix(mesh, bumps, bumps[:, :3], k=5)
    assert _overlap(partial.lower[:2], partial.values[:2], full.lower[:2], full.values[:2])


def test_default_k_is_a_budget_of_the_sizes():
    small = default_k(3000, 6000, 20, 190)
    large = default_k(50_000, 100_000, 1010, 10_000)
    assert small >= large and small > 0
    assert estimate_seconds(50_000, 100_000, large, 1010, 10_000) <= 60 or large == 0
    assert estimate_seconds(3000, 6000, 50, 20, 190) > estimate_seconds(3000, 6000, 0, 20, 190)


def test_working_bytes_bound_the_fields():
    # rows x columns: the columns and one row block of fields, not the whole collection
    few = working_bytes(50_000, 100_000, 0, 1000, 10, symmetric=False)
    every = working_bytes(50_000, 100_000, 0, 1000, 1000, symmetric=True)
    assert 8e5 * 74 <= few < 8e5 * 74 + 2e8 and every >= 8e5 * 1000
    assert working_bytes(50_000, 100_000, 50, 1000, 10, False) > few


def test_w1_method_decision_from_the_sizes():
    small = decide_w1_method(3000, 6000, 10, 45)
    assert small.method == "interior_point" and small.k is None
    large = decide_w1_method(50_000, 100_000, 1010, 10_000)
    assert large.method == "spectral" and large.k == default_k(50_000, 100_000, 1010, 10_000)
    assert "estimated" in large.reason
    given = decide_w1_method(3000, 6000, 10, 45, k=20)
    assert given.method == "spectral" and given.k == 20
    with pytest.raises(InputError) as err:
        decide_w1_method(3000, 6000, 10, 45, method="interior_point", k=5)
    assert err.value.field == "k"
    with pytest.raises(InputError) as err:
        decide_w1_method(3000, 6000, 10, 45, method="exact")
    assert err.value.field == "method"
