"""Exact W2 between large supports, without and with the nearest-pivot bounds (issue 40).

Runs whose rows² x columns exceed ``solvers.transport.exact.TRIANGLE_ENTRIES`` bound
each row's unknown entries through its ``PIVOT_ROWS`` nearest rows of known distance
(``_pivot_bounds``); this times one such run with those bounds replaced by zeros (as before
them) and as committed, in one process, warm, on the cases of ``bench/distance_routes.py``
(``mesh:label:radius``, label near / middle / far)::

    cpu bench env OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 \\
        .venv/bin/python bench/exact_pivots.py rocker-arm.obj:near:0.2 homer.obj:near:0.2

Results: ``bench/results/exact_geodesics_speed.md``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import distance_routes as routes  # noqa: E402

import solvers.transport.exact as exact  # noqa: E402
from solvers import load_mesh  # noqa: E402


def timed_run(mesh, m0, m1, with_pivots: bool) -> tuple[float, float]:
    """Seconds and value of one exact run, with the pivot bounds or with zeros for them."""
    committed = exact._pivot_bounds
    if not with_pivots:
        exact._pivot_bounds = lambda near, dist, pivots: np.zeros(dist.shape)
    try:
        start = time.perf_counter()
        value = exact.exact_wasserstein_distance(mesh, m0, m1).value
        return time.perf_counter() - start, value
    finally:
        exact._pivot_bounds = committed


def main(cases: list[str]) -> None:
    for case in cases:
        name, label, radius = case.split(":")
        routes.RADIUS[0] = float(radius)
        mesh = load_mesh(routes.MESHES / name)
        runs = routes.cases(mesh, name)
        exact.exact_wasserstein_distance(mesh, *runs["points"][:2])  # warm: fan split, closure
        m0, m1, _ = runs[label]
        size = f"{np.count_nonzero(m0)} x {np.count_nonzero(m1)}"
        seconds = {}
        for with_pivots in (False, True):
            seconds[with_pivots], value = timed_run(mesh, m0, m1, with_pivots)
            print(f"{case} ({size}) {'pivots' if with_pivots else 'none  '} "
                  f"{seconds[with_pivots]:.2f} s  W2^2 {value!r}  load {os.getloadavg()[0]:.2f}",
                  flush=True)
        print(f"{case}: {seconds[False] / seconds[True]:.2f}x with the pivot bounds")


if __name__ == "__main__":
    main(sys.argv[1:] or ["homer.obj:near:0.2"])
