"""Benchmark W1 matrices by d_W^k (thesis §2.5) on nefertiti: 1,000 x 10 bumps (issue 42).

Rows: 1,000 service bumps (``{"vertex": i, "radius": r}``: masses ``a_j max(0, 1 - |x_j -
x_i| / r)`` at unit area) with radii uniform in [0.05, 0.2] at random (seeded) centres;
columns: 10 more (another seed).  Per k in (0, 5, 20, 50, 100): ``dwk_matrix(mesh, rows, columns,
k=k)`` end to end (the mesh operators' factorization is reported apart, once per mesh; the
spectral reduction, once per mesh and k, is counted in the row), and the relative error of
20 sampled entries against the certified interior-point W1 (``earth_movers_distance``
defaults, gap 1e-4), median and worst.  ``--rows-k`` limits the rows of the k > 0 runs
(the time is then extrapolated linearly in pairs, and marked so).

Run: ``cpu bench nice -n 0 env OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
NUMBA_NUM_THREADS=2 .venv/bin/python bench/dwk_matrix.py`` (writes
bench/results/dwk_matrix.md).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
MESHES = ROOT.parent / "shared" / "meshes"
if not MESHES.exists():
    MESHES = Path("/work/shared/meshes")

from _common import cpu_model, load1, service_bump  # noqa: E402

from solvers.domains import load_mesh  # noqa: E402
from solvers.emd import earth_movers_distance, mesh_operators  # noqa: E402
from solvers.emd.dwk import reduced_spectral_problem  # noqa: E402
from solvers.emd.dwk_matrix import default_k, dwk_matrix, embed, estimate_seconds  # noqa: E402

KS = (0, 5, 20, 50, 100)
SAMPLES = 20


def bumps(mesh, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centres = rng.choice(mesh.n, count, replace=False)
    radii = rng.uniform(0.05, 0.2, count)
    return np.stack([service_bump(mesh, int(c), float(r))
                     for c, r in zip(centres, radii, strict=True)], axis=1)


def reference(mesh, rows, cols, sample) -> list:
    """Certified interior-point W1 of the sampled pairs: ``(value, lower_bound, seconds)``."""
    out = []
    for i, j in sample:
        start = time.perf_counter()
        res = earth_movers_distance(mesh, rows[:, i], cols[:, j])
        out.append((res.value, res.lower_bound, time.perf_counter() - start))
        print(f"  W1 {i},{j}: {res.value:.5f} gap {res.residual:.1e} "
              f"{out[-1][2]:.1f} s", flush=True)
    return out


def run_k(mesh, ops, rows, cols, k: int, n_rows: int, sample) -> dict:
    """One k: reduction, then the matrix on ``n_rows`` rows; its sampled entries."""
    load_before = load1()
    start = time.perf_counter()
    if k:
        reduced_spectral_problem(ops, k)
    reduce_s = time.perf_counter() - start
    start = time.perf_counter()
    res = dwk_matrix(mesh, rows[:, :n_rows], cols, k=k)
    matrix_s = time.perf_counter() - start
    full = rows.shape[1] * cols.shape[1]
    its = res.pair_iterations
    return {"k": k, "rows": n_rows, "reduce": reduce_s, "matrix": matrix_s,
            "total": reduce_s + matrix_s * full / (n_rows * cols.shape[1]),
            "extrapolated": n_rows < rows.shape[1], "its": (np.median(its), its.max()),
            "gap": res.residual, "converged": res.converged,
            "values_sample": [float(res.values[i, j]) for i, j in sample],
            "median": float("nan"), "worst": float("nan"), "best": float("nan"),
            "above": False,
            "estimate": estimate_seconds(mesh.n, ops.n_faces, k, rows.shape[1] + cols.shape[1],
                                         full),
            "load": (load_before, load1())}


def table(rows_out: list) -> list:
    out = ["| k | rows timed | reduction (s) | matrix (s) | end to end, 1000 x 10 (s) "
           "| ADMM its median / max | worst gap | median err | worst err | best err "
           "| all ≥ W1 lower bound | estimate (s) | load |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows_out:
        mark = " (extrapolated)" if r["extrapolated"] else ""
        out.append(f"| {r['k']} | {r['rows']} | {r['reduce']:.1f} | {r['matrix']:.1f} "
                   f"| **{r['total']:.1f}**{mark} | {r['its'][0]:.0f} / {r['its'][1]} "
                   f"| {r['gap']:.1e} | {100 * r['median']:.1f} % | {100 * r['worst']:.1f} % "
                   f"| {100 * r['best']:.1f} % | {r['above']} | {r['estimate']:.0f} "
                   f"| {r['load'][0]:.2f} / {r['load'][1]:.2f} |")
    return out


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--mesh", default="nefertiti.obj")
    parser.add_argument("--rows", type=int, default=1000)
    parser.add_argument("--rows-k", type=int, default=1000,
                        help="rows of the k > 0 runs (time extrapolated to all rows)")
    parser.add_argument("--ks", default=",".join(map(str, KS)))
    parser.add_argument("--out", default=str(ROOT / "bench" / "results" / "dwk_matrix.md"))
    args = parser.parse_args()
    warm = load_mesh(MESHES / "woody.obj")  # compile (or load) the numba kernels first
    dwk_matrix(warm, bumps(warm, 4, 0), k=0)
    dwk_matrix(warm, bumps(warm, 4, 0), k=5)
    load_start = load1()
    start = time.perf_counter()
    mesh = load_mesh(MESHES / args.mesh)
    ops = mesh_operators(mesh)
    setup_s = time.perf_counter() - start
    start = time.perf_counter()
    rows, cols = bumps(mesh, args.rows, 0), bumps(mesh, 10, 2)
    bump_s = time.perf_counter() - start
    rng = np.random.default_rng(7)
    cells = rng.choice(min(args.rows, args.rows_k) * 10, SAMPLES, replace=False)
    sample = [divmod(int(c), 10) for c in cells]  # distinct (row, column) of every run
    start = time.perf_counter()
    embed(ops, np.hstack([rows, cols]))
    embed_s = time.perf_counter() - start
    print(f"embedding {rows.shape[1] + 10} distributions: {embed_s:.1f} s", flush=True)
    ks = [int(x) for x in args.ks.split(",")]
    results = []
    for k in ks:
        results.append(run_k(mesh, ops, rows, cols, k, args.rows if k == 0 else args.rows_k,
                             sample))
        print(table(results)[-1], flush=True)
    ref_start = time.perf_counter()
    ref = reference(mesh, rows, cols, sample)
    ref_s = time.perf_counter() - ref_start
    w1 = np.array([r[0] for r in ref])
    lb = np.array([r[1] for r in ref])
    for r in results:  # errors against the reference
        vals = np.array(r.pop("values_sample"))
        err = (vals - w1) / w1
        r.update(median=float(np.median(err)), worst=float(err.max()),
                 best=float(err.min()), above=bool(np.all(vals >= lb)))
    write(args, mesh, ops, (setup_s, bump_s, embed_s, ref_s), results, load_start)


def write(args, mesh, ops, seconds, results, load_start) -> None:
    setup_s, bump_s, embed_s, ref_s = seconds
    n_pairs = args.rows * 10
    dk = default_k(mesh.n, ops.n_faces, args.rows + 10, n_pairs)
    good = [r["k"] for r in results if r["median"] <= 0.05]
    lines = [f"# bench/dwk_matrix.py — W1 matrices by d_W^k ({args.mesh}, {args.rows} x 10)",
             "", f"Command: `cpu bench nice -n 0 env OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 "
             f"OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=2 .venv/bin/python bench/dwk_matrix.py"
             f"{' --rows-k ' + str(args.rows_k) if args.rows_k != 1000 else ''}` "
             f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}).", "",
             f"Machine: {cpu_model()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}; BLAS 1 thread, numba 2 threads. Load (1-minute "
             f"average) at start {load_start:.2f}, at end {load1():.2f}.", "",
             f"Mesh: V = {mesh.n}, F = {ops.n_faces}; operators (Laplacian factorization, once "
             f"per mesh): {setup_s:.1f} s; {args.rows + 10} bumps: {bump_s:.1f} s (not counted); "
             f"embedding all {args.rows + 10} (one Poisson solve each, in blocks of 64; "
             f"part of every row's matrix time): {embed_s:.1f} s. "
             f"Errors: {SAMPLES} sampled entries against the certified interior-point W1 "
             f"(reference: {ref_s:.0f} s for the {SAMPLES} pairs). 'End to end' = spectral "
             f"reduction (once per mesh and k) + embedding + pairs.", ""]
    lines += table(results)
    tried = [r["k"] for r in results]
    lines += ["", f"Default k for these sizes (`default_k`, budget 60 s): **{dk}**. "
              f"k with median error ≤ 5 %: {good if good else f'none of {tried}'}."]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
