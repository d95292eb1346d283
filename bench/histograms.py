"""Benchmark Wasserstein propagation of histograms (thesis ch. 5, ``solvers.histograms``).

Part ``scale`` — Prop. 13 at scale: 100 quantile levels, 1 % of the nodes labeled with
random two-Gaussian histograms on 32 bins, on grid graphs (100², 316², 1000²) and on
midpoint-subdivided real meshes (~10k, ~100k, ~800k vertices).  Per size, in its own
process (so the peak RSS is that size's), on a domain whose Laplacian and components are
built first (as at upload): the Wasserstein route as users get it (``propagate_histograms``
defaults: the direct solver, MKL PARDISO when the mkl wheel loads, else cholespy — the
backend is recorded per row; factorization, one block solve, inverse CDFs back to
histograms), the PDF route on the same (cached) factorization, the AMG-preconditioned CG
solver (one pyamg hierarchy shared by all levels; at 1M on the first 10 columns,
extrapolated), and a per-quantile ``scipy.sparse.linalg.spsolve`` loop (all 100 levels at
10k; at larger sizes a few levels, extrapolated linearly to 100 and marked so).  Targets:
100k nodes <= 2 s, 1M <= 30 s on 2 cores, <= 4 GB.  The scaling exponent is the
least-squares slope of log time vs log n per family (and the slopes between consecutive
sizes).  Raw rows go to ``bench/results/histograms_scale.json``; ``--part scale --rows
mesh:100k`` reruns one row (e.g. at a quieter minute) and re-renders the table.

Part ``circle`` — §5.4 on S¹: a 1,000-node k-NN graph, 36 periodic bins, 5 % labeled
with von Mises histograms: the exact LP (HiGHS) time, the entropic route's time, and the
gap of its exact objective to the LP optimum.

Part ``real`` — the Fig. 5.6 protocol on real meshes (``../shared/meshes``): every vertex
gets the histogram of a geometric quantity over its geodesic neighbourhood (graph
distance along edges): mean curvature for Prob(ℝ) (24 bins over
the 1st-99th percentile), principal-direction angle for S¹ (12 periodic bins on [0, π));
1 %, 5 % and 10 % of the vertices labeled at random (plus one per unlabeled component),
20 trials, neighbourhood radii 1.5 and 3 mean edge lengths; mean W1 error per unlabeled
vertex against the true histograms, Wasserstein vs PDF (and, on S¹, the LP vs PDF).

BLAS/OpenMP threads are set to 2 (both cores; the targets are "on 2 cores") before numpy
loads; the 1-minute load average is recorded before and after every row.

Run: ``.venv/bin/python bench/histograms.py [--part scale|circle|real|all] [--quick]``
(timings that decide a target: under ``flock /tmp/otgeo-timing.lock`` with the thread
variables set to 2 explicitly);
writes ``bench/results/histograms.md`` (parts not run are kept from the existing file).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "2")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import re  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MESHES = ROOT.parent / "shared" / "meshes"
RESULTS = ROOT / "bench" / "results" / "histograms.md"

from solvers import Grid, TriangleMesh, load_mesh  # noqa: E402
from solvers.curvature import mean_curvature, principal_direction_angles  # noqa: E402
from solvers.histograms import (  # noqa: E402
    as_graph,
    knn_graph,
    make_bins,
    propagate_circular,
    propagate_histograms,
    w1_distance,
)
from solvers.histograms import summaries as S  # noqa: E402
from solvers.histograms.dirichlet import dirichlet_system  # noqa: E402
from solvers.histograms.features import neighbourhood_histograms  # noqa: E402

LEVELS = 100
NBINS = 32


def load() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


# -- domains ---------------------------------------------------------------------------
def subdivide(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint subdivision: every triangle into four (same angles, 4x the faces)."""
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    mid = len(v) + inv.reshape(3, -1).T  # (F, 3): midpoints of edges 01, 12, 20
    v2 = np.vstack([v, 0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]])])
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    m01, m12, m20 = mid[:, 0], mid[:, 1], mid[:, 2]
    f2 = np.concatenate([np.c_[a, m01, m20], np.c_[m01, b, m12], np.c_[m20, m12, c],
                         np.c_[m01, m12, m20]])
    return v2, f2


MESH_CASES = {"10k": ("rocker-arm.obj", 0), "100k": ("cheburashka.obj", 2),
              "1M": ("nefertiti.obj", 2)}
GRID_CASES = {"10k": 100, "100k": 316, "1M": 1000}


def build_domain(kind: str, size: str):
    if kind == "grid":
        s = GRID_CASES[size]
        return Grid((s, s)), f"grid {s}x{s}"
    name, levels = MESH_CASES[size]
    mesh = load_mesh(MESHES / name)
    v, f = mesh.vertices, mesh.faces
    for _ in range(levels):
        v, f = subdivide(v, f)
    return TriangleMesh(v, f), f"{name} subdivided {levels}x"


def random_labels(rng, n: int, bins, k: int):
    labeled = rng.choice(n, k, replace=False)
    c = bins.centers
    mu = rng.uniform(0.15, 0.85, (k, 2))
    sd = rng.uniform(0.02, 0.08, (k, 2))
    w = rng.uniform(0.2, 0.8, k)[:, None]
    h = (w * np.exp(-0.5 * ((c[None] - mu[:, :1]) / sd[:, :1]) ** 2)
         + (1 - w) * np.exp(-0.5 * ((c[None] - mu[:, 1:]) / sd[:, 1:]) ** 2)) + 1e-9
    return labeled, h / h.sum(axis=1, keepdims=True)


def one_scale(kind: str, size: str, spsolve_levels: int | None,
              amg_columns: int | None = None, repeat: int = 1) -> dict:
    """One row of part ``scale`` (run in a fresh process, so the peak RSS is this row's).

    The Wasserstein and PDF routes are timed as a user gets them after upload: the domain,
    its Laplacian and its components are built first (reported, not timed), then
    ``dirichlet_system`` + ``propagate_histograms`` with their defaults (``linear_method="auto"``:
    the direct route, MKL PARDISO when the mkl wheel loads, else cholespy; the backend used
    is recorded), ``repeat`` times with a fresh factorization each (the row reports the
    median run and keeps all).  ``amg_columns``: solve only that many (centred) columns
    with AMG-CG and extrapolate to the solved rank (None: all, through
    ``propagate_histograms``).
    """
    load_start = load()  # before this process does any work
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    domain, label = build_domain(kind, size)
    _ = domain.laplacian, domain.component_labels  # built at upload, not in the route
    build_s = time.perf_counter() - t0
    n = domain.n
    bins = make_bins(lo=0.0, hi=1.0, count=NBINS)
    labeled, h = random_labels(rng, n, bins, max(1, n // 100))
    row = {"kind": kind, "size": size, "domain": label, "n": n, "labeled": len(labeled),
           "load_start": load_start,
           "domain_build_s": build_s, "rss_domain_gb": peak_rss_gb(),
           "threads": {v: os.environ.get(v) for v in
                       ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")},
           "utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())}
    # warm-up on a small problem: BLAS/OpenMP thread pools and the compiled (numba)
    # back-conversion start once per process
    from solvers import Graph

    warm = Graph(50, np.c_[np.arange(49), np.arange(1, 50)])
    propagate_histograms(warm, [0, 49], h[:2], bins=bins, levels=LEVELS)

    row["load_before"] = load()
    runs = []
    for _ in range(repeat):  # each repetition factors afresh (cached factor discarded)
        for key in domain.operators.keys():
            if key[0] == "histograms.dirichlet":
                domain.operators.discard(key)
        system = res = None
        t, cpu = time.perf_counter(), time.process_time()
        system = dirichlet_system(domain, labeled)  # what propagate_histograms uses (cached)
        factor_s = time.perf_counter() - t
        t = time.perf_counter()
        res = propagate_histograms(domain, labeled, h, bins=bins, levels=LEVELS)
        solve_s = time.perf_counter() - t
        runs.append({"factor_s": factor_s, "w_solve_s": solve_s,
                     "w_direct_total_s": factor_s + solve_s,
                     "w_direct_cpu_s": time.process_time() - cpu, "load": load()})
    med = sorted(runs, key=lambda x: x["w_direct_total_s"])[(len(runs) - 1) // 2]
    row.update({k: v for k, v in med.items() if k != "load"})  # the (lower) median run
    row["w_direct_runs"] = runs
    row["load_after_direct"] = load()
    row["backend"] = getattr(system.factor, "backend", "?")
    row["solver"] = res.linear_method
    row["rss_w_gb"] = peak_rss_gb()
    row["w_rank"] = res.rank
    row["w_residual"] = res.residual
    t = time.perf_counter()
    res_pdf = propagate_histograms(domain, labeled, h, bins=bins, method="pdf")
    row["pdf_solve_s"] = time.perf_counter() - t
    row["pdf_residual"] = res_pdf.residual
    row["rss_direct_gb"] = peak_rss_gb()
    del res_pdf

    from solvers.histograms import harmonic_extension, label_quantiles

    # AMG-preconditioned CG shared by all levels (same labels, fresh hierarchy)
    if amg_columns == 0:
        row.update(amg_setup_s=None, amg_solve_s=None, amg_total_s=None,
                   amg_iterations=None, amg_max_diff=None, amg_columns_run=0)
    else:
        t = time.perf_counter()
        amg = dirichlet_system(domain, labeled, linear_method="amg")
        row["amg_setup_s"] = time.perf_counter() - t
        if amg_columns is None:
            t = time.perf_counter()
            res_amg = propagate_histograms(domain, labeled, h, bins=bins, levels=LEVELS,
                                           linear_method="amg", tol=1e-8)
            row["amg_solve_s"] = time.perf_counter() - t
            row["amg_iterations"] = res_amg.iterations
            row["amg_max_diff"] = float(np.abs(res_amg.quantiles - res.quantiles).max())
            row["amg_columns_run"] = res_amg.rank
            del res_amg
        else:  # the first columns only (centred, as the route solves them), extrapolated
            c = amg_columns
            q = label_quantiles(res.levels, bins=bins, histograms=h)
            Vq = np.empty_like(q)
            Vq[np.searchsorted(amg.labeled, labeled)] = q
            cols = Vq[:, :c] - Vq[:, :c].mean(axis=0)
            t = time.perf_counter()
            ext = harmonic_extension(amg, cols + 0.0, tol=1e-8, rank_tol=0.0)
            per = (time.perf_counter() - t) / c
            row["amg_solve_s"] = per * res.rank
            row["amg_iterations"] = ext.iterations
            ref = res.quantiles[:, :c] - Vq[:, :c].mean(axis=0)
            row["amg_max_diff"] = float(np.abs(ext.values - ref).max())
            row["amg_columns_run"] = c
        row["amg_total_s"] = row["amg_setup_s"] + row["amg_solve_s"]
        row["load_after_amg"] = load()

    # per-quantile spsolve loop on the same reduced system (SuperLU: refactors per level)
    A = sp.csc_matrix(system.A)
    q = label_quantiles(res.levels, bins=bins, histograms=h)
    V = np.empty_like(q)
    V[np.searchsorted(system.labeled, labeled)] = q
    B = -(system.coupling @ V)
    count = LEVELS if spsolve_levels is None else min(spsolve_levels, LEVELS)
    t = time.perf_counter()
    for j in range(count):
        x = spla.spsolve(A, B[:, j])
    per = (time.perf_counter() - t) / count
    row["spsolve_levels_run"] = count
    row["spsolve_total_s"] = per * LEVELS
    row["spsolve_max_diff"] = float(np.abs(x - res.quantiles[system.free, count - 1]).max())
    row["rss_peak_gb"] = peak_rss_gb()
    row["load_after"] = load()
    return row


def route_only(kind: str, size: str, factorization: str = "auto") -> dict:
    """The Wasserstein route alone, on a domain as uploaded (warm BLAS).

    Timed: ``propagate_histograms`` from the label histograms to the output histograms —
    reduced Laplacian, factorization, block solve with its residual, back-conversion.  Not
    timed (reported beside): building the domain and its Laplacian and components, which
    the service does once at upload (its summary counts the components).
    """
    import solvers.histograms.dirichlet as dirichlet

    if factorization == "cholespy":  # what "auto" was before PARDISO (no mkl wheel)
        dirichlet.have_pardiso = lambda: False
    domain, label = build_domain(kind, size)
    t0 = time.perf_counter()
    _ = domain.laplacian, domain.component_labels
    prepare_s = time.perf_counter() - t0
    bins = make_bins(lo=0.0, hi=1.0, count=NBINS)
    labeled, h = random_labels(np.random.default_rng(0), domain.n, bins,
                               max(1, domain.n // 100))
    from solvers import Graph

    warm = Graph(50, np.c_[np.arange(49), np.arange(1, 50)])
    propagate_histograms(warm, [0, 49], h[:2], bins=bins, levels=LEVELS)
    l0 = load()
    t, cpu = time.perf_counter(), time.process_time()
    dirichlet_system(domain, labeled)
    factor_s = time.perf_counter() - t
    res = propagate_histograms(domain, labeled, h, bins=bins, levels=LEVELS)
    total = time.perf_counter() - t
    # CPU seconds of this process (all its threads): on a loaded machine the wall time
    # is stretched by waiting for a core, the CPU time much less
    return {"domain": label, "n": domain.n, "w_total_s": total,
            "w_total_cpu_s": time.process_time() - cpu, "factor_s": factor_s,
            "solve_and_back_s": total - factor_s, "laplacian_and_components_s": prepare_s,
            "backend": dirichlet_system(domain, labeled).factor.backend, "rss_gb": peak_rss_gb(),
            "load": [l0, load()], "residual": res.residual,
            "threads": os.environ.get("OMP_NUM_THREADS")}


SCALE_JSON = ROOT / "bench" / "results" / "histograms_scale.json"
SCALE_ROWS = [(k, s) for k in ("grid", "mesh") for s in ("10k", "100k", "1M")]
# spsolve levels run per size (the rest extrapolated); AMG columns (None: all)
SPSOLVE_RUN = {"10k": LEVELS, "100k": 5, "1M": 1}
AMG_RUN = {"10k": None, "100k": None, "1M": 10}
REPEAT = {"10k": 5, "100k": 9, "1M": 3}  # direct-route repetitions (median reported)
TARGETS = {"100k": (2.0, None), "1M": (30.0, 4.0)}


def scale_row(kind: str, size: str) -> dict:
    """Run one row of part ``scale`` in a fresh process and return its JSON."""
    cmd = [sys.executable, __file__, "--one", kind, size, "--spsolve-levels",
           str(SPSOLVE_RUN[size]), "--amg-columns", str(AMG_RUN[size] or -1),
           "--repeat", str(REPEAT[size])]
    out = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        print(out.stderr[-3000:], file=sys.stderr)
        raise SystemExit(f"{kind} {size} failed")
    return json.loads(out.stdout.strip().splitlines()[-1])


def part_scale(quick: bool, only: list[str] | None = None, render: bool = False
               ) -> list[str]:
    """Run the rows (all, or ``only`` = ["grid:100k", ...]) one process at a time, store
    them in ``histograms_scale.json`` (a rerun replaces its row; the replaced run is kept
    under ``superseded``) and render the table from all stored rows (``render``: only
    render)."""
    sizes = ["10k", "100k"] if quick else ["10k", "100k", "1M"]
    wanted = [(k, s) for k, s in SCALE_ROWS if s in sizes]
    if only:
        wanted = [tuple(o.split(":")) for o in only]
    stored = json.loads(SCALE_JSON.read_text()) if SCALE_JSON.exists() else {}
    for kind, size in [] if render else wanted:
        row = scale_row(kind, size)
        print(json.dumps(row), flush=True)
        key = f"{kind}:{size}"
        if key in stored:
            row["superseded"] = stored[key].get("superseded", []) + [
                {k: v for k, v in stored[key].items() if k != "superseded"}]
        stored[key] = row
        SCALE_JSON.write_text(json.dumps(stored, indent=1) + "\n")
    return scale_table([stored[f"{k}:{s}"] for k, s in SCALE_ROWS if f"{k}:{s}" in stored])


def _verdict(r: dict) -> str:
    if r["size"] not in TARGETS:
        return ""
    t_max, gb_max = TARGETS[r["size"]]
    ok = r["w_direct_total_s"] <= t_max and (gb_max is None or r["rss_w_gb"] <= gb_max)
    text = f"≤ {t_max:.0f} s" + (f", ≤ {gb_max:.0f} GB" if gb_max else "")
    text += ": **met**" if ok else ": **missed**"
    worst = max([r["load_before"], r["load_after_direct"]]
                + [x["load"] for x in r.get("w_direct_runs", [])])
    if worst > 2:
        text += f" (load {worst:.1f} > 2: not decisive)"
    return text


def _spread(r: dict) -> str:
    runs = [x["w_direct_total_s"] for x in r.get("w_direct_runs", [])]
    if len(runs) < 2:
        return ""
    return f"; median of {len(runs)}, {min(runs):.2f}-{max(runs):.2f}"


def _median_of(r: dict) -> str:
    runs = r.get("w_direct_runs", [])
    return f" (median of {len(runs)})" if len(runs) > 1 else ""


def _fmt(x, spec=".2f") -> str:
    return "—" if x is None else format(x, spec)


def fitted_exponents(rows: list[dict], key: str) -> tuple[float, list[float]]:
    """Least-squares slope p of log t = p log n + c over the rows, and the slopes between
    consecutive sizes."""
    x = np.log([r["n"] for r in rows])
    y = np.log([r[key] for r in rows])
    return float(np.polyfit(x, y, 1)[0]), list(np.diff(y) / np.diff(x))


def scale_table(rows: list[dict]) -> list[str]:
    backends = sorted({r["backend"] for r in rows})
    threads = sorted({str(r["threads"].get("OMP_NUM_THREADS")) for r in rows})
    lines = [
        "## Scale (Prop. 13): 100 levels, 1 % labeled, 32 bins",
        "",
        "Command: `flock /tmp/otgeo-timing.lock env OMP_NUM_THREADS=2 OPENBLAS_NUM_THREADS=2 "
        "MKL_NUM_THREADS=2 .venv/bin/python bench/histograms.py --part scale` (one process "
        "per row, one row at a time; a row rerun with `--part scale --rows KIND:SIZE` "
        "replaces its row, raw rows in `bench/results/histograms_scale.json`). "
        f"Measured {min(r['utc'] for r in rows)} - {max(r['utc'] for r in rows)} UTC; "
        f"threads {', '.join(threads)}; direct backend: {', '.join(backends)}.",
        "",
        "Direct = what `propagate_histograms` does by default (`linear_method=\"auto\"`): sparse "
        "Cholesky of the reduced Laplacian (MKL PARDISO when the mkl wheel loads, else "
        "cholespy; factorization once per labeled set, cached) + one block solve of the "
        "(compressed) 100 columns + inverse CDFs back to histograms; timed from the label "
        "histograms to the output histograms on a domain whose Laplacian and components "
        "were built beforehand (as at upload; that build is the `build` column, not timed "
        "in the route); the median of several runs (5 at 10k, 9 at 100k, 3 at 1M), each "
        "factoring afresh, with the range of the runs. PDF = the same Dirichlet problem on "
        "the 32 bins, on the cached "
        "factorization (solve + normalization only). AMG = pyamg smoothed aggregation + CG "
        "per column, tol 1e-8, hierarchy shared by all columns (`*`: the first 10 columns "
        "run and extrapolated to the solved rank; CG iterations then of the columns run). "
        "spsolve = `scipy.sparse.linalg.spsolve` (SuperLU, refactors per level) per level on "
        "the same reduced matrix (`*`: a few levels run and extrapolated linearly to 100). "
        "RSS: peak of the row's process after the Wasserstein route (domain build "
        "included), after the PDF route too (the Wasserstein result still held), in "
        "brackets after AMG and spsolve. Each row warms BLAS and the compiled "
        "back-conversion up on a 50-node problem first. Load: 1-minute load average at "
        "the row's start (before the domain build) / before the direct route / after it / "
        "at the end of the row; all but the first include this benchmark's own threads "
        "(up to 2 during the long rows).",
        "",
        "| domain | n | labeled | build (s) | direct: factor + solve = total (s) "
        "[CPU-s of that run] | rank | PDF on same factor (s) "
        "| AMG: setup + solve = total (s), CG its "
        "| spsolve loop (s) | spsolve / direct | peak RSS (GB): Wasserstein / + PDF "
        "(whole row) | target (direct) | load |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        star = "" if r["spsolve_levels_run"] == LEVELS else f"* ({r['spsolve_levels_run']} run)"
        if r["amg_columns_run"] == 0:
            amg = "not run"
        else:
            amg_star = "" if r["amg_columns_run"] == r["w_rank"] else (
                f"* ({r['amg_columns_run']} columns run)")
            amg = (f"{r['amg_setup_s']:.2f} + {r['amg_solve_s']:.2f} = "
                   f"{r['amg_total_s']:.2f}{amg_star}, {r['amg_iterations']}")
        lines.append(
            f"| {r['domain']} | {r['n']:,} | {r['labeled']:,} | {r['domain_build_s']:.1f} | "
            f"{r['factor_s']:.2f} + {r['w_solve_s']:.2f} = **{r['w_direct_total_s']:.2f}** "
            f"[{r['w_direct_cpu_s']:.1f}]{_spread(r)} | {r['w_rank']} | "
            f"{r['pdf_solve_s']:.2f} | {amg} | "
            f"{r['spsolve_total_s']:.1f}{star} "
            f"| {r['spsolve_total_s'] / r['w_direct_total_s']:.0f}× | {r['rss_w_gb']:.2f} / "
            f"{r['rss_direct_gb']:.2f} ({r['rss_peak_gb']:.2f}) | {_verdict(r)} | "
            f"{_fmt(r.get('load_start'))} / {r['load_before']:.2f} / "
            f"{r['load_after_direct']:.2f} / {r['load_after']:.2f} |")
    lines += ["", "Fitted exponent p of time ∝ n^p (least squares over the sizes of a family; "
              "in brackets the slope between consecutive sizes, 10k→100k, 100k→1M; "
              "extrapolated entries enter as extrapolated):", "",
              "| family | sizes | direct (Wasserstein) | PDF on same factor | AMG total "
              "| spsolve loop |", "|---|---|---|---|---|---|"]
    for kind in ("grid", "mesh"):
        rs = [r for r in rows if r["kind"] == kind]
        if len(rs) < 2:
            continue
        cells = []
        for key in ("w_direct_total_s", "pdf_solve_s", "amg_total_s", "spsolve_total_s"):
            rk = [r for r in rs if r.get(key) is not None]
            if len(rk) < 2:
                cells.append("—")
                continue
            p, local = fitted_exponents(rk, key)
            cells.append(f"{p:.2f} ({', '.join(f'{s:.2f}' for s in local)})")
        ns = ", ".join(format(r["n"], ",") for r in rs)
        lines.append(f"| {kind} | {ns} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("Largest differences to the direct result: " + ", ".join(
        f"{r['domain']}: AMG {_fmt(r['amg_max_diff'], '.1e')}, "
        f"spsolve {r['spsolve_max_diff']:.1e}" for r in rows)
        + ". Direct residuals (relative, block): " + ", ".join(
        f"{r['w_residual']:.1e}" for r in rows) + ".")
    old = [(r["domain"], s) for r in rows for s in r.get("superseded", [])]
    if old:
        lines += ["", "Earlier runs of these rows, replaced by the ones above (direct total: "
                  "one run, or the median of the runs; load before / after the direct route): "
                  + "; ".join(
                      f"{d}: {s['w_direct_total_s']:.2f} s"
                      f"{_median_of(s)}"
                      f" at load {s['load_before']:.2f} / {s['load_after_direct']:.2f} "
                      f"({s['utc']} UTC)" for d, s in old) + "."]
    lines.append("")
    return lines


# -- S¹ -------------------------------------------------------------------------------
def part_circle(quick: bool) -> list[str]:
    rng = np.random.default_rng(1)
    n = 300 if quick else 1000
    pts = rng.random((n, 2))
    g = knn_graph(pts, 4)
    bins = make_bins(lo=0.0, hi=2 * np.pi, count=36, periodic=True)
    k = n // 20
    labeled = rng.choice(n, k, replace=False)
    truth = np.mod(2 * np.pi * (pts[:, 0] + 0.5 * pts[:, 1]), 2 * np.pi)
    kappa = rng.uniform(5, 40, k)
    h = np.exp(kappa[:, None] * np.cos(bins.centers[None] - truth[labeled, None]))
    h /= h.sum(axis=1, keepdims=True)
    lines = ["## S¹ (§5.4): LP vs entropic route", ""]
    l0 = load()
    t = time.perf_counter()
    lp = propagate_circular(g, labeled, h, bins=bins)
    lp_s = time.perf_counter() - t
    l1 = load()
    rows = []
    for gamma in (None, (2 * np.pi / 36) ** 2):
        t = time.perf_counter()
        ent = propagate_circular(g, labeled, h, bins=bins, method="entropic", gamma=gamma,
                                 evaluate=False)
        ent_s = time.perf_counter() - t
        t = time.perf_counter()
        from solvers.histograms import circle_cost, dirichlet_value

        value = dirichlet_value(ent.histograms, g.edges, g.weights, circle_cost(bins))
        eval_s = time.perf_counter() - t
        rows.append((ent.gamma, ent_s, ent.iterations, ent.converged, value, eval_s,
                     float(np.abs(ent.histograms @ np.exp(1j * bins.centers)).mean())))
    l2 = load()
    free = np.setdiff1d(np.arange(n), labeled)
    R_lp = float(np.abs(lp.histograms[free] @ np.exp(1j * bins.centers)).mean())
    lines += [f"k-NN graph (k = 4, uniform weights) of {n} random points in the unit square: "
              f"{len(g.edges)} edges; {k} labeled nodes (von Mises, κ in [5, 40], angle "
              f"2π(x + y/2)); 36 bins. LP: {len(g.edges) * 36 * 36 + (n - k) * 36:,} "
              "variables, HiGHS through `scipy.optimize.linprog`.", "",
              "| route | γ | time (s) | iterations | exact objective Σ w W₂² | gap to LP | "
              "mean resultant length (free nodes) | load |", "|---|---|---|---|---|---|---|---|",
              f"| LP (HiGHS) | – | {lp_s:.2f} | {lp.iterations} | {lp.value:.5f} | 0 | "
              f"{R_lp:.3f} | {l0:.2f} → {l1:.2f} |"]
    for gamma, ent_s, it, conv, value, eval_s, R in rows:
        lines.append(f"| entropic (Alg. 4, periodic 1-D grid) | {gamma:.4f} | {ent_s:.2f} "
                     f"(+ {eval_s:.1f} exact evaluation) | {it}{'' if conv else ' (not conv.)'}"
                     f" | {value:.5f} | +{value - lp.value:.5f} "
                     f"({100 * (value - lp.value) / lp.value:.0f} %) | {R:.3f} | {l1:.2f} → "
                     f"{l2:.2f} |")
    lines.append("")
    print("\n".join(lines), flush=True)
    return lines


# -- real data (Fig. 5.6) -----------------------------------------------------------------
def label_set(rng, mesh, fraction):
    n = mesh.n
    k = max(1, int(round(fraction * n)))
    lab = set(rng.choice(n, k, replace=False).tolist())
    comp = mesh.component_labels
    for c in range(mesh.n_components):  # one per component the draw missed
        members = np.flatnonzero(comp == c)
        if not lab.intersection(members.tolist()):
            lab.add(int(rng.choice(members)))
    return np.array(sorted(lab))


REAL_LINE = ["cow.obj", "spot.obj", "homer.obj", "fandisk.obj", "rocker-arm.obj"]
REAL_CIRCLE = ["suzanne.obj", "beetle.obj"]  # woody.obj is planar (no curvature)
FRACTIONS = (0.01, 0.05, 0.10)
RADII = (1.5, 3.0)
CIRCLE_TRIALS = 5  # one S¹ LP takes ~10-60 s on these meshes: 5 trials, radius 1.5 h only


def _trial_errors(mesh, truth, bins, lab, circular_graph=None):
    free = np.setdiff1d(np.arange(mesh.n), lab)
    t = time.perf_counter()
    if circular_graph is None:
        w = propagate_histograms(mesh, lab, truth[lab], bins=bins, levels=LEVELS)
    else:
        w = propagate_circular(circular_graph, lab, truth[lab], bins=bins)
    elapsed = time.perf_counter() - t
    p = propagate_histograms(mesh, lab, truth[lab], bins=bins, method="pdf")
    ts = S.std(truth[free], bins)
    return (w1_distance(w.histograms[free], truth[free], bins).mean(),
            w1_distance(p.histograms[free], truth[free], bins).mean(),
            np.abs(S.std(w.histograms[free], bins) - ts).mean(),
            np.abs(S.std(p.histograms[free], bins) - ts).mean(), elapsed)


def _real_rows(names, trials, quantity, bins_for, circular: bool) -> list[str]:
    lines = []
    for name in names:
        mesh = load_mesh(MESHES / name)
        values = quantity(mesh)
        bins = bins_for(values)
        graph = as_graph(mesh) if circular else None
        for radius in (RADII[:1] if circular else RADII):
            truth = neighbourhood_histograms(mesh, values, bins, radius * mesh.mean_edge_length)
            for frac in FRACTIONS:
                l0 = load()
                rng = np.random.default_rng(7)
                e = np.array([_trial_errors(mesh, truth, bins, label_set(rng, mesh, frac), graph)
                              for _ in range(trials)])
                ew, ep, sw, sp_, tl = e.T
                lines.append(
                    f"| {name} | {mesh.n} | {radius:g} h | {100 * frac:.0f} % | {ew.mean():.4f} "
                    f"± {ew.std():.4f} | {ep.mean():.4f} ± {ep.std():.4f} | "
                    f"{ep.mean() / ew.mean():.2f} | {int((ew < ep).sum())}/{trials} | "
                    f"{sw.mean():.4f} / {sp_.mean():.4f} | {tl.mean():.2f} | {l0:.2f} / "
                    f"{load():.2f} |")
                print(lines[-1], flush=True)
    return lines


REAL_HEADER = ("| mesh | V | radius | labeled | {w} W1 | PDF W1 | PDF / {w} | {w} wins (of "
               "trials) | std error {w} / PDF | {w} time per trial (s) | load before/after |")


def part_real(quick: bool) -> list[str]:
    trials = 4 if quick else 20
    lines = ["## Real data (Fig. 5.6 protocol)", "",
             f"Mean W1 error per unlabeled vertex (against the true neighbourhood histogram), "
             f"averaged over {trials} random labelings (± one standard deviation over trials); "
             "std error: mean |std(predicted) - std(true)| per unlabeled vertex. "
             "Neighbourhood: vertices within `radius` along mesh edges (h: mean edge length). "
             "W1 on S¹: min over rotations of the CDF difference.", "",
             "### Prob(ℝ): mean curvature, 24 bins over its 1st-99th percentile", "",
             REAL_HEADER.format(w="Wasserstein"), "|---|---|---|---|---|---|---|---|---|---|---|"]

    def line_bins(v):
        lo, hi = np.percentile(v, [1, 99])
        return make_bins(lo=lo, hi=hi, count=24)

    lines += _real_rows(REAL_LINE[:2] if quick else REAL_LINE, trials, mean_curvature,
                        line_bins, circular=False)
    lines += ["", "### S¹: principal-direction angle, 12 periodic bins on [0, π), exact LP "
              "(HiGHS) on the mesh's robust-Laplacian weights", "",
              f"{min(trials, CIRCLE_TRIALS)} trials per row and radius 1.5 h only (one LP "
              "takes tens of seconds here); woody.obj is planar, so suzanne and beetle.", "",
              REAL_HEADER.format(w="LP"), "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += _real_rows(REAL_CIRCLE[:1] if quick else REAL_CIRCLE, min(trials, CIRCLE_TRIALS),
                        principal_direction_angles,
                        lambda v: make_bins(lo=0.0, hi=np.pi, count=12, periodic=True),
                        circular=True)
    lines.append("")
    return lines


# -- results file ------------------------------------------------------------------------
SECTION = re.compile(r"^## ", re.M)


def write(parts: dict[str, list[str]], command: str) -> None:
    old = RESULTS.read_text() if RESULTS.exists() else ""
    kept = {}
    for block in SECTION.split(old)[1:]:
        title = block.splitlines()[0]
        key = ("scale" if title.startswith("Scale") else "circle" if title.startswith("S¹")
               else "real" if title.startswith("Real") else None)
        if key:
            kept[key] = ("## " + block.rstrip("\n")).split("\n")
    header = [
        "# bench/histograms.py — Wasserstein propagation of histograms (thesis ch. 5)", "",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}; BLAS/OpenMP threads "
        f"{os.environ.get('OMP_NUM_THREADS')}. Last command: `{command}` "
        f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}). The 1-minute load average "
        "is given per row (before/after).", ""]
    if "--render" in command and old.startswith("# "):  # nothing ran: keep the old header
        header = old.split("\n## ", 1)[0].rstrip("\n").split("\n") + [""]
    body = []
    for key in ("scale", "circle", "real"):
        if key in parts:
            body += parts[key]
            # the section's dated ### subsections (separate runs) stay below its table
            sub = None if key != "scale" else next(
                (i for i, line in enumerate(kept.get(key, [])) if line.startswith("### ")),
                None)
            if sub is not None:
                body += kept[key][sub:] + [""]
        elif key in kept:
            body += kept[key] + [""]
    notes = old.split("## Reading notes", 1)
    tail = ["## Reading notes" + notes[1].rstrip("\n"), ""] if len(notes) == 2 else []
    RESULTS.write_text("\n".join(header + body + tail).rstrip("\n") + "\n")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--part", default="all", choices=["scale", "circle", "real", "all"])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--one", nargs=2, metavar=("KIND", "SIZE"))
    ap.add_argument("--spsolve-levels", type=int, default=LEVELS)
    ap.add_argument("--amg-columns", type=int, default=-1,
                    help="with --one: AMG columns to run (-1 all, 0 none)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="with --one: direct-route repetitions (median reported)")
    ap.add_argument("--rows", nargs="+", metavar="KIND:SIZE",
                    help="with --part scale: rerun only these rows (e.g. mesh:100k)")
    ap.add_argument("--render", action="store_true",
                    help="with --part scale: rewrite the table from the stored rows, run nothing")
    ap.add_argument("--route-only", nargs=2, metavar=("KIND", "SIZE"),
                    help="time the Wasserstein route alone on one domain (prints JSON)")
    ap.add_argument("--factorization", default="auto",
                    help="direct factorization for --route-only: auto, pardiso, cholespy")
    args = ap.parse_args()
    if args.route_only:
        print(json.dumps(route_only(*args.route_only, args.factorization)))
        return
    if args.one:
        cols = None if args.amg_columns < 0 else args.amg_columns
        print(json.dumps(one_scale(args.one[0], args.one[1], args.spsolve_levels, cols,
                                   args.repeat)))
        return
    command = "python bench/histograms.py " + " ".join(sys.argv[1:])
    parts = {}
    if args.part in ("scale", "all"):
        parts["scale"] = part_scale(args.quick, args.rows, args.render)
        write(parts, command)
    if args.part in ("circle", "all"):
        parts["circle"] = part_circle(args.quick)
        write(parts, command)
    if args.part in ("real", "all"):
        parts["real"] = part_real(args.quick)
        write(parts, command)


if __name__ == "__main__":
    main()
