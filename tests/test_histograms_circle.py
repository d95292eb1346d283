"""§5.4: histograms on S¹ through the LP (HiGHS) and the entropic route (Alg. 4)."""

from __future__ import annotations

import numpy as np
import pytest

from solvers import Graph
from solvers.errors import InputError
from solvers.histograms import (
    circle_cost,
    dirichlet_value,
    make_bins,
    propagate_circular,
)
from solvers.histograms import summaries as S

BINS = make_bins(lo=0.0, hi=2 * np.pi, count=36, periodic=True)


def von_mises(mu, kappa=40.0):
    h = np.exp(kappa * np.cos(BINS.centers - mu))
    return h / h.sum()


def path(n):
    return Graph(n, np.c_[np.arange(n - 1), np.arange(1, n)])


def resultant(h):
    return np.abs(h @ np.exp(1j * BINS.centers))


def test_angles_across_zero_interpolate_the_short_way_and_stay_peaked():
    n = 11
    labels = np.stack([von_mises(np.deg2rad(340)), von_mises(np.deg2rad(20))])
    res = propagate_circular(path(n), [0, n - 1], labels, bins=BINS)
    assert res.converged and res.gap == 0.0
    mean = np.rad2deg(S.circular_mean(res.histograms, BINS))
    off_zero = np.minimum(mean, 360 - mean)  # angular distance to 0
    assert np.all(off_zero <= 20.5)  # never through 180 degrees
    assert np.all(np.abs(np.diff(np.unwrap(np.deg2rad(mean)))) < np.deg2rad(15))
    assert np.all(resultant(res.histograms) >= 0.9)  # peaked labels stay peaked (Fig. 5.5)
    # the reported objective is the exact Dirichlet energy of the returned histograms
    exact = dirichlet_value(res.histograms, path(n).edges, np.ones(n - 1), circle_cost(BINS))
    assert res.value == pytest.approx(exact, rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
def test_lp_value_never_above_entropic_route(seed):
    rng = np.random.default_rng(seed)
    n = 14
    e = np.c_[np.arange(n - 1), np.arange(1, n)]
    extra = rng.choice(n, (6, 2))
    extra = extra[extra[:, 0] != extra[:, 1]]
    g = Graph(n, np.r_[e, extra], rng.uniform(0.5, 2.0, len(e) + len(extra)))
    labeled = rng.choice(n, 4, replace=False)
    labels = np.stack([von_mises(rng.uniform(0, 2 * np.pi), rng.uniform(5, 40))
                       for _ in labeled])
    lp = propagate_circular(g, labeled, labels, bins=BINS)
    ent = propagate_circular(g, labeled, labels, bins=BINS, method="entropic",
                             lp_value=lp.value)
    assert ent.converged
    assert lp.value <= ent.value + 1e-9
    assert ent.gap == pytest.approx(ent.value - lp.value) and ent.gap >= -1e-9
    assert np.allclose(ent.histograms[labeled], labels, atol=1e-6)
    # peaked labels stay more peaked through the exact LP than through the entropic route
    free = np.setdiff1d(np.arange(n), labeled)
    assert resultant(lp.histograms[free]).mean() >= resultant(ent.histograms[free]).mean()


def test_small_metric_space_cost_and_validation():
    b = make_bins(lo=0, hi=3, count=3)
    cost = np.array([[0, 1, 4], [1, 0, 1], [4, 1, 0]], dtype=float)
    res = propagate_circular(path(3), [0, 2], [[1, 0, 0], [0, 0, 1]], bins=b, cost=cost)
    assert np.allclose(res.histograms[1], [0, 1, 0], atol=1e-8)  # the metric midpoint
    assert res.value == pytest.approx(2.0)
    with pytest.raises(InputError) as exc:
        propagate_circular(Graph(4, [[0, 1], [2, 3]]), [0], [[1, 0, 0]], bins=b, cost=cost)
    assert exc.value.field == "labeled"
    with pytest.raises(InputError) as exc:
        propagate_circular(path(3), [0, 2], [[1, 0, 0], [0, 0, 1]], bins=b, cost=-cost)
    assert exc.value.field == "cost"


def _unrestricted_lp(n, edges, weights, labeled, labels, cost):
    """The §5.4 LP over all ``m B^2`` plan entries, written out independently (``2B`` rows
    per edge and one normalization row per free node; scipy's HiGHS, no column generation)."""
    import scipy.sparse as sp
    from scipy.optimize import linprog

    B, m = cost.shape[0], len(edges)
    free = np.setdiff1d(np.arange(n), labeled)
    col_of = {int(v): k for k, v in enumerate(free)}
    label_of = {int(v): k for k, v in enumerate(labeled)}
    rows, cols, vals, rhs = [], [], [], []
    n_plan = m * B * B
    r = 0
    for e, (u, v) in enumerate(edges):
        for side, end in ((0, u), (1, v)):
            for i in range(B):
                k = np.arange(B)
                entries = e * B * B + (i * B + k if side == 0 else k * B + i)
                rows += [r] * B
                cols += entries.tolist()
                vals += [1.0] * B
                if int(end) in col_of:
                    rows.append(r)
                    cols.append(n_plan + col_of[int(end)] * B + i)
                    vals.append(-1.0)
                    rhs.append(0.0)
                else:
                    rhs.append(labels[label_of[int(end)], i])
                r += 1
    for f in range(len(free)):
        rows += [r] * B
        cols += (n_plan + f * B + np.arange(B)).tolist()
        vals += [1.0] * B
        rhs.append(1.0)
        r += 1
    A = sp.csr_matrix((vals, (rows, cols)), shape=(r, n_plan + len(free) * B))
    c = np.concatenate([np.repeat(weights, B * B) * np.tile(cost.ravel(), m),
                        np.zeros(len(free) * B)])
    res = linprog(c, A_eq=A, b_eq=np.array(rhs), bounds=(0, None), method="highs")
    assert res.status == 0, res.message
    return res.fun


@pytest.mark.parametrize("lp_method", ["simplex", "hybrid"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_column_generation_reaches_the_unrestricted_lp_optimum(seed, lp_method):
    # far-apart labels (opposite Diracs, bimodal) need plan entries outside the starting
    # band, so the pricing rounds matter; the result must be the full LP's optimum
    rng = np.random.default_rng(seed)
    bins = make_bins(lo=0.0, hi=2 * np.pi, count=12, periodic=True)
    n = 9
    ring = np.c_[np.arange(n), np.roll(np.arange(n), -1)]
    chords = np.array([[0, 4], [2, 7], [1, 5]])
    edges = np.r_[ring, chords]
    weights = rng.uniform(0.5, 2.0, len(edges))
    labeled = np.array([0, 3, 6])
    labels = np.zeros((3, 12))
    labels[0, 0] = 1.0                      # a Dirac
    labels[1, 6] = 1.0                      # the opposite Dirac
    labels[2] = rng.random(12) ** 4         # spread out
    labels[2, [2, 9]] += 1.0                # ... with two modes
    labels /= labels.sum(axis=1, keepdims=True)
    cost = circle_cost(bins)
    res = propagate_circular(Graph(n, edges, weights), labeled, labels, bins=bins,
                             lp_method=lp_method)
    reference = _unrestricted_lp(n, edges, weights, labeled, labels, cost)
    assert res.certified and res.converged and res.lp_method == lp_method
    assert (res.ipm_iterations is not None) == (lp_method == "hybrid")
    assert res.value == pytest.approx(reference, rel=1e-7, abs=1e-9)
    assert res.lower_bound <= reference + 1e-9 and res.min_reduced_cost >= -1e-9
    assert res.plan_entries < len(edges) * 12 * 12  # column generation left entries out
    exact = dirichlet_value(res.histograms, edges, weights, cost)
    assert exact == pytest.approx(res.value, rel=1e-6, abs=1e-9)
    assert np.allclose(res.histograms.sum(axis=1), 1.0, atol=1e-7)


def _random_case(seed, n=16, B=36, n_labeled=4):
    rng = np.random.default_rng(seed)
    e = np.c_[np.arange(n - 1), np.arange(1, n)]
    extra = rng.choice(n, (8, 2))
    extra = extra[extra[:, 0] != extra[:, 1]]
    edges = np.r_[e, extra]
    weights = rng.uniform(0.5, 2.0, len(edges))
    labeled = rng.choice(n, n_labeled, replace=False)
    bins = make_bins(lo=0.0, hi=2 * np.pi, count=B, periodic=True)
    labels = np.exp(rng.uniform(5, 40, (n_labeled, 1))
                    * np.cos(bins.centers[None] - rng.uniform(0, 2 * np.pi, (n_labeled, 1))))
    labels /= labels.sum(axis=1, keepdims=True)
    return n, edges, weights, labeled, labels, bins


@pytest.mark.parametrize("seed", [3, 4])
def test_hybrid_start_matches_the_simplex_start(seed):
    # the interior-point start changes the route, not the certified optimum
    n, edges, weights, labeled, labels, bins = _random_case(seed)
    g = Graph(n, edges, weights)
    old = propagate_circular(g, labeled, labels, bins=bins, lp_method="simplex")
    new = propagate_circular(g, labeled, labels, bins=bins, lp_method="hybrid")
    assert old.certified and new.certified and new.ipm_iterations > 0
    assert new.value == pytest.approx(old.value, rel=1e-7, abs=1e-9)
    exact = dirichlet_value(new.histograms, edges, weights, circle_cost(bins))
    assert exact == pytest.approx(new.value, rel=1e-6, abs=1e-9)


def test_structured_ipm_operators_and_normal_equations():
    from solvers.histograms.circle_ipm import StructuredLP, dual_bound, solve_ipm
    from solvers.monitor import Monitor

    n, edges, weights, labeled, labels, bins = _random_case(5, n=12, B=8, n_labeled=3)
    cost = circle_cost(bins)
    lp = StructuredLP(n, edges, weights, labeled, labels, cost)
    rng = np.random.default_rng(0)
    B, m, nf = lp.B, lp.m, lp.nf
    X, mu = rng.random((m, B, B)), rng.random((nf, B))
    yr, yc, z = rng.standard_normal((m, B)), rng.standard_normal((m, B)), rng.standard_normal(nf)
    yc[:, -1] = 0.0
    ar, ac, az = lp.A_x(X, mu)
    tp, tm = lp.At_y(yr, yc, z)
    # A and A^T are adjoint
    assert np.sum(ar * yr) + np.sum(ac * yc) + az @ z == pytest.approx(
        np.sum(X * tp) + np.sum(mu * tm), rel=1e-12)
    # the block elimination solves A D A^T y = g
    D, Dmu = rng.random((m, B, B)) + 0.05, rng.random((nf, B)) + 0.05
    lp.prepare(D, Dmu)
    gr, gc, gz = rng.standard_normal((m, B)), rng.standard_normal((m, B)), rng.standard_normal(nf)
    gc[:, -1] = 0.0
    sr, sc, sz, _ = lp.normal_solve(gr, gc, gz)
    er, ec, ez = lp.ADAt(D, Dmu, sr, sc, sz)
    assert np.abs(er - gr).max() < 1e-8 and np.abs(ec - gc)[:, :-1].max() < 1e-8
    assert np.abs(ez - gz).max() < 1e-8
    # the IPM's dual bound is a lower bound on the (independently computed) optimum, and
    # the IPM's own objectives approach it
    res = solve_ipm(n, edges, weights, labeled, labels, cost, Monitor(), tol=1e-6)
    reference = _unrestricted_lp(n, edges, weights, labeled, labels, cost)
    lower, _ = dual_bound(res["lp"], res["yr"], res["yc"], res["z"])
    assert lower <= reference + 1e-9
    assert lower == pytest.approx(reference, rel=1e-3)


def test_solver_validation():
    with pytest.raises(InputError) as exc:
        propagate_circular(path(3), [0, 2], [von_mises(0.0), von_mises(1.0)], bins=BINS,
                           lp_method="barrier")
    assert exc.value.field == "lp_method"
