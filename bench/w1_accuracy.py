"""W1 accuracy and speed of the Beckmann solvers against the exact LP and the exact discrete
optimum (issue 10: W1 within ±3 % of the LP; speed target "W1 on 10k vertices ≤ 2 s to 1e-4").

For each mesh: bumps (the service's ``{"vertex": 0, "radius": 0.1}`` kind) at 15 / 50 / 90 %
of the largest geodesic distance from vertex 0, and 25 + 25 scattered point masses.

* LP = ``ot.emd2`` on exact (MMP) geodesic lengths between the supports
  (``solvers.geodesics``): the quantity W1 names.
* SOCP = ``beckmann_w1_exact`` (Clarabel, tol 1e-8): the exact optimum of the *same*
  discretization the default solves (all piecewise-constant flows, weak divergence), i.e. the
  converged value against which "to 1e-4" is measured.
* default = ``earth_movers_distance`` with its defaults (all flows, primal-dual interior
  point, certified relative gap 1e-4, PARDISO when the ``mkl`` wheel loads, as in the README's
  install); "err" is its relative value error against the SOCP, "gap" its own certified
  bound (value − lower bound) / value.
* ipm cholespy = the same solve with the core install's factorization (cholespy, factored
  anew every iteration: the Docker image).
* ADMM = ``method="admm"`` (the previous default over all flows, tol 1e-2).
* full = the thesis' curl basis ``basis="full"`` at tol 1e-4 (``--full``; off by default).

All times warm (operators cached on the mesh), wall clock; load = 1-minute load average
before/after the row.  Writes ``bench/results/w1_accuracy.md``.

Usage: ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python
bench/w1_accuracy.py [--full] [--points-only] [--out=bench/results/NAME.md] [mesh.obj ...]``
(``--points-only``: the 25 + 25 point masses only, for the large meshes, where the bump LPs
would need geodesics from every bump vertex; the SOCP is skipped above 20k vertices).
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

import solvers.emd.interior_point as interior_point  # noqa: E402
from solvers import load_mesh  # noqa: E402
from solvers.emd import earth_movers_distance  # noqa: E402
from solvers.emd.exact import beckmann_w1_exact  # noqa: E402
from solvers.geodesics import geodesic_distances  # noqa: E402

OUT = ROOT / "bench" / "results" / "w1_accuracy.md"


def timed(fn, *args, **kwargs):
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - start


# Above this many vertices the SOCP reference (Clarabel) is skipped: minutes per case.
SOCP_MAX_VERTICES = 20000


def rows_for(name, full: bool, points_only: bool = False):
    mesh = load_mesh(MESHES / name)
    rng = np.random.default_rng(len(name))
    cases = {}
    if not points_only:
        d0 = geodesic_distances(mesh, [0])[0]
        for label, frac in (("near", 0.15), ("middle", 0.5), ("far", 0.9)):
            j = int(np.argmin(np.abs(d0 - frac * d0.max())))
            cases[label] = (service_bump(mesh, 0), service_bump(mesh, j))
    p0, p1 = np.zeros(mesh.n), np.zeros(mesh.n)
    p0[rng.choice(mesh.n, 25, replace=False)] = 1 / 25
    p1[rng.choice(mesh.n, 25, replace=False)] = 1 / 25
    cases["points"] = (p0, p1)
    earth_movers_distance(mesh, p0, p1)  # warm: factorizations and structure cached
    earth_movers_distance(mesh, p0, p1, method="admm")
    if full:
        earth_movers_distance(mesh, p0, p1, basis="full", tol=1e-2)
    for label, (m0, m1) in cases.items():
        row = dict(name=name, n=mesh.n, case=label, load_before=load1())
        s0, s1 = np.flatnonzero(m0), np.flatnonzero(m1)
        row["lp"] = float(ot.emd2(m0[s0], m1[s1], geodesic_distances(mesh, s0, s1)))
        if mesh.n <= SOCP_MAX_VERTICES:
            exact, row["socp_s"] = timed(beckmann_w1_exact, mesh, m0, m1,
                                         max_vertices=max(mesh.n, 5000))
            row["socp"] = float(exact.value)
        else:
            row["socp"], row["socp_s"] = float("nan"), float("nan")
        res, t = timed(earth_movers_distance, mesh, m0, m1)
        row["default"] = (float(res.value), t, int(res.iterations), float(res.residual),
                          bool(res.converged))
        have = interior_point.have_pardiso
        interior_point.have_pardiso = lambda: False
        try:
            res, t = timed(earth_movers_distance, mesh, m0, m1)
        finally:
            interior_point.have_pardiso = have
        row["cholespy"] = (float(res.value), t, int(res.iterations))
        res, t = timed(earth_movers_distance, mesh, m0, m1, method="admm")
        row["admm"] = (float(res.value), t, int(res.iterations))
        if full:
            res, t = timed(earth_movers_distance, mesh, m0, m1, basis="full", tol=1e-4)
            row["full"] = (float(res.value), t, int(res.iterations))
        row["load_after"] = load1()
        print(row, flush=True)
        yield row


def main(names, full: bool, out: Path, points_only: bool = False):
    cmd = ("OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python "
           "bench/w1_accuracy.py "
           + ("--full " if full else "") + ("--points-only " if points_only else "")
           + (f"--out={out.relative_to(ROOT)} " if out != OUT else "")
           + " ".join(names))
    lines = ["# W1 (Beckmann) vs the exact LP and the exact discrete optimum", "",
             f"Command: `{cmd}`.  LP = `ot.emd2` on exact (MMP) geodesic lengths between the "
             "supports; SOCP = `beckmann_w1_exact` (Clarabel, tol 1e-8), the exact optimum of "
             "the discretization the default solves; default = `earth_movers_distance` with "
             "its defaults (all flows, interior point, certified gap 1e-4), err = relative "
             "value error against the SOCP; gap = its certified (value − lower bound) / "
             "value; ipm cholespy = the "
             "same solve on the core install's factorization; ADMM = method='admm' (tol "
             "1e-2, the previous default).  PARDISO: " + str(interior_point.have_pardiso())
             + ".  Times warm, wall clock, seconds; load = 1-minute load average "
             "before/after the row (2 cores shared with other jobs).", "",
             "| mesh | V | case | LP W1 | SOCP W1 (vs LP), s | default W1 (vs LP), err vs SOCP, "
             "gap, s, it | ipm cholespy: s, it | ADMM tol 1e-2: W1 (vs LP), s, it |"
             + (" full basis tol 1e-4: W1 (vs LP), s, it |" if full else "") + " load |",
             "|---|---|---|---|---|---|---|---|" + ("---|" if full else "") + "---|"]
    for name in names:
        for r in rows_for(name, full, points_only):
            lp, socp = r["lp"], r["socp"]
            v, t, it, gap, ok = r["default"]
            _, ct, cit = r["cholespy"]
            av, at, ait = r["admm"]
            skip = not np.isfinite(socp)
            err = "–" if skip else f"{abs(v / socp - 1):.1e}"
            cells = ["– (skipped above 20k vertices)" if skip else
                     f"{socp:.4f} ({socp / lp - 1:+.1%}), {r['socp_s']:.1f}",
                     f"{v:.4f} ({v / lp - 1:+.1%}), {err}, {gap:.1e}"
                     + ("" if ok else " (not converged)") + f", **{t:.2f}**, {it}",
                     f"{ct:.2f}, {cit}",
                     f"{av:.4f} ({av / lp - 1:+.1%}), {at:.2f}, {ait}"]
            if full:
                fv, ft, fit = r["full"]
                cells.append(f"{fv:.4f} ({fv / lp - 1:+.1%}), {ft:.2f}, {fit}")
            lines.append(f"| {r['name']} | {r['n']} | {r['case']} | {lp:.4f} | "
                         + " | ".join(cells)
                         + f" | {r['load_before']:.1f}/{r['load_after']:.1f} |")
            out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    outs = [ROOT / a.split("=", 1)[1] for a in sys.argv[1:] if a.startswith("--out=")]
    main([a for a in sys.argv[1:] if a.endswith(".obj")] or ["spot.obj", "cow.obj"],
         "--full" in sys.argv, outs[-1] if outs else OUT, "--points-only" in sys.argv)
