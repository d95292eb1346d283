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
    ent = propagate_circular(g, labeled, labels, bins=BINS, algorithm="entropic",
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
