"""The default decision of a distance (solvers.transport.decision) on every domain kind:
the sketch of stored arrays equals the built domain's, and the decision follows from it."""

from __future__ import annotations

import numpy as np
import pytest

from solvers import Graph, Grid, PointCloud
from solvers.convolutional import wasserstein_distance
from solvers.domains.sketch import DomainSketch
from solvers.errors import InputError
from solvers.transport.decision import DistanceDecision, decide_distance


def _stored(domain) -> DomainSketch:
    """What the service builds from its stored copy (arrays, unit-area points, labels)."""
    points = None if domain.kind == "graph" else getattr(domain, "points", None)
    return DomainSketch.from_stored(domain.kind, domain.to_arrays(), points,
                                    domain.component_labels)


def _masses(n, idx):
    m = np.zeros(n)
    m[idx] = 1.0
    return m / m.sum()


def _cloud():
    rng = np.random.default_rng(0)
    theta, z = rng.uniform(0, 2 * np.pi, 400), rng.uniform(0, 1, 400)
    return PointCloud(np.stack([np.cos(theta), np.sin(theta), z], axis=1))


@pytest.mark.parametrize("make", [lambda: Grid((12, 10), periodic=(True, False)),
                                  lambda: Graph(6, [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5)]),
                                  _cloud])
def test_stored_sketch_gives_the_library_decision(make):
    domain = make()
    stored, built = _stored(domain), DomainSketch.of(domain)
    assert stored.length_scale == built.length_scale
    src, dst = np.arange(3), np.arange(domain.n - 3, domain.n)
    assert np.array_equal(stored.distances(src, dst), built.distances(src, dst))
    m0, m1 = _masses(domain.n, [0, 1]), _masses(domain.n, [domain.n - 2, domain.n - 1])
    decision = decide_distance(stored, m0, m1)
    assert decision == decide_distance(domain, m0, m1)
    assert DistanceDecision.from_dict(decision.as_dict()) == decision
    res = wasserstein_distance(domain, m0, m1)
    assert res.decision == decision and res.method == decision.method
    if domain.kind == "graph":
        assert decision.method == "convolutional" and "no exact route" in decision.reason
        assert decision.debiased and decision.regularization.h == 1.0
    else:
        assert decision.method == "exact" and decision.exact_seconds < 1.0


def test_periodic_grid_distances_wrap():
    grid = Grid((16,), periodic=True)
    sketch = DomainSketch.of(grid)
    assert sketch.distances([0], [15])[0, 0] == pytest.approx(grid.spacing[0])


def test_explicit_arguments_are_the_decision():
    grid = Grid((8, 8))
    m0, m1 = _masses(grid.n, [0]), _masses(grid.n, [63])
    given = decide_distance(grid, m0, m1, gamma=0.02, substeps=3)
    assert (given.method, given.gamma, given.substeps, given.debiased) == (
        "convolutional", 0.02, 3, False)
    assert given.regularization is None and given.reason == "gamma given"
    assert decide_distance(grid, m0, m1, method="exact").method == "exact"
    forced = decide_distance(grid, m0, m1, method="convolutional")
    assert forced.method == "convolutional" and forced.exact_seconds is None
    assert forced.solver_arguments() == {"method": "convolutional", "gamma": forced.gamma,
                                         "t": forced.t, "substeps": forced.substeps,
                                         "debiased": True}
    for bad, field in ((dict(method="fast"), "method"), (dict(gamma="small"), "gamma")):
        with pytest.raises(InputError) as err:
            decide_distance(grid, m0, m1, **bad)
        assert err.value.field == field
