"""The one progress/cancellation/stagnation hook of every iterative solver."""

from __future__ import annotations

import math

import pytest

from solvers.errors import CancelledError
from solvers.monitor import Monitor, SolverResult


def test_progress_cancel_and_fraction():
    seen = []
    mon = Monitor(lambda i, r, f: seen.append((i, r, f)), tol=1e-4)
    mon(1, 1.0)
    mon(2, 1e-2)
    mon(3, 1e-5)
    assert [s[0] for s in seen] == [1, 2, 3]
    assert seen[0][2] == 0.0 and math.isclose(seen[1][2], 0.5) and seen[2][2] == 1.0
    two = []
    Monitor(lambda i, r: two.append(i))(4, 0.1)  # two-argument callbacks keep working
    assert two == [4]
    stop = Monitor(should_cancel=lambda: True)
    with pytest.raises(CancelledError):
        stop(1, 1.0)


def test_stalls_when_the_residual_stops_falling():
    mon = Monitor(tol=1e-9, patience=10)
    for it in range(1, 30):
        mon(it, 1e-3 if it > 5 else 10.0 ** -it)
    assert mon.stalled
    falling = Monitor(tol=1e-9, patience=10)
    for it in range(1, 30):
        falling(it, 0.5**it)
    assert not falling.stalled


def test_projection_stops_a_sublinear_tail_but_not_a_fast_one():
    slow = Monitor(tol=1e-9, patience=20, max_iter=1000, project=True)
    for it in range(1, 200):
        slow(it, 1.0 / it)  # would need ~1e9 iterations to reach tol
        if slow.stalled:
            break
    assert slow.stalled and it < 100
    fast = Monitor(tol=1e-9, patience=20, max_iter=1000, project=True)
    for it in range(1, 200):
        fast(it, 0.9**it)  # reaches 1e-9 near iteration 197
    assert not fast.stalled
    fresh = slow.next_stage()
    assert not fresh.stalled and fresh.project and fresh.max_iter == 1000


def test_result_base_is_keyword_only_with_shared_fields():
    from dataclasses import dataclass

    import numpy as np

    @dataclass
    class Result(SolverResult):
        masses: np.ndarray

    r = Result(np.ones(2), iterations=3, residual=1e-7, converged=True)
    assert (r.iterations, r.residual, r.converged) == (3, 1e-7, True)
