"""Benchmark the §2.7 applications at scale: path planning (eq. 2.6) and W1 barycenters
(eq. 2.7) on ~10k- and ~50k-vertex meshes.

Path planning: the vertex-sized interior point (``method="ipm"``, certified relative gap
1e-6) beside Clarabel on the whole program (``"socp"``, 10k only) in the same run, with the
ratio.  Barycenters (Dirac inputs): the vertex-sized interior point of
:mod:`solvers.emd.interior_point_barycenter` (certified relative gap 1e-6) beside Clarabel on
the whole coupled program (size caps lifted, 10k only), each solve in a fresh process whose
peak resident memory above its baseline is recorded beside the modelled cost
(:func:`~solvers.emd.interior_point_barycenter.estimated_cost`) the service admits jobs by.

Run: ``cpu bench .venv/bin/python bench/w1_applications.py``; with ``--barycenter`` only the
barycenter rows run, and only that section of the results file is rewritten (with its own
command and load).  Writes ``bench/results/w1_applications.md``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import load1, service_bump  # noqa: E402

import solvers.emd.exact as exact  # noqa: E402
from solvers.domains import load_mesh  # noqa: E402
from solvers.emd.interior_point_barycenter import estimated_cost  # noqa: E402
from solvers.emd.path_planning import w1_path_planning  # noqa: E402

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
OUT = Path(__file__).resolve().parent / "results" / "w1_applications.md"
BARYCENTER_TIME_LIMIT = 300.0  # s: Clarabel stops there (status "MaxTime")
SIZES = [("rocker-arm.obj", True), ("nefertiti.obj", False)]  # (mesh, run the SOCP peers)


def _timed(fn):
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def path_rows(mesh, name, with_socp):
    rng = np.random.default_rng(0)
    m0 = 0.5 * service_bump(mesh, 0, 0.1) + 0.5 * service_bump(mesh, mesh.n // 2, 0.1)
    exits = rng.choice(mesh.n, 40, replace=False)
    rows = []
    for eps in (0.0, 1e-3):
        ipm, t_ipm = _timed(lambda eps=eps: w1_path_planning(mesh, m0, exits, epsilon=eps,
                                                              method="ipm"))
        row = [name, mesh.n, eps, f"{ipm.objective:.6f}", ipm.iterations, f"{t_ipm:.2f}",
               str(ipm.converged)]
        if with_socp:
            socp, t_socp = _timed(lambda eps=eps: w1_path_planning(
                mesh, m0, exits, epsilon=eps, method="socp", max_vertices=10**7))
            rel = abs(ipm.objective - socp.objective) / socp.objective
            row += [f"{socp.objective:.6f}", f"{t_socp:.2f} [{t_socp / t_ipm:.1f}x]",
                    f"{rel:.1e}"]
        else:
            row += ["not run", "", ""]
        rows.append(row + [f"{load1():.2f}"])
        print(rows[-1], flush=True)
    return rows


BARYCENTER_CASES = [("rocker-arm.obj", 3, True), ("rocker-arm.obj", 6, False),
                    ("nefertiti.obj", 3, False)]  # (mesh, Dirac inputs, run Clarabel too)


def _peak_rss() -> int:
    """Peak resident set size of this process (bytes)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0


def _rss() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def barycenter_case(name: str, k: int, algorithm: str) -> dict:
    """One barycenter solve (run in a fresh process by ``--case``): k Diracs at vertices
    spread over the index range, uniform weights."""
    mesh = load_mesh(MESHES / name)
    M = np.zeros((mesh.n, k))
    M[[i * mesh.n // k for i in range(k)], np.arange(k)] = 1.0
    exact.MAX_BLOCK_UNKNOWNS = 10**9  # lift the conic program's caps for the measurement
    baseline = _rss()
    res, t = _timed(lambda: exact.w1_barycenter(
        mesh, M, method=algorithm, max_vertices=10**7,
        time_limit=BARYCENTER_TIME_LIMIT if algorithm == "socp" else None))
    model = estimated_cost(mesh.n, mesh.n_faces, k)
    return {"V": mesh.n, "F": mesh.n_faces, "value": res.value, "iterations": res.iterations,
            "time": t, "status": res.status, "gap": res.gap, "converged": res.converged,
            "residual": res.residual, "memory": _peak_rss() - baseline,
            "model_seconds": model.seconds, "model_bytes": model.bytes}


def _run_case(name: str, k: int, algorithm: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "--case", name, str(k), algorithm],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def barycenter_rows():
    rows = []
    for name, k, with_socp in BARYCENTER_CASES:
        ipm = _run_case(name, k, "ipm")
        row = [name, ipm["V"], k, f"{ipm['value']:.6f}", ipm["iterations"],
               f"{ipm['gap']:.1e}", f"{ipm['residual']:.1e}", str(ipm["converged"]),
               f"{ipm['time']:.2f}",
               f"{ipm['model_seconds']:.1f}", f"{ipm['memory'] / 2**20:.0f}",
               f"{ipm['model_bytes'] / 2**20:.0f}"]
        if with_socp:
            socp = _run_case(name, k, "socp")
            rel = abs(ipm["value"] - socp["value"]) / socp["value"]
            row += [f"{socp['value']:.6f}", socp["status"],
                    f"{socp['time']:.2f} [{socp['time'] / ipm['time']:.1f}x]", f"{rel:.1e}"]
        else:
            row += ["not run", "", "", ""]
        rows.append(row + [f"{load1():.2f}"])
        print(rows[-1], flush=True)
    return rows


def _table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


BARYCENTER_HEADING = "## W1 barycenter, eq. 2.7 (`w1_barycenter`)"


def barycenter_section(barys, command: str = "", loads: tuple[float, float] | None = None):
    run = "" if loads is None else (
        f"Run on its own: `{command}`; load average (1 min) before {loads[0]:.2f}, after "
        f"{loads[1]:.2f}.  ")
    return f"""{BARYCENTER_HEADING}

{run}k Dirac inputs (vertices i V / k), uniform weights.  `ipm`: the vertex-sized interior point
(`method="ipm"`, the default), certified relative gap 1e-6 (`gap` is the measured one;
`residual` the largest divergence-constraint violation, converged needs <= 1e-6);
`socp`: Clarabel on the whole coupled program (tol 1e-8, caps lifted, time limit
{BARYCENTER_TIME_LIMIT:.0f} s), same run, 10k only.  Each solve runs in a fresh process;
memory = its peak resident set above the resident set before the solve (MiB).  `model`: the
service's admission estimate (`estimated_cost`; refused above 300 s or the job memory limit).

{_table(["mesh", "V", "k", "ipm objective", "ipm iterations", "gap", "residual", "converged",
         "ipm time (s)", "model (s)", "memory (MiB)", "model (MiB)", "socp objective",
         "socp status", "socp time (s) [x ipm]", "rel. diff", "load"], barys)}
"""


def main_barycenter():
    """Only the barycenter rows; the path-planning section of the results file is kept."""
    before = load1()
    barys = barycenter_rows()
    after = load1()
    head = OUT.read_text().split(BARYCENTER_HEADING)[0] if OUT.exists() else ""
    command = ("cpu bench env OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python "
               "bench/w1_applications.py --barycenter")
    text = head + barycenter_section(barys, command, (before, after))
    OUT.write_text(text)
    print(text)


def main():
    before = load1()
    paths = []
    for name, with_socp in SIZES:
        paths += path_rows(load_mesh(MESHES / name), name, with_socp)
    barys = barycenter_rows()
    after = load1()
    text = f"""# §2.7 applications at scale: path planning (eq. 2.6), W1 barycenters (eq. 2.7)

Machine: {platform.machine()}, Python {platform.python_version()}, BLAS threads pinned to 1;
`cpu bench .venv/bin/python bench/w1_applications.py`.  Load average (1 min) before
{before:.2f}, after {after:.2f}; per row in the last column.  Targets of issue 26: 10k
vertices <= 10 s, 50k <= 60 s.

## Path planning (`w1_path_planning`)

Occupants: two service bumps (radius 0.1); 40 random exit vertices.  `ipm`: vertex-sized
interior point, certified relative gap 1e-6; `socp`: Clarabel on the whole program (tol
1e-8), same run; ratio = socp time / ipm time; rel. diff = |objective difference| / socp.

{_table(["mesh", "V", "epsilon", "ipm objective", "ipm iterations", "ipm time (s)",
         "ipm converged", "socp objective", "socp time (s) [x ipm]", "rel. diff", "load"],
        paths)}

{barycenter_section(barys)}"""
    OUT.write_text(text)
    print(text)


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "--case":
        print(json.dumps(barycenter_case(sys.argv[2], int(sys.argv[3]), sys.argv[4])))
    elif sys.argv[1:] == ["--barycenter"]:
        main_barycenter()
    else:
        main()
