"""All-pairs geodesics as artifacts of a stored domain (issue 42): the spot 100 x 100 W2 matrix.

``cpu bench nice -n 0 env OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
.venv/bin/python bench/geodesic_artifacts.py`` stores spot afresh in a temporary service store,
then runs, each in a new process:

* ``cold`` — the matrix (100 bumps ``{"vertex": i, "radius": 0.1}``, vertices drawn with seed
  0 as in ``bench/distance_matrix.py spot``, default decision: the exact route) on the domain
  loaded from the store: the all-pairs geodesics are computed (in worker processes over the
  sources) and stored; then the same matrix again in that process (``warm``);
* ``artifact`` — the matrix in a new process, which reads the stored geodesics (memory-mapped)
  and solves none (counted);
* ``float64`` — the matrix on the float64 geodesics the cold run computed, without the store:
  the largest change float32 storage makes in a geodesic and in a W2 value.

Writes ``bench/results/geodesic_artifacts.md`` (command, load, CPU model).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MESHES = ROOT.parent / "shared" / "meshes"
RESULT = ROOT / "bench" / "results" / "geodesic_artifacts.md"

from _common import cpu_model, load1, service_bump  # noqa: E402

COUNT, RADIUS = 100, 0.1


def _masses(mesh) -> np.ndarray:
    idx = np.random.default_rng(0).choice(mesh.n, COUNT, replace=False)
    return np.stack([service_bump(mesh, int(i), RADIUS) for i in idx], axis=1)


def _counted():
    """Wrap the all-pairs computation and the MMP solves with counters and a timer."""
    import solvers.geodesics as g

    calls = {"all_pairs": 0, "solves": 0, "all_pairs_seconds": 0.0}
    all_pairs, one_to_all = g.all_pairs_geodesics, g._one_to_all

    def counted_all_pairs(*args, **kwargs):
        calls["all_pairs"] += 1
        dtype = kwargs.pop("dtype", np.float64)
        start = time.perf_counter()
        d = all_pairs(*args, **kwargs)  # float64 kept for the comparison, then cast
        calls["all_pairs_seconds"] += time.perf_counter() - start
        calls["float64"] = d
        return d.astype(dtype)

    def counted_one_to_all(*args, **kwargs):
        calls["solves"] += 1
        return one_to_all(*args, **kwargs)

    g.all_pairs_geodesics, g._one_to_all = counted_all_pairs, counted_one_to_all
    return calls


def _timed_matrix(domain, masses):
    from solvers.convolutional import distance_matrix

    start = time.perf_counter()
    res = distance_matrix(domain, masses)
    return time.perf_counter() - start, res


def child(phase: str, data: str, domain_id: str, work: str) -> dict:
    """One phase in this (new) process; returns its figures."""
    from service.store import Store
    from solvers import load_mesh

    calls = _counted()
    out = {"phase": phase, "load_start": load1()}
    if phase == "float64":
        mesh = load_mesh(MESHES / "spot.obj")
        d64 = np.load(Path(work) / "geodesics64.npy")
        mesh.operators.get(("exact_geodesics",), lambda: d64)
        out["seconds"], res = _timed_matrix(mesh, _masses(mesh))
    else:
        domain = Store(data).load_domain(domain_id)
        out["seconds"], res = _timed_matrix(domain, _masses(domain))
        if phase == "cold":
            np.save(Path(work) / "geodesics64.npy", calls.pop("float64"))
            out["warm_seconds"], again = _timed_matrix(domain, _masses(domain))
            assert np.array_equal(again.values, res.values, equal_nan=True)
    calls.pop("float64", None)
    np.save(Path(work) / f"{phase}.npy", res.values)
    kinds, counts = np.unique(res.methods, return_counts=True)
    out.update(calls=calls, load_end=load1(),
               methods={str(k): int(v) for k, v in zip(kinds, counts, strict=True)})
    return out


def _run_child(phase: str, data: str, domain_id: str, work: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "child", phase, data, domain_id, work],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    from service.store import Store
    from solvers import load_mesh
    from solvers.domains.mesh import GEODESICS_ARTIFACT

    start_load = load1()
    with tempfile.TemporaryDirectory() as tmp:
        store = Store(Path(tmp) / "data")
        meta, _ = store.put_domain(load_mesh(MESHES / "spot.obj"))
        phases = {p: _run_child(p, str(store.root), meta["id"], tmp)
                  for p in ("cold", "artifact", "float64")}
        d32 = store.domain_artifacts(meta["id"]).get(GEODESICS_ARTIFACT)
        d64 = np.load(Path(tmp) / "geodesics64.npy")
        finite = np.isfinite(d64)
        d_change = float(np.abs(d32[finite].astype(np.float64) - d64[finite]).max())
        v32, v64 = np.load(Path(tmp) / "artifact.npy"), np.load(Path(tmp) / "float64.npy")
        cold = np.load(Path(tmp) / "cold.npy")
        off = ~np.eye(COUNT, dtype=bool)
        w_change = float((np.abs(v32[off] - v64[off]) / np.abs(v64[off])).max())
        same = bool(np.array_equal(cold, v32))
        artifact_bytes = (store.domain_artifacts(meta["id"]).folder
                          / f"{GEODESICS_ARTIFACT}.npy").stat().st_size
    _write(phases, d_change, float(d64[finite].max()), w_change, same, artifact_bytes,
           start_load)


def _write(phases, d_change, d_max, w_change, same, artifact_bytes, start_load) -> None:
    cold, art, f64 = phases["cold"], phases["artifact"], phases["float64"]
    lines = [
        "# Geodesic cost matrices as domain artifacts (spot, 100 x 100 W2)", "",
        "Command: `cpu bench nice -n 0 env OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 "
        "OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/geodesic_artifacts.py`", "",
        f"CPU: {cpu_model()}; 1-minute load at start {start_load:.2f}, at end {load1():.2f}.",
        "", "100 bumps of radius 0.1 (vertices drawn with seed 0), default decision "
        f"(methods: {cold['methods']}); spot freshly stored in a new service store; each "
        "row a new process.", "",
        "| run | seconds | all-pairs computations | MMP solves in the process | load start / end |",
        "| --- | --- | --- | --- | --- |",
        f"| cold (computes and stores the geodesics) | {cold['seconds']:.1f} (of which "
        f"geodesics {cold['calls']['all_pairs_seconds']:.1f}) | {cold['calls']['all_pairs']} "
        f"| {cold['calls']['solves']} | {cold['load_start']:.2f} / {cold['load_end']:.2f} |",
        f"| warm (same process, second matrix) | {cold['warm_seconds']:.1f} | 0 | 0 | |",
        f"| from the artifact (new process) | {art['seconds']:.1f} | "
        f"{art['calls']['all_pairs']} | {art['calls']['solves']} | {art['load_start']:.2f} "
        f"/ {art['load_end']:.2f} |",
        f"| float64 geodesics, no store (reference) | {f64['seconds']:.1f} | "
        f"{f64['calls']['all_pairs']} | {f64['calls']['solves']} | "
        f"{f64['load_start']:.2f} / {f64['load_end']:.2f} |", "",
        f"Artifact: {artifact_bytes / 1e6:.1f} MB (float32). Float32 storage changes a "
        f"geodesic by at most {d_change:.3g} (largest geodesic {d_max:.3g}) and a W2 value by "
        f"at most {w_change:.3g} relative (off-diagonal entries, against the float64 "
        f"geodesics). Cold and artifact matrices equal: {same}.", "",
        "The cold run's MMP solves run in its forked worker processes (one per CPU), not "
        "counted by the process's counter; its one all-pairs computation is all of them.", "",
    ]
    RESULT.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "child":
        print(json.dumps(child(*sys.argv[2:6])))
    else:
        main()
