"""Benchmark d_W^k (k > 0) one source to all vertices beside the thesis' Table 2.1.

The thesis (§2.5, Table 2.1) reports 30.8 s for d_W^20 and 41.4 s for d_W^100 from one
source to every vertex of its ~3k-vertex "Bearing" model (MATLAB).  Here: the shared
meshes of that size, cow (2,903 vertices) and spot (welded, 2,930), source vertex 0, all
vertices as targets, ``pointwise_distances(mesh, 0, k=k)`` with its defaults (certified
relative duality gap 1e-3 per target, :mod:`solvers.emd.dwk`).

Per row: the spectral reduction, paid once per mesh and k (eigenbasis, frames, QR; the
Poisson and curl factorizations before it are reported apart), the one-to-all solve,
ADMM iterations per target (median / max), the worst certified gap, converged targets,
the service's cost estimate (``estimate_seconds``), the thesis figure and the ratio
thesis / ours.  Peer in the same run: the library's one-pair ADMM over the same spectral
basis (``earth_movers_distance(..., method="admm", basis="spectral", k=k)``, its
default tolerance) on ``--pairs`` targets, timed and extrapolated to all vertices, with
the largest relative difference of its values from the batched ones.

BLAS pinned to one thread (the fused ADMM pass runs on both cores through numba).  Run:
``cpu bench .venv/bin/python bench/dwk.py`` (writes bench/results/dwk.md).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MESHES = ROOT.parent / "shared" / "meshes"

from bench._common import load1  # noqa: E402
from solvers.domains import load_mesh  # noqa: E402
from solvers.emd import earth_movers_distance, mesh_operators, pointwise_distances  # noqa: E402
from solvers.emd.dwk import reduced_spectral_problem  # noqa: E402
from solvers.emd.pointwise import estimate_seconds  # noqa: E402

THESIS = {20: 30.8, 100: 41.4}  # seconds, Table 2.1, "Bearing", one source to all vertices
SOURCE = 0


def setup(name: str):
    start = time.perf_counter()
    mesh = load_mesh(MESHES / name, weld=name.startswith("spot"))
    ops = mesh_operators(mesh)
    _ = ops.curl_factor, ops.harmonic_fields
    return mesh, ops, time.perf_counter() - start


def direct_peer(mesh, k: int, batched, n_pairs: int) -> tuple[float, float]:
    """One-pair ADMM on ``n_pairs`` spread targets: (seconds extrapolated to all
    vertices, max relative difference from the batched values)."""
    targets = np.linspace(1, mesh.n - 1, n_pairs).astype(int)
    source = np.zeros(mesh.n)
    source[SOURCE] = 1.0
    diffs, start = [], time.perf_counter()
    for t in targets:
        target = np.zeros(mesh.n)
        target[t] = 1.0
        res = earth_movers_distance(mesh, source, target, method="admm", basis="spectral",
                                    k=k)
        diffs.append(abs(res.value - batched[t]) / res.value)
    per_pair = (time.perf_counter() - start) / n_pairs
    return per_pair * mesh.n, max(diffs)


def row(name: str, k: int, n_pairs: int) -> str:
    load_before = load1()
    mesh, ops, setup_s = setup(name)
    start = time.perf_counter()
    reduced_spectral_problem(ops, k)
    reduce_s = time.perf_counter() - start
    start = time.perf_counter()
    res = pointwise_distances(mesh, SOURCE, k=k)
    solve_s = time.perf_counter() - start
    its = res.target_iterations
    est = estimate_seconds(mesh.n, mesh.n_faces, k, mesh.n, False)
    peer_s, peer_diff = direct_peer(mesh, k, res.distances, n_pairs) if n_pairs else (
        float("nan"), float("nan"))
    line = (f"| {name} | {mesh.n} | {mesh.n_faces} | {k} | {setup_s:.2f} | {reduce_s:.2f} "
            f"| **{solve_s:.1f}** | {int(np.median(its))} / {int(its.max())} "
            f"| {res.residual:.1e} | {int(res.converged_targets.sum())} / {len(its)} "
            f"| {est:.1f} | {THESIS[k]} | {THESIS[k] / solve_s:.1f}x "
            f"| {peer_s:.0f} ({peer_s / solve_s:.0f}x) | {peer_diff:.1e} "
            f"| {load_before:.2f} / {load1():.2f} |")
    print(line, flush=True)
    return line


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--pairs", type=int, default=8,
                        help="targets of the one-pair ADMM peer (0: skip)")
    parser.add_argument("--meshes", nargs="+", default=["cow.obj", "spot.obj"])
    args = parser.parse_args()
    warm = load_mesh(MESHES / "woody.obj")  # compile (or load) the numba kernels first
    pointwise_distances(warm, 0, k=5, targets=np.arange(1, 40))
    lines = ["# bench/dwk.py — d_W^k one source to all vertices (thesis Table 2.1)", "",
             f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}, BLAS pinned to 1 thread, numba on both cores. "
             f"Command: `cpu bench .venv/bin/python bench/dwk.py"
             f"{' --pairs ' + str(args.pairs) if args.pairs != 8 else ''}` "
             f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}).", "",
             "Source vertex 0, every vertex a target, default tolerance (certified relative "
             "duality gap 1e-3 per target). Setup: mesh operators, Poisson and curl "
             "factorizations, harmonic fields (once per mesh); reduction: eigenbasis + "
             "frames + QR (once per mesh and k). Peer: one-pair ADMM over the same basis "
             "on a few targets, extrapolated to all vertices; 'diff': its largest relative "
             "difference from the batched value. Load: 1-minute average before / after "
             "the row.", "",
             "| mesh | V | F | k | setup (s) | reduction (s) | one-to-all d_W^k (s) "
             "| ADMM its median / max | worst gap | converged | estimate (s) "
             "| thesis MATLAB (s) | thesis / ours | one-pair ADMM, extrapolated (s) "
             "| diff | load |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in args.meshes:
        for k in (20, 100):
            lines.append(row(name, k, args.pairs))
    out = ROOT / "bench" / "results" / "dwk.md"
    out.write_text("\n".join(lines) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
