"""Working memory of soft maps against the submission estimate (issue 31: 859 samples on
nefertiti, full-resolution target, peaked at ~4.4 GiB against an estimate of 3.99 GiB).

Each configuration runs in a fresh process: the meshes are loaded (domain operators built),
then one soft map runs with ``max_iter`` sweeps (the working arrays are allocated before the
first sweep, so a few sweeps reach the same peak as a converged run). Printed: the process's
resident memory before the call, its peak (``VmHWM``) during it, their difference (the job's
working memory), and the service's estimate (``service.operations.softmaps.estimate_bytes``).

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python -P bench/softmap_memory.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
MESHES = Path("/work/shared/meshes")
CONFIGS = [  # (mesh, samples, target_points)
    ("nefertiti.obj", 128, None),
    ("nefertiti.obj", 256, None),
    ("nefertiti.obj", 512, None),
    ("nefertiti.obj", 859, "auto"),
]


def status_kib(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def one(mesh: str, samples: int, target_points) -> dict:
    sys.path.insert(0, str(ROOT))
    from service.operations.softmaps import SoftMapRequest, estimate_sizes
    from solvers.domains import load_mesh
    from solvers.softmaps import soft_map

    domain = load_mesh(str(MESHES / mesh))
    pairs = [(0, 0), (domain.n // 2, domain.n // 2)]
    req = SoftMapRequest(source_id="a", target_id="b", samples=samples,
                         target_points=target_points,
                         landmarks=[{"source": s, "target": t} for s, t in pairs])
    estimate = estimate_sizes(domain.n, domain.n, req)["bytes"]
    soft_map(domain, domain, pairs, samples=8, max_iter=1, k=req.k)  # operators, eigenpairs
    before = status_kib("VmRSS")
    res = soft_map(domain, domain, pairs, samples=samples, target_points=target_points,
                   max_iter=3, k=req.k)
    peak = status_kib("VmHWM")
    return {"mesh": mesh, "n": domain.n, "samples": samples, "target_points": target_points,
            "solved": int(res.soft_map.shape[1]) if hasattr(res, "soft_map") else None,
            "rss_before_mib": before / 1024, "peak_mib": peak / 1024,
            "job_mib": (peak - before) / 1024, "estimate_mib": estimate / 2**20}


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--one":
        mesh, samples, tp = sys.argv[2], int(sys.argv[3]), json.loads(sys.argv[4])
        print(json.dumps(one(mesh, samples, tp)))
        return
    print("| mesh | n | samples | target_points | RSS before MiB | peak MiB | job MiB | "
          "estimate MiB | estimate / job | load before | load after |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for mesh, samples, tp in CONFIGS:
        before = loadavg()
        out = subprocess.run([sys.executable, "-P", __file__, "--one", mesh, str(samples),
                              json.dumps(tp)], capture_output=True, text=True, cwd=ROOT)
        if out.returncode != 0:
            print(out.stderr[-2000:])
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"| {r['mesh']} | {r['n']} | {r['samples']} | {r['target_points']} | "
              f"{r['rss_before_mib']:.0f} | {r['peak_mib']:.0f} | {r['job_mib']:.0f} | "
              f"{r['estimate_mib']:.0f} | {r['estimate_mib'] / max(r['job_mib'], 1):.2f} | "
              f"{before} | {loadavg()} |", flush=True)


if __name__ == "__main__":
    main()
