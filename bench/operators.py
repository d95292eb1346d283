"""Benchmark mesh loading, operator construction and the heat-kernel linear solves.

For every mesh in ``../shared/meshes`` (measured in one run, same process):

- load: ``load_mesh(path)`` (parse OBJ, clean, topology and diagnostics);
- build: first access of ``areas``, ``cotan_laplacian``, ``robust_laplacian`` (intrinsic
  Delaunay, robust-laplacian) and ``gradient`` on a fresh ``TriangleMesh`` built from arrays;
- factor: the heat-kernel system ``D_a + t L`` (robust L, t = mean_edge_length**2) with
  cholespy (the default backend) and with scipy's ``splu`` (the reference);
- solve: time per right-hand side for 1 RHS and for a 16-column block, both backends.

The ``splu/chol`` columns are speed-ups of cholespy over splu (> 1: cholespy faster).
``max rel diff`` compares the two backends' solutions (a correctness check).

Run: ``.venv/bin/python bench/operators.py`` (about a minute).  Writes
``bench/results/operators.md`` and prints the same table.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from datetime import UTC, datetime
from importlib.metadata import version
from pathlib import Path

import numpy as np
import scipy
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from solvers.domains import TriangleMesh, load_mesh  # noqa: E402
from solvers.linalg import factorize_spd  # noqa: E402

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
RESULTS = Path(__file__).resolve().parent / "results" / "operators.md"
BLOCK = 16


def best_of(fn, repeats: int) -> tuple[float, object]:
    """Minimum wall time of ``repeats`` calls (seconds) and the last result."""
    best, out = np.inf, None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - start)
    return best, out


def per_rhs(factor, rhs: np.ndarray, repeats: int) -> float:
    """Median seconds per right-hand side of ``factor.solve(rhs)``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        factor.solve(rhs)
        times.append(time.perf_counter() - start)
    k = 1 if rhs.ndim == 1 else rhs.shape[1]
    return float(np.median(times)) / k


def build_times(vertices, faces) -> dict[str, float]:
    m = TriangleMesh(vertices, faces)
    out = {}
    for name in ("areas", "cotan_laplacian", "robust_laplacian", "gradient"):
        start = time.perf_counter()
        getattr(m, name)
        out[name] = time.perf_counter() - start
    return out


def bench_mesh(path: Path) -> dict:
    big = path.stat().st_size > 1_000_000
    load_s, mesh = best_of(lambda: load_mesh(path), 1 if big else 3)
    arrays = mesh.to_arrays()
    builds = [build_times(arrays["vertices"], arrays["faces"]) for _ in range(1 if big else 3)]
    build = {k: min(b[k] for b in builds) for k in builds[0]}
    t = mesh.mean_edge_length**2
    system = (sp.diags(mesh.areas) + t * mesh.robust_laplacian).tocsc()
    rng = np.random.default_rng(0)
    one = rng.random(mesh.n)
    block = rng.random((mesh.n, BLOCK))
    row = {"mesh": path.name, "V": mesh.n, "F": mesh.n_faces, "load": load_s, **build}
    solutions = {}
    for backend in ("cholespy", "splu"):
        factor_s, factor = best_of(lambda b=backend: factorize_spd(system, backend=b), 3)
        row[f"factor_{backend}"] = factor_s
        row[f"one_{backend}"] = per_rhs(factor, one, 15 if big else 40)
        row[f"block_{backend}"] = per_rhs(factor, block, 5 if big else 15)
        solutions[backend] = factor.solve(block)
    ref = solutions["splu"]
    row["rel_diff"] = float(np.abs(solutions["cholespy"] - ref).max() / np.abs(ref).max())
    residual = system @ solutions["cholespy"] - block
    row["residual"] = float(np.abs(residual).max() / np.abs(block).max())
    return row


def ms(seconds: float) -> str:
    return f"{1e3 * seconds:.1f}" if seconds >= 1e-3 else f"{1e3 * seconds:.3f}"


def table(rows: list[dict]) -> str:
    head = ("| mesh | V | F | load ms | areas ms | cotan L ms | robust L ms | gradient ms "
            "| factor chol ms | factor splu ms | splu/chol | 1 RHS chol ms | 1 RHS splu ms "
            "| splu/chol | 16 RHS chol ms/col | 16 RHS splu ms/col | splu/chol | max rel diff |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        lines.append(
            f"| {r['mesh']} | {r['V']} | {r['F']} | {ms(r['load'])} | {ms(r['areas'])} "
            f"| {ms(r['cotan_laplacian'])} | {ms(r['robust_laplacian'])} | {ms(r['gradient'])} "
            f"| {ms(r['factor_cholespy'])} | {ms(r['factor_splu'])} "
            f"| {r['factor_splu'] / r['factor_cholespy']:.2f} "
            f"| {ms(r['one_cholespy'])} | {ms(r['one_splu'])} "
            f"| {r['one_splu'] / r['one_cholespy']:.2f} "
            f"| {ms(r['block_cholespy'])} | {ms(r['block_splu'])} "
            f"| {r['block_splu'] / r['block_cholespy']:.2f} | {r['rel_diff']:.1e} |"
        )
    return "\n".join(lines)


def main() -> None:
    paths = sorted(MESHES.glob("*.obj"), key=lambda p: p.stat().st_size)
    if not paths:
        raise SystemExit(f"no meshes found in {MESHES}")
    load_before = os.getloadavg()
    started = datetime.now(UTC)
    rows = []
    for path in paths:
        row = bench_mesh(path)
        rows.append(row)
        print(f"{path.name}: V={row['V']} factor chol/splu {ms(row['factor_cholespy'])}/"
              f"{ms(row['factor_splu'])} ms, 1 RHS {ms(row['one_cholespy'])}/"
              f"{ms(row['one_splu'])} ms, 16 RHS {ms(row['block_cholespy'])}/"
              f"{ms(row['block_splu'])} ms per column", flush=True)
    load_after = os.getloadavg()
    worst_residual = max(r["residual"] for r in rows)
    text = "\n".join([
        "# Mesh operators and heat-kernel solves",
        "",
        "Generated by `.venv/bin/python bench/operators.py` "
        f"on {started:%Y-%m-%d %H:%M} UTC.",
        "",
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"cholespy {version('cholespy')}, robust-laplacian {version('robust-laplacian')}.  "
        f"Load average (1 min) {load_before[0]:.1f} before, {load_after[0]:.1f} after"
        + (": other jobs shared the two cores, so absolute times are noisy; "
           if max(load_before[0], load_after[0]) > 1 else "; ")
        + "the ratios compare backends measured back to back in the same process.",
        "",
        "System: `D_a + t L` with the robust (intrinsic-Delaunay) Laplacian, "
        "t = mean_edge_length², unit total area.  Times: load and build are the best of 3 "
        "(1 for the two large meshes); factor is the best of 3; solves are the median over "
        "repeated calls, reported per right-hand side.  `splu/chol` > 1 means cholespy is "
        "faster.  `max rel diff` = max |x_chol - x_splu| / max |x_splu| on the 16-column block; "
        f"worst relative residual of the cholespy solves {worst_residual:.1e}.",
        "",
        table(rows),
        "",
    ])
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print()
    print(text)


if __name__ == "__main__":
    main()
