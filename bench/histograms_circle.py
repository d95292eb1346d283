"""Benchmark §5.4 on S¹: the exact propagation LP vs the entropic route, and real data.

Part ``graph`` — k-NN graphs (k = 4, uniform weights) of ``n`` random points in the unit
square, ``n`` in 100, 300, 1,000; 5 % of the nodes labeled with von Mises histograms
(κ uniform in [5, 40], mean angle 2π(x + y/2)) on 36 periodic bins.  In the same process:
the exact LP (``propagate_circular(method="lp", lp_method=--solver)``: highspy,
warm-started column generation started from a band of cheap entries (``simplex``) or from
the support found by the structured interior-point method (``hybrid``), certified by a
dual lower bound over all plan entries), then the entropic
route (Alg. 4 on a periodic 1-D grid, default γ = (2 w)²) and the exact objective of its
histograms (per-edge ``ot.emd2``): its gap to the LP optimum, absolute and relative.  The
LP gets ``--lp-time-limit`` seconds (HiGHS' own limit over all rounds); a row whose LP did
not finish says so and keeps the entropic figures.

Part ``bound`` — the structured interior-point method alone (the hybrid route's start)
on the same graphs: a certified bracket on the LP optimum (its dual bound and the exact
objective of its histograms) and so on the entropic route's gap, where the exact LP is
too slow.

Part ``real`` — the Fig. 5.6 protocol on S¹: on real meshes from ``../shared/meshes``
(suzanne, beetle), every vertex gets the histogram of its principal-direction angle
(``principal_direction_angles``, period π, 12 periodic bins on [0, π)) over its
geodesic neighbourhood (radius 1.5 mean edge lengths along edges); ``--fraction`` of the
vertices are labeled at random (plus one per unlabeled component), the exact LP on the
mesh's graph (``as_graph``) and PDF propagation fill in the rest; mean W1 error (circular:
min over rotations of the CDF difference) per unlabeled vertex against the true
histograms, over ``--trials`` random labelings.

BLAS/OpenMP threads are pinned to 1; the 1-minute load average is recorded before and
after every row.  Rows are appended to ``bench/results/histograms_circle.md`` (or
``--out``) as they finish.

Run: ``.venv/bin/python bench/histograms_circle.py graph --sizes 100 300 1000``
     ``.venv/bin/python bench/histograms_circle.py bound --sizes 1000``
     ``.venv/bin/python bench/histograms_circle.py real --meshes suzanne.obj --trials 20``
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
MESHES = ROOT.parent / "shared" / "meshes"
RESULTS = ROOT / "bench" / "results" / "histograms_circle.md"
OUT = RESULTS  # --out: rows of one run go there (several runs at once, merged by hand)

from _common import load1  # noqa: E402
from histograms import label_set  # noqa: E402  (the Fig. 5.6 label draw of bench/histograms.py)

from solvers import load_mesh  # noqa: E402
from solvers.curvature import principal_direction_angles  # noqa: E402
from solvers.errors import ConvergenceError  # noqa: E402
from solvers.histograms import (  # noqa: E402
    as_graph,
    circle_cost,
    dirichlet_value,
    knn_graph,
    make_bins,
    propagate_circular,
    propagate_histograms,
    w1_distance,
)
from solvers.histograms.features import neighbourhood_histograms  # noqa: E402


def emit(line: str) -> None:
    print(line, flush=True)
    with OUT.open("a") as f:
        f.write(line + "\n")


def knn_case(n: int, seed: int = 1, fraction: float = 0.05):
    rng = np.random.default_rng(seed)
    pts = rng.random((n, 2))
    g = knn_graph(pts, 4)
    bins = make_bins(lo=0.0, hi=2 * np.pi, count=36, periodic=True)
    k = max(2, int(round(fraction * n)))
    labeled = rng.choice(n, k, replace=False)
    truth = np.mod(2 * np.pi * (pts[:, 0] + 0.5 * pts[:, 1]), 2 * np.pi)
    kappa = rng.uniform(5, 40, k)
    h = np.exp(kappa[:, None] * np.cos(bins.centers[None] - truth[labeled, None]))
    return g, labeled, h / h.sum(axis=1, keepdims=True), bins


def resultant(H, bins) -> float:
    return float(np.abs(H @ np.exp(1j * bins.centers)).mean())


def part_graph(sizes, lp_time_limit: float, solver: str = "auto") -> None:
    emit("")
    stamp = time.strftime("%H:%M UTC", time.gmtime())
    emit(f"### k-NN graphs, 36 periodic bins, 5 % labeled ({stamp}, LP time limit "
         f"{lp_time_limit:g} s, solver {solver})")
    emit("")
    emit("| n | edges | labeled | LP plan entries (of m B²) | LP start (IPM its) / rounds / "
         "simplex its (last round) | LP time (s) | LP optimum | certified (value − dual bound) | "
         "entropic time (s), its | entropic exact objective (eval. s) | gap abs / rel | "
         "mean resultant LP / entropic | load before LP / after LP / after entropic |")
    emit("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in sizes:
        g, labeled, h, bins = knn_case(n)
        m = len(g.edges)
        free = np.setdiff1d(np.arange(n), labeled)
        l0 = load1()
        t = time.perf_counter()
        try:
            lp = propagate_circular(g, labeled, h, bins=bins, time_limit=lp_time_limit,
                                    lp_method=solver)
            lp_s = time.perf_counter() - t
        except ConvergenceError as exc:
            lp, lp_s = None, time.perf_counter() - t
            print(f"LP n={n}: {exc}", flush=True)
        l1 = load1()
        t = time.perf_counter()
        ent = propagate_circular(g, labeled, h, bins=bins, method="entropic",
                                 evaluate=False)
        ent_s = time.perf_counter() - t
        t = time.perf_counter()
        value = dirichlet_value(ent.histograms, g.edges, g.weights, circle_cost(bins))
        eval_s = time.perf_counter() - t
        l2 = load1()
        r_ent = resultant(ent.histograms[free], bins)
        if lp is None:
            lp_cells = (f"– | – | not finished in {lp_s:.0f} s | – | – ")
            gap = "– "
            r_lp = "–"
        else:
            lp_cells = (f"{lp.plan_entries:,} ({100 * lp.plan_entries / (m * 36 * 36):.0f} %) "
                        f"| {lp.lp_method}"
                        f"{'' if lp.ipm_iterations is None else f' ({lp.ipm_iterations})'}"
                        f" / {lp.iterations} / {lp.simplex_iterations} | **{lp_s:.1f}** | "
                        f"{lp.value:.6f} | {lp.certified} ({lp.value - lp.lower_bound:.1e}) ")
            gap = (f"+{value - lp.value:.5f} / {100 * (value - lp.value) / lp.value:.0f} % ")
            r_lp = f"{resultant(lp.histograms[free], bins):.3f}"
        emit(f"| {n} | {m} | {len(labeled)} | {lp_cells}| {ent_s:.2f}, {ent.iterations}"
             f"{'' if ent.converged else ' (not converged)'} | "
             f"{value:.6f} ({eval_s:.1f}) | {gap}| {r_lp} / {r_ent:.3f} | "
             f"{l0:.2f} / {l1:.2f} / {l2:.2f} |")


def part_bound(sizes, max_iter: int = 60) -> None:
    """The structured IPM alone (``solvers.histograms.circle_ipm.solve_ipm``, the hybrid
    route's start) on graphs too large for the exact LP here: a certified bracket
    ``dual bound <= LP optimum <= exact objective of the IPM histograms``, hence a
    bracket on the entropic route's gap."""
    from solvers.histograms.circle_ipm import dual_bound, solve_ipm
    from solvers.monitor import Monitor

    emit("")
    stamp = time.strftime("%H:%M UTC", time.gmtime())
    emit(f"### LP optimum bracketed by the structured IPM alone, k-NN graphs, 36 periodic "
         f"bins ({stamp})")
    emit("")
    emit("| n | edges | IPM its (status) | IPM time (s) | dual bound | exact objective of IPM "
         "histograms | bracket width (rel.) | entropic time (s), its | entropic exact "
         "objective | entropic gap (bracket) | load before / after IPM / after entropic |")
    emit("|---|---|---|---|---|---|---|---|---|---|---|")
    for n in sizes:
        g, labeled, h, bins = knn_case(n)
        m = len(g.edges)
        cost = circle_cost(bins)
        hc = np.where(h > 1e-12, h, 0.0)
        hc /= hc.sum(axis=1, keepdims=True)
        l0 = load1()
        t = time.perf_counter()
        res = solve_ipm(n, g.edges, g.weights, labeled, hc, cost, Monitor(), tol=1e-9,
                        max_iter=max_iter)
        ipm_s = time.perf_counter() - t
        lower, _ = dual_bound(res["lp"], res["yr"], res["yc"], res["z"])
        H = np.zeros((n, bins.count))
        H[labeled] = hc
        H[res["lp"].free] = np.clip(res["mu"], 0.0, None)
        upper = dirichlet_value(H, g.edges, g.weights, cost)
        l1 = load1()
        t = time.perf_counter()
        ent = propagate_circular(g, labeled, h, bins=bins, method="entropic",
                                 evaluate=False)
        ent_s = time.perf_counter() - t
        value = dirichlet_value(ent.histograms, g.edges, g.weights, cost)
        l2 = load1()
        emit(f"| {n} | {m} | {res['iterations']} ({res['status']}, best {res['best_iteration']})"
             f" | {ipm_s:.1f} | {lower:.6f} | {upper:.6f} | "
             f"{(upper - lower) / upper:.1e} | {ent_s:.2f}, {ent.iterations}"
             f"{'' if ent.converged else ' (not converged)'} | {value:.6f} | "
             f"[{value - upper:+.4f}, {value - lower:+.4f}] = "
             f"[{100 * (value - upper) / upper:.0f} %, {100 * (value - lower) / lower:.0f} %] | "
             f"{l0:.2f} / {l1:.2f} / {l2:.2f} |")


def part_real(meshes, trials: int, fraction: float, lp_time_limit: float,
              seed: int = 7, solver: str = "auto") -> None:
    bins = make_bins(lo=0.0, hi=np.pi, count=12, periodic=True)
    emit("")
    emit(f"### Real data: principal-direction angle, 12 periodic bins on [0, π), radius 1.5 h, "
         f"{100 * fraction:g} % labeled ({time.strftime('%H:%M UTC', time.gmtime())})")
    emit("")
    emit("| mesh | V | edges | trials | LP W1 | PDF W1 | PDF / LP | LP wins (of trials) | "
         "all LPs certified | LP time per trial (s) | load before/after |")
    emit("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in meshes:
        mesh = load_mesh(MESHES / name)
        values = principal_direction_angles(mesh)
        if np.ptp(values) == 0:  # e.g. woody is planar: no curvature, one angle everywhere
            emit(f"| {name} | {mesh.n} | skipped: the principal-direction angle is constant "
                 "(planar mesh), so every histogram is the same |  |  |  |  |  |  |  |  |")
            continue
        truth = neighbourhood_histograms(mesh, values, bins, 1.5 * mesh.mean_edge_length)
        graph = as_graph(mesh)
        rng = np.random.default_rng(seed)
        l0 = load1()
        errs, times, certified = [], [], True
        for trial in range(trials):
            lab = label_set(rng, mesh, fraction)
            free = np.setdiff1d(np.arange(mesh.n), lab)
            t = time.perf_counter()
            w = propagate_circular(graph, lab, truth[lab], bins=bins, time_limit=lp_time_limit,
                                   lp_method=solver)
            times.append(time.perf_counter() - t)
            certified &= bool(w.certified)
            p = propagate_histograms(mesh, lab, truth[lab], bins=bins, method="pdf")
            errs.append((w1_distance(w.histograms[free], truth[free], bins).mean(),
                         w1_distance(p.histograms[free], truth[free], bins).mean()))
            print(f"{name} trial {trial}: LP {errs[-1][0]:.4f} PDF {errs[-1][1]:.4f} "
                  f"({times[-1]:.1f} s, load {load1():.2f})", flush=True)
        e = np.array(errs)
        emit(f"| {name} | {mesh.n} | {len(graph.edges)} | {trials} | {e[:, 0].mean():.4f} ± "
             f"{e[:, 0].std():.4f} | {e[:, 1].mean():.4f} ± {e[:, 1].std():.4f} | "
             f"{e[:, 1].mean() / e[:, 0].mean():.2f} | {int((e[:, 0] < e[:, 1]).sum())}/{trials}"
             f" | {certified} | {np.mean(times):.1f} | {l0:.2f} / {load1():.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("part", choices=["graph", "bound", "real"])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 300, 1000])
    ap.add_argument("--lp-time-limit", type=float, default=3600.0)
    ap.add_argument("--meshes", nargs="+", default=["suzanne.obj", "beetle.obj"])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--fraction", type=float, default=0.05)
    ap.add_argument("--seed", type=int, default=7, help="seed of the random labelings")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--ipm-iterations", type=int, default=60,
                    help="part bound: the IPM's iteration cap")
    ap.add_argument("--solver", choices=["auto", "hybrid", "simplex"], default="auto",
                    help="start of the LP's column generation (propagate_circular(lp_method=))")
    args = ap.parse_args()
    global OUT
    OUT = args.out
    emit(f"\nCommand: `.venv/bin/python bench/histograms_circle.py {' '.join(sys.argv[1:])}`")
    if args.part == "graph":
        part_graph(args.sizes, args.lp_time_limit, args.solver)
    elif args.part == "bound":
        part_bound(args.sizes, args.ipm_iterations)
    else:
        part_real(args.meshes, args.trials, args.fraction, args.lp_time_limit, args.seed,
                  args.solver)


if __name__ == "__main__":
    main()
