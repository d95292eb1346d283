"""Working memory of a JSON domain's build against the estimate checked at submission
(``service.domain_builder.estimate_build_bytes``: a domain whose build would need more than
``OTGEO_JOB_MEMORY_BYTES`` is refused with 413 before it is built).

Each configuration runs in a fresh process: the spec is validated (as the API's parser
returns it), then ``build_domain`` runs and the peak resident memory (``VmHWM``) minus the
resident memory before is the build's working memory.

    cpu bench env OPENBLAS_NUM_THREADS=1 .venv/bin/python -P bench/domain_build_memory.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
ROOT = Path(__file__).resolve().parents[1]
CONFIGS = [  # (kind, size)
    ("pointcloud", 25_000), ("pointcloud", 100_000),
    ("graph", 200_000), ("graph", 800_000),
    ("mesh", 50_000), ("mesh", 200_000),
    ("grid", 250_000), ("grid", 1_000_000),
]


def status_kib(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def spec_of(kind: str, n: int) -> dict:
    import numpy as np

    rng = np.random.default_rng(0)
    if kind == "pointcloud":
        return {"kind": "pointcloud", "points": rng.normal(size=(n, 3)).tolist()}
    if kind == "graph":  # a ring with chords: 2 edges per node
        i = np.arange(n)
        edges = np.concatenate([np.stack([i, (i + 1) % n], 1),
                                np.stack([i, (i + 7) % n], 1)])
        return {"kind": "graph", "n_nodes": n, "edges": edges.tolist()}
    if kind == "mesh":  # a grid of squares, two triangles each
        side = int(np.sqrt(n))
        y, x = np.mgrid[0:side, 0:side]
        verts = np.stack([x.ravel(), y.ravel(), 0.1 * np.sin(x.ravel())], 1) / side
        idx = (y[:-1, :-1] * side + x[:-1, :-1]).ravel()
        faces = np.concatenate([np.stack([idx, idx + 1, idx + side], 1),
                                np.stack([idx + 1, idx + side + 1, idx + side], 1)])
        return {"kind": "mesh", "vertices": verts.tolist(), "faces": faces.tolist()}
    side = int(np.sqrt(n))
    return {"kind": "grid", "shape": [side, side]}


def one(kind: str, n: int) -> dict:
    sys.path.insert(0, str(ROOT))
    from pydantic import TypeAdapter

    from service.domain_builder import estimate_build_bytes
    from service.domains import build_domain, spec_size
    from service.schemas import DomainSpec
    from service.settings import Settings

    spec = TypeAdapter(DomainSpec).validate_python(spec_of(kind, n))
    field, points = spec_size(spec)
    estimate = estimate_build_bytes(spec)
    Path("/proc/self/clear_refs").write_text("5")
    before = status_kib("VmRSS")
    t0 = time.perf_counter()
    build_domain(Settings(data_dir="/tmp"), spec, {"format": "json"})
    seconds = time.perf_counter() - t0
    used = (status_kib("VmHWM") - before) * 1024
    return {"kind": kind, "points": points, "field": field, "seconds": seconds,
            "measured_mib": used / 2**20, "estimate_mib": estimate / 2**20}


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--one":
        print(json.dumps(one(sys.argv[2], int(sys.argv[3]))))
        return
    print(f"load before: {loadavg()}")
    print("| kind | points | build s | measured MiB | estimate MiB | estimate / measured |")
    print("|---|---|---|---|---|---|")
    for kind, n in CONFIGS:
        out = subprocess.run([sys.executable, "-P", __file__, "--one", kind, str(n)],
                             capture_output=True, text=True, cwd=ROOT)
        if out.returncode != 0:
            print(f"| {kind} | {n} | failed: {out.stderr.strip().splitlines()[-1][:200]} |")
            continue
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"| {kind} | {r['points']:,} | {r['seconds']:.1f} | {r['measured_mib']:.0f} | "
              f"{r['estimate_mib']:.0f} | {r['estimate_mib'] / max(r['measured_mib'], 1):.2f} |",
              flush=True)
    print(f"load after: {loadavg()}")


if __name__ == "__main__":
    main()
