"""W1 accuracy of the Beckmann bases against the exact LP (issue: W1 within ±3 %).

For each mesh: bumps (the service's ``{"vertex": 0, "radius": 0.1}`` kind) at 15 / 50 / 90 %
of the largest geodesic distance from vertex 0, and 25 + 25 scattered point masses.  LP =
``ot.emd2`` on exact (MMP) geodesic lengths between the supports (``solvers.geodesics``);
W1 by ``earth_movers_distance`` with its defaults (``basis="auto"`` = all flows, tol 1e-2),
with the thesis' curl basis ``basis="full"`` at tol 1e-4 (the previous default), and
optionally (``--flow-1e-4``) all flows at tol 1e-4; timed warm.
Writes ``bench/results/w1_accuracy.md``.

Usage: ``OMP_NUM_THREADS=1 .venv/bin/python bench/w1_accuracy.py [mesh.obj ...]``
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import ot

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MESHES = ROOT.parent / "shared" / "meshes"

from _common import load1, service_bump  # noqa: E402

from solvers import load_mesh  # noqa: E402
from solvers.emd import earth_movers_distance  # noqa: E402
from solvers.geodesics import geodesic_distances  # noqa: E402

VARIANTS = {"default": {}, "full": {"basis": "full", "tol": 1e-4}}


def rows_for(name):
    mesh = load_mesh(MESHES / name)
    d0 = geodesic_distances(mesh, [0])[0]
    rng = np.random.default_rng(len(name))
    cases = {}
    for label, frac in (("near", 0.15), ("middle", 0.5), ("far", 0.9)):
        j = int(np.argmin(np.abs(d0 - frac * d0.max())))
        cases[label] = (service_bump(mesh, 0), service_bump(mesh, j))
    p0, p1 = np.zeros(mesh.n), np.zeros(mesh.n)
    p0[rng.choice(mesh.n, 25, replace=False)] = 1 / 25
    p1[rng.choice(mesh.n, 25, replace=False)] = 1 / 25
    cases["points"] = (p0, p1)
    earth_movers_distance(mesh, p0, p1, tol=1e-2)  # warm: factorizations cached
    for label, (m0, m1) in cases.items():
        row = dict(name=name, n=mesh.n, case=label, load_before=load1())
        s0, s1 = np.flatnonzero(m0), np.flatnonzero(m1)
        row["lp"] = float(ot.emd2(m0[s0], m1[s1], geodesic_distances(mesh, s0, s1)))
        for key, kwargs in VARIANTS.items():
            start = time.perf_counter()
            res = earth_movers_distance(mesh, m0, m1, **kwargs)
            row[key] = (float(res.value), time.perf_counter() - start, int(res.iterations),
                        bool(res.converged))
        row["load_after"] = load1()
        print(row, flush=True)
        yield row


def main(names):
    lines = ["# W1 bases vs the exact LP", "",
             "Command: `OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python "
             "bench/w1_accuracy.py " + " ".join(names) + "`.  LP = `ot.emd2` on exact (MMP) "
             "geodesic lengths between the supports; W1 = `earth_movers_distance(..., "
             "basis=B, tol=1e-4)`, warm; times wall clock in seconds; load = 1-minute load "
             "average before/after the row (2 cores shared with other jobs).", "",
             "| mesh | V | case | LP W1 | " + " | ".join(
                 f"{k} {v or '(flow, tol 1e-2)'}: W1 (gap), s, it" for k, v in VARIANTS.items())
             + " | load |", "|---|---|---|---|" + "---|" * len(VARIANTS) + "---|"]
    for name in names:
        for r in rows_for(name):
            cells = []
            for key in VARIANTS:
                v, t, it, ok = r[key]
                cells.append(f"{v:.4f} ({v / r['lp'] - 1:+.1%}), {t:.2f}, {it}"
                             + ("" if ok else " (not converged)"))
            lines.append(f"| {r['name']} | {r['n']} | {r['case']} | {r['lp']:.4f} | "
                         f"{cells[0]} | {cells[1]} | {r['load_before']:.1f}/"
                         f"{r['load_after']:.1f} |")
            out = ROOT / "bench" / "results" / "w1_accuracy.md"
            out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    if "--flow-1e-4" in sys.argv:
        VARIANTS["flow 1e-4"] = {"basis": "flow", "tol": 1e-4}
    main([a for a in sys.argv[1:] if a.endswith(".obj")] or ["spot.obj", "cow.obj"])
