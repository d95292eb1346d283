"""Benchmark of soft maps (thesis ch. 4, §3.7) on the TOSCA cat/lion pair, peers in the same run.

Parts (``.venv/bin/python bench/softmaps.py [coarse] [gamma_floor] [growth] [multiscale]
[accuracy] [reverse] [scaling] [convergence] [propagation] ...``):

coarse
    the defaults (coarse target) at 128 and 1,024 samples, both directions, each warm in a
    fresh process (meshes rebuilt from stored arrays, as a service worker holds them);
    errors with and without refinement, held-out landmarks, peak RSS; pyFM in the same run.
gamma_floor
    1,024 samples, both directions: the default gamma (with the coarse target's floor)
    against gamma without the floor.
growth
    the defaults lion -> cat at ``SOFTMAPS_GROWTH`` samples (default 128 ... 4,096), one
    fresh process each: time, sweeps, residual, error, peak RSS.

accuracy
    lion -> cat, 5 landmark pairs (the first 5 of ``cat-lion-landmarks.txt``), score = mean
    geodesic error on the cat (heat-method distances, the same evaluator for every method)
    / sqrt(cat area).  otgeo: soft map with 1,024 source samples over all cat vertices
    (defaults: tol 1e-4, adaptive over-relaxation, residual reported), ZoomOut from the
    soft map's functional map.  pyFM
    (``pyfmaps``) with the settings the issue quotes from its example: WKS, 35 eigenpairs,
    the 5 landmarks, basic functional map (w_descr 1, w_lap 1e-2, w_dcomm 1e-1), then ICP
    and ZoomOut (15 steps of 1).  POT's
    ``ot.gromov.entropic_gromov_wasserstein`` on heat-method geodesic matrices of 500
    farthest-point samples per mesh (argmax of the plan, extended through Voronoi cells).
reverse
    the same comparison cat -> lion with the lion -> cat settings (ground truth: the inverse
    of the given map where it is defined), otgeo and pyFM.
scaling
    soft map time for 5 sweeps (warm: caches built by a first call) and peak memory of the
    call (tracemalloc), 128 ... 1,024 samples over 7,207 cat vertices; the time per sweep.
convergence
    the same soft map with the defaults, run to tol, warm, 128 ... 1,024 samples: sweeps,
    time, error and peak memory.
trace
    the default 1,024-sample soft map, warm: sweeps and seconds until the residual reaches
    1e-1 ... 1e-4, and the residual after 10 s (the issue's warm target).
continuation
    epsilon-scaling (stages at 8 / 4 / 2 x gamma, each warm-starting the next) against a cold
    start, same 1,024-sample problem: sweeps, work and seconds of each stage.
relaxation
    the work of a default propagation (kernel columns, in full sweeps of 2 x edges columns,
    and sweeps) with the over-relaxation's rate window at 5 sweeps (OverRelaxation's
    default) and 3 (the propagation's), 128 ... 1,024 samples, lion -> cat.
sweep_cost
    the wall time of one default propagation sweep (lion -> cat, 512 and 1,024 samples, mean
    of sweeps 4-13), the solvers package of commit ``SWEEP_BEFORE`` against the working tree,
    alternating in fresh processes so both see the same load.
propagation
    Alg. 4 before (the node-by-node code of commit 820e3ef) and after (colored batched
    sweeps) on one problem: time, sweeps, and the L1 gap between the two results.

BLAS threads are pinned to 1; ``/proc/loadavg`` is recorded around every figure.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
PAIRS = ROOT.parent / "shared" / "meshes" / "pairs"
RESULTS = ROOT / "bench" / "results" / "softmaps.json"
SCALING_SWEEPS = 5  # fixed sweeps per scaling row: time per sweep and peak memory
SCALING_SIZES = tuple(int(x) for x in os.environ.get("SOFTMAPS_SIZES", "128,256,512,1024")
                      .split(","))


# The meshes as a service worker holds them: stored arrays (``Domain.to_arrays()``), rebuilt
# without the mesh-file parser (trimesh, ~31 MB resident once imported); written by the
# parent of the fresh-process rows (:func:`_store_meshes`).
STORED = Path(os.environ.get("SOFTMAPS_STORED", "/tmp/otgeo_bench_softmaps_meshes.npz"))


def _store_meshes() -> None:
    cat, lion, _, _ = load()
    np.savez(STORED, **{f"cat_{k}": v for k, v in cat.to_arrays().items()},
             **{f"lion_{k}": v for k, v in lion.to_arrays().items()})


def load_stored():
    """``load()`` from the arrays of :func:`_store_meshes` (no mesh-file parser imported)."""
    from solvers.domains import domain_from_arrays

    with np.load(STORED) as data:
        cat, lion = (domain_from_arrays("mesh", {k: data[f"{name}_{k}"]
                                                 for k in ("vertices", "faces")})
                     for name in ("cat", "lion"))
    gt = np.loadtxt(PAIRS / "lion-to-cat.txt", dtype=np.int64)
    lm = np.loadtxt(PAIRS / "cat-lion-landmarks.txt", dtype=np.int64)[:5]
    return cat, lion, gt, lm


def load():
    import solvers

    cat = solvers.load_mesh(PAIRS / "cat-00.off", weld=False)  # keep the file's vertex order
    lion = solvers.load_mesh(PAIRS / "lion-00.off", weld=False)
    gt = np.loadtxt(PAIRS / "lion-to-cat.txt", dtype=np.int64)
    lm = np.loadtxt(PAIRS / "cat-lion-landmarks.txt", dtype=np.int64)[:5]
    return cat, lion, gt, lm


def _code() -> str:
    """Commit of the measured code (``+dirty`` when the solver files differ from it)."""
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(ROOT), "diff", "--quiet", "HEAD", "--",
                            "solvers/convolutional/propagation.py", "solvers/softmaps"]).returncode
    return head + ("+dirty" if dirty else "")


def loadavg() -> str:
    return " ".join(open("/proc/loadavg").read().split()[:3])


class Evaluator:
    """Mean geodesic error on the target / sqrt(area) (the target is at unit area), over the
    source vertices whose ground truth ``gt`` is not -1."""

    def __init__(self, target, gt):
        import potpourri3d as pp3d

        solver = pp3d.MeshHeatMethodDistanceSolver(target.vertices, target.faces)
        self.gt = np.asarray(gt)
        self.rows = {int(g): solver.compute_distance(int(g)) for g in np.unique(gt) if g >= 0}

    def __call__(self, corr) -> float:
        corr = np.asarray(corr)
        return float(np.mean([self.rows[int(g)][int(c)] for g, c in zip(self.gt, corr,
                                                                          strict=True)
                              if g >= 0]))


HELD_OUT = slice(5, None)  # landmark lines 6-20: never given to a method, scored only


def held_out_misses(target, corr, held_target, held_source) -> np.ndarray:
    """Geodesic distance on the target between where ``corr`` sends each held-out source
    landmark and its target landmark."""
    from solvers.softmaps.descriptors import geodesic_distances_from

    d = geodesic_distances_from(target, held_target)
    return d[np.asarray(corr)[held_source], np.arange(len(held_target))]


def reverse_truth(gt, n_cat: int) -> np.ndarray:
    """Cat -> lion ground truth from the lion -> cat map: for every cat vertex hit by the map,
    the first lion vertex mapped to it (-1 elsewhere)."""
    out = -np.ones(n_cat, np.int64)
    for lion_vertex in range(len(gt) - 1, -1, -1):
        out[gt[lion_vertex]] = lion_vertex
    return out


def _timed_soft_map(method: str, ev, source, target, pairs, **options):
    """(row, result) of one otgeo soft map call, scored by ``ev`` before and after
    refinement."""
    from solvers.softmaps import soft_map

    before = loadavg()
    t0 = time.perf_counter()
    res = soft_map(source, target, pairs, **options)
    row = {"method": method, "seconds": time.perf_counter() - t0, "code": _code(),
           "error_mode": ev(res.sample_correspondence[res.labels]),
           "error": ev(res.correspondence), "iterations": res.iterations,
           "residual": res.residual, "converged": res.converged, "timings": res.timings,
           "load_before": before, "load_after": loadavg()}
    print(row, flush=True)
    return row, res


def _peak_rss_mb() -> float:
    """The process's peak resident memory (``VmHWM``; ``ru_maxrss`` would carry the
    parent's over from the fork of a fresh-process row)."""
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _rss_mb() -> float:
    """The process's resident memory now (``VmRSS``)."""
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


COARSE_SIZES = (128, 1024)


def _one_coarse(direction: str, n: int, floor: bool = True) -> dict:
    """A warm default soft map (a first call builds the caches), ``direction`` "lion->cat"
    or "cat->lion", ``n`` samples; errors with and without refinement, held-out landmarks,
    the process's peak RSS.  ``floor=False``: gamma without the coarse-target floor
    (``COARSE_GAMMA_MIN``), all else the defaults."""
    from solvers.softmaps import soft_map
    from solvers.softmaps.coarse_target import coarse_target
    from solvers.softmaps.propagation_map import default_gamma

    cat, lion, gt, lm = load_stored()
    baseline = _rss_mb()  # interpreter, imports (numpy, scipy, numba), both meshes
    every = np.loadtxt(PAIRS / "cat-lion-landmarks.txt", dtype=np.int64)
    held = every[HELD_OUT]
    if direction == "lion->cat":
        source, target, truth, pairs = lion, cat, gt, lm[:, ::-1]
        held_t, held_s = held[:, 0], held[:, 1]
    else:
        source, target, truth, pairs = cat, lion, reverse_truth(gt, cat.n), lm
        held_t, held_s = held[:, 1], held[:, 0]
    gamma = None if floor else default_gamma(n, coarse_target(target, n).mesh)
    soft_map(source, target, pairs, samples=n, max_iter=2)  # caches: eigenpairs, samples, ...
    first_peak = _peak_rss_mb()
    resident = _rss_mb()  # with the caches and compiled kernels of the first call
    before = loadavg()
    t0 = time.perf_counter()
    res = soft_map(source, target, pairs, samples=n, gamma=gamma)
    seconds = time.perf_counter() - t0
    after = loadavg()
    rss = _peak_rss_mb()  # before the evaluator's distance rows
    ev = Evaluator(target, truth)
    misses = held_out_misses(target, res.correspondence, held_t, held_s)
    return {"direction": direction, "samples": n, "target_points": res.target_points,
            "gamma_floor": floor,
            "seconds": seconds, "timings": res.timings, "iterations": res.iterations,
            "residual": res.residual, "converged": res.converged, "gamma": res.gamma,
            "error": ev(res.correspondence),
            "error_mode": ev(res.sample_correspondence[res.labels]),
            "held_out_median": float(np.median(misses)), "held_out_max": float(misses.max()),
            "peak_rss_mb": rss, "baseline_rss_mb": baseline, "first_peak_rss_mb": first_peak,
            "resident_before_mb": resident, "code": _code(), "load_before": before,
            "load_after": after}


def part_coarse():
    """The defaults (coarse target, symmetric ZoomOut) at 128 and 1,024 samples, both
    directions, each in a fresh process, warm; pyFM in the same run."""
    rows = []
    _store_meshes()
    for direction in ("lion->cat", "cat->lion"):
        for n in COARSE_SIZES:
            out = subprocess.run([sys.executable, __file__, "_coarse", direction, str(n)],
                                 check=True, capture_output=True, text=True).stdout
            rows.append(json.loads(out.strip().splitlines()[-1]))
            print(rows[-1], flush=True)
    cat, lion, gt, lm = load()
    for row in _pyfm_rows(Evaluator(cat, gt), lm):
        rows.append({"direction": "lion->cat", **row})
    for row in _pyfm_rows(Evaluator(lion, reverse_truth(gt, cat.n)), lm[:, ::-1],
                          target="lion-00.off", source="cat-00.off"):
        rows.append({"direction": "cat->lion", **row})
    return rows


def part_gamma_floor():
    """1,024 samples, warm, each in a fresh process: the default gamma (with the coarse
    target's floor) against gamma without the floor, both directions."""
    rows = []
    _store_meshes()
    for direction in ("lion->cat", "cat->lion"):
        for floor in (True, False):
            out = subprocess.run([sys.executable, __file__, "_coarse", direction, "1024",
                                  "floor" if floor else "nofloor"],
                                 check=True, capture_output=True, text=True).stdout
            rows.append(json.loads(out.strip().splitlines()[-1]))
            print(rows[-1], flush=True)
    return rows


def part_multiscale():
    """1,024 samples, warm, defaults (coarse target), cold start against the start from a
    128-sample solve prolonged (``multiscale=True``), both directions, alternating."""
    from solvers.softmaps import soft_map

    cat, lion, gt, lm = load()
    rows = []
    for direction in ("lion->cat", "cat->lion"):
        if direction == "lion->cat":
            source, target, ev, pairs = lion, cat, Evaluator(cat, gt), lm[:, ::-1]
        else:
            source, target, ev, pairs = cat, lion, Evaluator(lion, reverse_truth(gt, cat.n)), lm
        soft_map(source, target, pairs, max_iter=2, multiscale=True)  # caches
        for multiscale in (False, True, False, True):
            before = loadavg()
            res = soft_map(source, target, pairs, multiscale=multiscale)
            rows.append({"direction": direction, "multiscale": multiscale,
                         "iterations": res.iterations, "converged": res.converged,
                         "seconds": res.timings["propagation"] + res.timings["multiscale"],
                         "error": ev(res.correspondence), "code": _code(),
                         "load_before": before, "load_after": loadavg()})
            print(rows[-1], flush=True)
    return rows


GROWTH_SIZES = tuple(int(x) for x in os.environ.get(
    "SOFTMAPS_GROWTH", "128,256,512,1024,2048,4096").split(","))


def _one_growth(n: int) -> dict:
    from solvers.softmaps import soft_map

    cat, lion, gt, lm = load_stored()
    baseline = _rss_mb()
    pairs = lm[:, ::-1]
    soft_map(lion, cat, pairs, samples=n, max_iter=2)  # caches
    resident = _rss_mb()
    before = loadavg()
    t0 = time.perf_counter()

    def progress(sweep, residual):  # to stderr: a long row shows where it stands
        if sweep % 50 == 0:
            print(f"{n} samples: sweep {sweep}, residual {residual:.3g}, "
                  f"{time.perf_counter() - t0:.0f} s, load {loadavg()}", file=sys.stderr,
                  flush=True)

    res = soft_map(lion, cat, pairs, samples=n, progress=progress)
    seconds = time.perf_counter() - t0
    rss = _peak_rss_mb()  # before the evaluator's distance rows
    return {"samples": n, "target_points": res.target_points, "seconds": seconds,
            "propagation": res.timings["propagation"], "iterations": res.iterations,
            "residual": res.residual, "baseline_rss_mb": baseline,
            "resident_before_mb": resident,
            "converged": res.converged, "edges": int(len(res.edges)),
            "error": Evaluator(cat, gt)(res.correspondence), "peak_rss_mb": rss,
            "code": _code(), "load_before": before, "load_after": loadavg()}


def part_growth():
    """One fresh process per size of ``SOFTMAPS_GROWTH``; the recorded rows of other sizes
    are kept (the largest size is run on its own)."""
    old = json.loads(RESULTS.read_text()).get("growth", {}) if RESULTS.exists() else {}
    rows = [r for r in old.get("rows", []) if r["samples"] not in GROWTH_SIZES]
    _store_meshes()
    for n in GROWTH_SIZES:
        out = subprocess.run([sys.executable, __file__, "_growth", str(n)], check=True,
                             stdout=subprocess.PIPE, text=True).stdout
        rows.append(json.loads(out.strip().splitlines()[-1]))
        print(rows[-1], flush=True)
    return sorted(rows, key=lambda r: r["samples"])


def _pyfm_rows(ev, lm, **meshes) -> list[dict]:
    try:
        return _pyfm(ev, lm, **meshes)
    except ImportError as exc:
        return [{"method": "pyFM", "error": None, "note": f"not installed: {exc}"}]


def part_accuracy():
    from solvers.softmaps import zoomout

    cat, lion, gt, lm = load()
    ev = Evaluator(cat, gt)
    pairs = lm[:, ::-1]  # (lion vertex, cat vertex)
    row, res = _timed_soft_map("otgeo soft map, 1024 samples, defaults (tol 1e-4), ZoomOut "
                               "(20, 50, 1) from its functional map (first call)", ev, lion,
                               cat, pairs, samples=1024)
    rows = [row]
    unrefined = res.sample_correspondence[res.labels]
    before = loadavg()
    t0 = time.perf_counter()
    wide = zoomout(lion, cat, unrefined, k_start=20, k_end=100, step=2)
    rows.append({"method": "same soft map, ZoomOut (20, 100, 2) from its modes",
                 "seconds": time.perf_counter() - t0, "error_mode": ev(unrefined),
                 "error": ev(wide), "load_before": before, "load_after": loadavg()})
    print(rows[-1], flush=True)
    rows += _pyfm_rows(ev, lm)
    rows += _pot_gw(cat, lion, ev)
    return rows


def _pyfm(ev, lm, target="cat-00.off", source="lion-00.off"):
    """pyFM's p2p maps its mesh2 (the source) to its mesh1 (the target); ``lm`` columns are
    (target vertex, source vertex)."""
    from pyFM.functional import FunctionalMapping
    from pyFM.mesh import TriMesh

    before = loadavg()
    t0 = time.perf_counter()
    mesh1 = TriMesh.load(str(PAIRS / target), area_normalize=True, center=True)
    mesh2 = TriMesh.load(str(PAIRS / source), area_normalize=True, center=True)
    model = FunctionalMapping(mesh1, mesh2)
    model.preprocess(n_descr=100, descr_type="WKS", landmarks=lm, subsample_step=5, K=35)
    model.fit(K=35, w_descr=1e0, w_lap=1e-2, w_dcomm=1e-1, w_orient=0)
    p2p = model.get_p2p(n_jobs=1)
    t_basic = time.perf_counter() - t0
    fm_icp = model.icp_refine(nit=10)
    p2p_icp = model.get_p2p(fm_icp, n_jobs=1)
    t_icp = time.perf_counter() - t0
    fm_zo = model.zoomout_refine(nit=15, step=1)
    p2p_zo = model.get_p2p(fm_zo, n_jobs=1)
    t_zo = time.perf_counter() - t0
    after = loadavg()
    out = []
    for name, p, t in (("basic", p2p, t_basic), ("ICP", p2p_icp, t_icp),
                       ("ZoomOut", p2p_zo, t_zo)):
        out.append({"method": f"pyFM {name}", "seconds": t, "error": ev(p),
                    "load_before": before, "load_after": after})
        print(out[-1], flush=True)
    return out


def _pot_gw(cat, lion, ev, n=500):
    import ot

    from solvers.softmaps.descriptors import geodesic_distances_from
    from solvers.softmaps.sampling import farthest_point_samples

    before = loadavg()
    t0 = time.perf_counter()
    s_l = farthest_point_samples(lion, n)
    s_c = farthest_point_samples(cat, n)
    C1 = geodesic_distances_from(lion, s_l.indices)[s_l.indices]
    C2 = geodesic_distances_from(cat, s_c.indices)[s_c.indices]
    p = np.bincount(s_l.labels, weights=lion.areas, minlength=n)
    q = np.bincount(s_c.labels, weights=cat.areas, minlength=n)
    out = []
    for eps in (5e-3, 1e-3):
        t1 = time.perf_counter()
        T = ot.gromov.entropic_gromov_wasserstein(C1, C2, p, q, "square_loss", epsilon=eps,
                                                  max_iter=200)
        corr = s_c.indices[np.argmax(T, axis=1)][s_l.labels]
        out.append({"method": f"POT entropic GW, {n} samples, eps {eps}",
                    "seconds": time.perf_counter() - t1 + (t1 - t0), "error": ev(corr),
                    "load_before": before, "load_after": loadavg()})
        print(out[-1], flush=True)
    return out


def _warm_traced(n: int, **options):
    """A warm soft map (caches built by a first call) with ``n`` samples, traced by
    tracemalloc (numpy's allocations: the arrays of the call).  Returns the result, its
    seconds, the traced peak in MiB, the load before, and the cat and its ground truth."""
    import tracemalloc

    from solvers.softmaps import soft_map

    cat, lion, gt, lm = load()
    pairs = lm[:, ::-1]
    soft_map(lion, cat, pairs, samples=n, **{**options, "max_iter": 2})  # build caches
    before = loadavg()
    tracemalloc.start()
    t0 = time.perf_counter()
    res = soft_map(lion, cat, pairs, samples=n, **options)
    dt = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return res, dt, peak, before, cat, gt


def _one_scaling(n: int) -> dict:
    res, dt, peak, before, _, _ = _warm_traced(n, refine="none", max_iter=SCALING_SWEEPS)
    return {"samples": n, "seconds": dt, "iterations": res.iterations,
            "residual": res.residual, "converged": res.converged,
            "seconds_per_sweep": res.timings["propagation"] / max(res.iterations + 1, 1),
            "peak_extra_mb": peak, "edges": int(len(res.edges)), "code": _code(),
            "load_before": before, "load_after": loadavg()}


def _one_convergence(n: int) -> dict:
    res, dt, peak, before, cat, gt = _warm_traced(n)  # defaults: tol 1e-4, ZoomOut
    return {"samples": n, "seconds": dt, "iterations": res.iterations,
            "residual": res.residual, "converged": res.converged, "timings": res.timings,
            "error": Evaluator(cat, gt)(res.correspondence), "peak_extra_mb": peak,
            "code": _code(), "load_before": before, "load_after": loadavg()}


def _per_size(kind: str) -> list[dict]:
    """One fresh process per size (``_scaling`` or ``_convergence``), so each call is warm
    in the same way and its memory is its own."""
    rows = []
    for n in SCALING_SIZES:
        out = subprocess.run([sys.executable, __file__, kind, str(n)], check=True,
                             capture_output=True, text=True).stdout
        rows.append(json.loads(out.strip().splitlines()[-1]))
        print(rows[-1], flush=True)
    return rows


def part_scaling():
    return _per_size("_scaling")


def part_convergence():
    return _per_size("_convergence")


def part_relaxation():
    import solvers.convolutional.propagation as propagation
    import solvers.softmaps.propagation_map as propagation_map
    from solvers.softmaps import soft_map

    cat, lion, gt, lm = load()
    pairs = lm[:, ::-1]
    runs = []
    inner = propagation_map.wasserstein_propagation

    def recorded(*args, **kwargs):  # keep the propagation's kernel_columns
        runs.append(inner(*args, **kwargs))
        return runs[-1]

    rows = []
    default = propagation._RELAX_WINDOW
    propagation_map.wasserstein_propagation = recorded
    try:
        for n in SCALING_SIZES:
            for window in (5, 3):
                propagation._RELAX_WINDOW = window
                before = loadavg()
                res = soft_map(lion, cat, pairs, samples=n, refine="none")
                rows.append({"samples": n, "window": window, "sweeps": res.iterations + 1,
                             "full_sweeps": runs[-1].kernel_columns / (2 * len(res.edges)),
                             "converged": res.converged, "residual": res.residual,
                             "propagation_seconds": res.timings["propagation"],
                             "code": _code(), "load_before": before, "load_after": loadavg()})
                print(rows[-1], flush=True)
    finally:
        propagation._RELAX_WINDOW = default
        propagation_map.wasserstein_propagation = inner
    return rows


TRACE_SAMPLES = 1024
TRACE_LEVELS = (1e-1, 1e-2, 1e-3, 1e-4)
TRACE_BUDGET = 10.0  # seconds: the warm target at 1,024 samples
CONTINUATION = (8.0, 4.0, 2.0)  # gamma factors of the epsilon-scaling stages
CONTINUATION_TOL = 1e-2  # each stage's tolerance


def part_trace():
    """The default 1,024-sample soft map, warm: sweeps and seconds until the residual first
    reaches each of ``TRACE_LEVELS``, and where it stands after ``TRACE_BUDGET`` seconds."""
    from solvers.softmaps import soft_map

    cat, lion, gt, lm = load()
    pairs = lm[:, ::-1]
    soft_map(lion, cat, pairs, samples=TRACE_SAMPLES, max_iter=2)  # build caches
    marks = []
    before = loadavg()
    t0 = time.perf_counter()
    res = soft_map(lion, cat, pairs, samples=TRACE_SAMPLES, refine="none",
                   progress=lambda it, r: marks.append((it + 1, r, time.perf_counter() - t0)))
    after = loadavg()
    rows = []
    for level in TRACE_LEVELS:
        hit = next((m for m in marks if m[1] <= level), None)
        rows.append({"at": f"residual <= {level:g}", "sweeps": hit and hit[0],
                     "residual": hit and hit[1], "seconds": hit and hit[2]})
    within = [m for m in marks if m[2] <= TRACE_BUDGET]
    last = within[-1] if within else (0, float("nan"), 0.0)
    rows.append({"at": f"after {TRACE_BUDGET:g} s", "sweeps": last[0], "residual": last[1],
                 "seconds": last[2]})
    for row in rows:
        row.update(samples=TRACE_SAMPLES, converged=res.converged, code=_code(),
                   load_before=before, load_after=after)
        print(row, flush=True)
    return rows


def part_continuation():
    """Epsilon-scaling against a cold start, same 1,024-sample problem and fixed point: the
    propagation is first solved at ``CONTINUATION`` x gamma (to ``CONTINUATION_TOL``), each
    stage warm-starting the next (``initial=``), then at the default gamma to the default
    tol.  Work in full sweeps (kernel columns / (2 x edges))."""
    import solvers.softmaps.propagation_map as propagation_map
    from solvers.softmaps import soft_map

    cat, lion, gt, lm = load()
    pairs = lm[:, ::-1]
    inner = propagation_map.wasserstein_propagation
    stages = []  # (variant, propagation result, seconds)

    def timed(name, *args, **kwargs):
        t0 = time.perf_counter()
        out = inner(*args, **kwargs)
        stages.append((name, out, time.perf_counter() - t0))
        return out

    def cold(*args, **kwargs):
        return timed("cold start (the default)", *args, **kwargs)

    def continued(*args, gamma, node_scalings, tol, **kwargs):
        prev = None
        for factor in CONTINUATION:
            prev = timed(f"stage {factor:g} x gamma, tol {CONTINUATION_TOL:g}", *args,
                         gamma=factor * gamma, node_scalings=node_scalings / factor,
                         tol=CONTINUATION_TOL, initial=prev, keep_scalings=True, **kwargs)
        return timed(f"final stage, default gamma, tol {tol:g}", *args, gamma=gamma,
                     node_scalings=node_scalings, tol=tol, initial=prev, **kwargs)

    rows = []
    try:
        for variant, wrapper in (("cold start", cold), ("epsilon-scaling", continued)):
            propagation_map.wasserstein_propagation = wrapper
            soft_map(lion, cat, pairs, samples=TRACE_SAMPLES, max_iter=2)  # build caches
            stages.clear()
            before = loadavg()
            res = soft_map(lion, cat, pairs, samples=TRACE_SAMPLES, refine="none")
            after = loadavg()
            ends = 2 * len(res.edges)
            parts = [(name, out.iterations + 1, out.kernel_columns / ends, out.residual,
                      out.converged, seconds) for name, out, seconds in stages]
            if len(parts) > 1:
                parts.append((f"{variant}, all stages", sum(p[1] for p in parts),
                              sum(p[2] for p in parts), res.residual, res.converged,
                              sum(p[5] for p in parts)))
            for name, sweeps, full, residual, converged, seconds in parts:
                rows.append({"variant": name, "sweeps": sweeps, "full_sweeps": full,
                             "residual": residual, "converged": converged,
                             "seconds": seconds, "code": _code(), "load_before": before,
                             "load_after": after})
                print(rows[-1], flush=True)
    finally:
        propagation_map.wasserstein_propagation = inner
    return rows


SWEEP_BEFORE = "6202226"  # the last commit before the GIL-free triangular solves


def _one_sweep_cost(n: int) -> dict:
    """Seconds per sweep of the code on ``sys.path[0]``: 13 sweeps minus 3 sweeps, warm."""
    from solvers.softmaps import soft_map

    cat, lion, gt, lm = load()
    pairs = lm[:, ::-1]
    soft_map(lion, cat, pairs, samples=n, max_iter=1, refine="none")  # compile, factor
    before = loadavg()
    spent = {}
    for sweeps in (3, 13):
        res = soft_map(lion, cat, pairs, samples=n, max_iter=sweeps, refine="none")
        spent[sweeps] = res.timings["propagation"]
    return {"samples": n, "seconds_per_sweep": (spent[13] - spent[3]) / 10,
            "residual_after_13": res.residual, "load_before": before, "load_after": loadavg()}


def part_sweep_cost():
    import tempfile

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", SWEEP_BEFORE, "solvers"],
                                 check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        for n in (512, 1024):
            for _ in range(2):
                for code, root in ((SWEEP_BEFORE, tmp), (_code(), str(ROOT))):
                    out = subprocess.run([sys.executable, __file__, "_sweep_cost", root, str(n)],
                                         check=True, capture_output=True, text=True).stdout
                    rows.append({"code": code, **json.loads(out.strip().splitlines()[-1])})
                    print(rows[-1], flush=True)
    return rows


def part_reverse():
    """The other direction, cat -> lion, with the settings chosen on lion -> cat (no retuning):
    a check that the comparison with pyFM does not hinge on the tuned direction."""
    cat, lion, gt, lm = load()
    ev = Evaluator(lion, reverse_truth(gt, cat.n))
    row, _ = _timed_soft_map("otgeo soft map cat -> lion, 1024 samples, defaults", ev, cat,
                             lion, lm, samples=1024)  # lm rows: (cat vertex, lion vertex)
    return [row] + _pyfm_rows(ev, lm[:, ::-1], target="lion-00.off", source="cat-00.off")


def part_propagation():
    import importlib.util
    import tempfile

    from solvers.convolutional import wasserstein_propagation
    from solvers.softmaps.sampling import farthest_point_samples

    cat, lion, gt, lm = load()
    src = subprocess.run(["git", "-C", str(ROOT), "show",
                          "820e3ef:solvers/convolutional/propagation.py"], check=True,
                         capture_output=True, text=True).stdout
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as fh:
        fh.write(src)
    spec = importlib.util.spec_from_file_location("prop_before", fh.name)
    old = importlib.util.module_from_spec(spec)
    sys.modules["prop_before"] = old
    spec.loader.exec_module(old)
    g = farthest_point_samples(lion, 128, lm[:, 1])
    fixed = {j: np.eye(1, cat.n, int(y))[0] for j, y in enumerate(lm[:, 0])}
    rows, ref = [], None
    for name, fn in (("before: node by node", old.wasserstein_propagation),
                     ("after: colored batched sweeps", wasserstein_propagation)):
        kw = dict(edge_weights=g.weights, gamma=0.004, tol=1e-12, max_iter=40)
        fn(cat, g.n, g.edges, fixed, **{**kw, "max_iter": 1})
        before = loadavg()
        t0 = time.perf_counter()
        r = fn(cat, g.n, g.edges, fixed, **kw)
        dt = time.perf_counter() - t0
        row = {"variant": name, "seconds": dt, "sweeps": r.iterations + 1,
               "residual": r.residual, "load_before": before, "load_after": loadavg()}
        if ref is None:
            ref = r.masses
        else:
            row["max_l1_gap_vs_before"] = float(np.abs(r.masses - ref).sum(axis=0).max())
        rows.append(row)
        print(row, flush=True)
    # Run to convergence: the same fixed point (cow, a 6 x 6 grid graph, 4 fixed bumps).
    from solvers import load_mesh

    cow = load_mesh(ROOT.parent / "shared" / "meshes" / "cow.obj")
    side = 6
    idx = np.arange(side * side).reshape(side, side)
    edges = np.concatenate([np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1),
                            np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1)])

    def bump(v):
        d = np.linalg.norm(cow.vertices - cow.vertices[v], axis=1)
        x = np.exp(-d**2 / 0.003) * cow.areas
        return x / x.sum()

    fixed = {int(idx[0, 0]): bump(10), int(idx[0, -1]): bump(900),
             int(idx[-1, 0]): bump(1800), int(idx[-1, -1]): bump(2500)}
    ref = None
    for name, fn in (("before (converged, cow 6x6 graph)", old.wasserstein_propagation),
                     ("after (converged, cow 6x6 graph)", wasserstein_propagation)):
        fn(cow, side * side, edges, fixed, gamma=0.01, max_iter=1)
        before = loadavg()
        t0 = time.perf_counter()
        r = fn(cow, side * side, edges, fixed, gamma=0.01, tol=1e-7, max_iter=5000)
        row = {"variant": name, "seconds": time.perf_counter() - t0,
               "sweeps": r.iterations + 1, "residual": r.residual, "load_before": before,
               "load_after": loadavg()}
        if ref is None:
            ref = r.masses
        else:
            row["max_l1_gap_vs_before"] = float(np.abs(r.masses - ref).sum(axis=0).max())
        rows.append(row)
        print(row, flush=True)
    return rows


def _accuracy_table(acc, title: str, description: str) -> list[str]:
    if not acc:
        return []
    out = [f"## {title} (run {acc['when']})", "", description, "",
           "| method | error | error before refinement | seconds | notes | load before "
           "| load after |", "|---|---|---|---|---|---|---|"]
    best_pyfm = min((r["error"] for r in acc["rows"] if r["method"].startswith("pyFM")
                     and r.get("error") is not None), default=None)
    for r in acc["rows"]:
        note = ""
        if "iterations" in r:
            note = (f"{r['iterations'] + 1} sweeps, residual {r['residual']:.3g}, "
                    f"converged {r['converged']}; " + ", ".join(
                        f"{k} {v:.1f} s" for k, v in r["timings"].items()))
        if r.get("note"):
            note = r["note"]
        err = "-" if r.get("error") is None else f"{1e3 * r['error']:.2f}e-3"
        pre = f"{1e3 * r['error_mode']:.2f}e-3" if "error_mode" in r else ""
        out.append(f"| {r['method']} | {err} | {pre} | {r.get('seconds', 0):.1f} | {note} "
                   f"| {r.get('load_before', '')} | {r.get('load_after', '')} |")
    if best_pyfm:
        ours = [r for r in acc["rows"] if r["method"].startswith("otgeo")]
        out += ["", "Ratios (otgeo refined error / best pyFM error of this run): " + ", ".join(
            f"{r['method']}: {r['error'] / best_pyfm:.3f}" for r in ours)]
    return out + [""]


def _table(part, title: str, description: str, header: list[str], cells) -> list[str]:
    """A markdown section for one recorded part: title with its run time, description, and
    one row of ``cells(row)`` per recorded row (plus the part's ``note``)."""
    if not part:
        return []
    out = [f"## {title} (run {part['when']})", "", description, "",
           "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in cells(r)) + " |" for r in part["rows"]]
    if part.get("note"):
        out += ["", part["note"]]
    return out + [""]


def render(data) -> str:
    """bench/results/softmaps.md from the recorded parts."""
    out = ["# Soft maps: TOSCA lion -> cat (bench/softmaps.py)", "",
           "Written by `.venv/bin/python bench/softmaps.py [parts]`; every figure carries the "
           "load average (1/5/15 min) before and after it. The machine has 2 cores shared with "
           "other sessions: a load above ~1.5 means the times are inflated (by up to load/2).",
           ""]
    out += _table(
        data.get("coarse"), "Defaults: coarse target, both directions, pyFM in the same run",
        "Warm default soft maps (each in a fresh process after a first call; eq. 3.18 over "
        "the target decimated to about as many points as samples, rows prolonged; symmetric "
        "ZoomOut (20, 80, 2)), and pyFM (basic, ICP, ZoomOut; settings as in the accuracy "
        "part). Error: mean geodesic error on the target / sqrt(area) (lion -> cat over all "
        "5,000 lion vertices; cat -> lion over the cat vertices the ground truth hits), with "
        "and without refinement (the soft map's modes). Held out: the geodesic miss of the "
        "15 landmark pairs never given to any method (lines 6-20 of cat-lion-landmarks.txt), "
        "median / largest, unit-area target. Peak RSS: the process's (it includes the "
        "first call); baseline: resident after the imports (numpy, scipy, numba) and both "
        "meshes rebuilt from stored arrays as a service worker holds them (no mesh-file "
        "parser; rows before 2026-12-04: loaded from the files, trimesh imported), before "
        "any soft map; resident before: after the first call (its "
        "caches, compiled kernels), before the timed one.",
        ["direction", "method", "target points", "error", "error before refinement",
         "held out median / max", "seconds", "propagation s", "sweeps", "peak RSS MB",
         "baseline MB", "resident before MB", "load before", "load after"],
        lambda r: [r["direction"], r.get("method", f"otgeo soft map, {r.get('samples')} "
                                                   "samples, defaults"),
                   r.get("target_points", ""), f"{1e3 * r['error']:.2f}e-3",
                   f"{1e3 * r['error_mode']:.1f}e-3" if "error_mode" in r else "",
                   f"{r['held_out_median']:.4f} / {r['held_out_max']:.4f}"
                   if "held_out_median" in r else "", f"{r['seconds']:.2f}",
                   f"{r['timings']['propagation']:.2f}" if "timings" in r else "",
                   r["iterations"] + 1 if "iterations" in r else "",
                   f"{r['peak_rss_mb']:.1f}" if "peak_rss_mb" in r else "",
                   f"{r['baseline_rss_mb']:.0f}" if "baseline_rss_mb" in r else "",
                   f"{r['resident_before_mb']:.0f}" if "resident_before_mb" in r else "",
                   r["load_before"], r["load_after"]])
    out += _table(
        data.get("growth"), "Growth with the number of samples (defaults, coarse target)",
        "lion -> cat with the defaults, warm (second call in a fresh process): seconds end to "
        "end, of the propagation, sweeps, the residual (largest L1 marginal violation; tol "
        "1e-4), error as above, the process's peak RSS, its baseline and resident memory "
        "before the timed call (as in the defaults table).",
        ["samples", "target points", "source edges", "seconds", "propagation s", "sweeps",
         "residual", "converged", "error", "peak RSS MB", "baseline MB", "resident before MB",
         "code", "load before", "load after"],
        lambda r: [r["samples"], r["target_points"], r["edges"], f"{r['seconds']:.2f}",
                   f"{r['propagation']:.2f}", r["iterations"] + 1,
                   f"{r['residual']:.3g}" if "residual" in r else "", r["converged"],
                   f"{1e3 * r['error']:.2f}e-3", f"{r['peak_rss_mb']:.1f}",
                   f"{r['baseline_rss_mb']:.0f}" if "baseline_rss_mb" in r else "",
                   f"{r['resident_before_mb']:.0f}" if "resident_before_mb" in r else "",
                   r["code"], r["load_before"], r["load_after"]])
    out += _table(
        data.get("gamma_floor"), "The coarse target's gamma floor (1,024 samples)",
        "Warm default soft maps as in the defaults table (fresh process each), gamma with the "
        "floor COARSE_GAMMA_MIN = 0.01 (the default) or without it (max(4 / (sqrt(3) N), "
        "4 h^2 of the coarse target), the default before the floor); errors as there.",
        ["direction", "gamma floor", "gamma", "error", "error before refinement",
         "held out median / max", "seconds", "propagation s", "sweeps", "residual",
         "converged", "peak RSS MB", "code", "load before", "load after"],
        lambda r: [r["direction"], r["gamma_floor"], f"{r['gamma']:.3g}",
                   f"{1e3 * r['error']:.2f}e-3", f"{1e3 * r['error_mode']:.1f}e-3",
                   f"{r['held_out_median']:.4f} / {r['held_out_max']:.4f}",
                   f"{r['seconds']:.2f}", f"{r['timings']['propagation']:.2f}",
                   r["iterations"] + 1, f"{r['residual']:.3g}", r["converged"],
                   f"{r['peak_rss_mb']:.1f}", r["code"], r["load_before"], r["load_after"]])
    out += _table(
        data.get("multiscale"), "Multiscale start against a cold start (1,024 samples)",
        "Warm default soft maps; the multiscale start solves 128 samples over 128 coarse "
        "points first and starts every edge with one Sinkhorn step towards that solution "
        "prolonged (log-scalings centred at free nodes: the same fixed point). Seconds: "
        "the 128-sample solve plus the propagation.",
        ["direction", "multiscale start", "sweeps", "converged", "seconds", "error", "code",
         "load before", "load after"],
        lambda r: [r["direction"], r["multiscale"], r["iterations"] + 1, r["converged"],
                   f"{r['seconds']:.2f}", f"{1e3 * r['error']:.2f}e-3", r["code"],
                   r["load_before"], r["load_after"]])
    out += _accuracy_table(data.get("accuracy"), "Accuracy",
                           "Mean geodesic error on the cat / sqrt(cat area), all 5,000 lion "
                           "vertices, 5 landmarks, same evaluator (heat-method distances) for "
                           "every method.")
    out += _accuracy_table(data.get("reverse"), "The other direction: cat -> lion",
                           "Same settings (chosen on lion -> cat), the 5 landmarks reversed; "
                           "mean geodesic error on the lion / sqrt(lion area) over the cat "
                           "vertices the lion -> cat ground truth hits (for each, the first "
                           "lion vertex mapped to it).")
    out += _table(
        data.get("scaling"), "Growth with the number of samples",
        f"Soft map over all 7,207 cat vertices, {SCALING_SWEEPS} propagation sweeps (fixed, to "
        "compare sizes), warm (second call in a fresh process), refine none; peak memory = "
        "tracemalloc peak of the call (numpy arrays; the cached factorization and eigenpairs "
        "are not counted).",
        ["samples", "source edges", "seconds", "s / sweep", "peak MiB", "residual", "code",
         "load before", "load after"],
        lambda r: [r["samples"], r["edges"], f"{r['seconds']:.1f}",
                   f"{r['seconds_per_sweep']:.2f}", f"{r['peak_extra_mb']:.0f}",
                   f"{r['residual']:.3g}", r.get("code", ""), r["load_before"],
                   r["load_after"]])
    out += _table(
        data.get("convergence"), "Time to convergence",
        "Soft map over all 7,207 cat vertices with the defaults (tol 1e-4 on the largest L1 "
        "marginal violation, at most 1,000 sweeps, ZoomOut), warm (second call in a fresh "
        "process); error as in the accuracy table; peak = tracemalloc peak of the call.",
        ["samples", "sweeps", "residual", "converged", "propagation s", "total s", "error",
         "peak MiB", "code", "load before", "load after"],
        lambda r: [r["samples"], r["iterations"] + 1, f"{r['residual']:.3g}", r["converged"],
                   f"{r['timings']['propagation']:.1f}", f"{r['seconds']:.1f}",
                   f"{1e3 * r['error']:.2f}e-3", f"{r['peak_extra_mb']:.0f}",
                   r.get("code", ""), r["load_before"], r["load_after"]])
    out += _table(
        data.get("trace"), "Residual against time at 1,024 samples",
        f"The default soft map ({TRACE_SAMPLES} samples, lion -> cat over all 7,207 cat "
        "vertices, warm, refine none): the first sweep at which the residual (largest L1 "
        "marginal violation, at most 2) reaches each level, with the seconds since the call "
        f"began; the last row is where it stands after {TRACE_BUDGET:g} s, the issue's warm "
        "target.",
        ["when", "sweeps", "residual", "seconds", "converged at the end", "code",
         "load before", "load after"],
        lambda r: [r["at"], r["sweeps"], "" if r["residual"] is None else
                   f"{r['residual']:.3g}", "" if r["seconds"] is None else
                   f"{r['seconds']:.1f}", r["converged"], r["code"], r["load_before"],
                   r["load_after"]])
    out += _table(
        data.get("continuation"), "Epsilon-scaling against a cold start at 1,024 samples",
        f"The same default problem ({TRACE_SAMPLES} samples, warm, refine none), solved cold "
        f"or after stages at {' / '.join(f'{f:g}' for f in CONTINUATION)} x gamma (each to "
        f"tol {CONTINUATION_TOL:g}, warm-starting the next through ``initial=``, potentials "
        "carried over); both end at the default gamma and tol, the same fixed point.  Work in "
        "full sweeps = kernel columns / (2 x edges); seconds of the propagation.",
        ["variant", "sweeps", "full sweeps of work", "residual", "converged", "seconds",
         "code", "load before", "load after"],
        lambda r: [r["variant"], r["sweeps"], f"{r['full_sweeps']:.1f}",
                   f"{r['residual']:.3g}", r["converged"], f"{r['seconds']:.1f}", r["code"],
                   r["load_before"], r["load_after"]])
    out += _table(
        data.get("relaxation"), "Over-relaxation window",
        "Work of the default propagation (lion -> cat, tol 1e-4) with the adaptive "
        "over-relaxation measuring its rate over 5 sweeps (OverRelaxation's default) or 3 (the "
        "propagation's): kernel columns in units of full sweeps (2 x edges columns each), and "
        "sweeps.  The same fixed point either way (both stop at the tolerance); seconds are "
        "wall time on the shared machine.",
        ["samples", "window", "full sweeps of work", "sweeps", "converged", "propagation s",
         "code", "load before", "load after"],
        lambda r: [r["samples"], r["window"], f"{r['full_sweeps']:.1f}", r["sweeps"],
                   r["converged"], f"{r['propagation_seconds']:.1f}", r["code"],
                   r["load_before"], r["load_after"]])
    out += _table(
        data.get("sweep_cost"), "Cost of one sweep, before/after",
        "Wall seconds of one default propagation sweep (lion -> cat over the 7,207 cat "
        "vertices, 2 threads, warm, mean of sweeps 4-13); the code before (solves by cholespy, "
        "which holds the GIL, in 8-column blocks) and after (the triangular backend, GIL "
        "released, one solve per chunk), alternating in fresh processes. The residuals differ "
        "in the third digit because the cost's mean is now exact (a cost scale 0.03 % "
        "different).",
        ["samples", "code", "s / sweep", "residual after 13", "load before", "load after"],
        lambda r: [r["samples"], r["code"], f"{r['seconds_per_sweep']:.3f}",
                   f"{r['residual_after_13']:.4g}", r["load_before"], r["load_after"]])
    out += _table(
        data.get("propagation"), "Alg. 4 before/after batching",
        "First two rows: 128 farthest-point lion samples as nodes, 5 fixed deltas on the cat, "
        "gamma 0.004, 40 sweeps each (not converged: the gap is the difference of two "
        "unfinished iterations). Last two: cow, a 6 x 6 grid graph with 4 fixed bumps, gamma "
        "0.01, run to tol 1e-7.",
        ["variant", "seconds", "sweeps", "residual", "max L1 gap vs before", "load before",
         "load after"],
        lambda r: [r["variant"], f"{r['seconds']:.1f}", r["sweeps"], f"{r['residual']:.3g}",
                   f"{r['max_l1_gap_vs_before']:.2g}" if "max_l1_gap_vs_before" in r else "",
                   r["load_before"], r["load_after"]])
    out += [READING_FLOOR, READING]
    return "\n".join(out)


READING_FLOOR = """## Reading: the gamma floor and the memory cut (runs of 2026-12-04)

The defaults, gamma-floor and growth tables are of one run, `cpu bench env
OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/softmaps.py coarse gamma_floor growth`
(21:58-22:03 UTC, code f3dfba2, load 0.96 at the start, 1.90 at the end), but for the
growth rows of 2,048 and 4,096 samples: rerun on their own (`cpu bench env
OPENBLAS_NUM_THREADS=1 SOFTMAPS_GROWTH=2048,4096 .venv/bin/python bench/softmaps.py
growth`, 22:20-22:22, code de191bf: the same solver, load 0.99 at the start).  A run of
`coarse gamma_floor` just before it (21:50-21:52, code ab88011, load 1.2-1.8) is quoted
below.  The reading of 2026-12-03 further down quotes the tables as they were then (code
31e26c1 / 739e04a).

- What changed.  (1) Over a coarse target the default gamma is at least
  `COARSE_GAMMA_MIN` = 0.01 (`solvers.softmaps.propagation_map.default_gamma`): 4 h^2 of
  the coarse target is 9.3e-3 / 5.0e-3 / 2.5e-3 / 1.1e-3 at 512 / 1,024 / 2,048 / 4,096
  samples, so the floor is what the default solves from 512 samples on (twice the former
  gamma at 1,024).  (2) Memory: over a coarse target the propagation stores its edge-end
  log-scalings, barycenters (which become the masses) and node log-rescalings in float32
  (`scalings_dtype` of `wasserstein_propagation`; the kernel applications, barycenters and
  gaps are computed in float64); the final masses are formed 64 nodes at a time in place
  of the barycenters; the descriptors and the float64 cost are freed before the
  propagation; the descriptors (100 eigenpairs) and ZoomOut (80) share one eigen-solve and
  one cached basis (before: two, 8 MB more on this pair); glibc maps blocks of 4 MiB and
  more on their own (`solvers.memory.map_large_blocks`, process-wide), so freed
  (samples x target) temporaries leave at once.  Full resolution (`target_points=None`)
  stays float64.  (3) The fresh-process rows rebuild both meshes from stored arrays as a
  service worker does (`Domain.to_arrays()`), so trimesh, the file parser, is not
  imported (29 MB resident, ad hoc); peak RSS is read from `VmHWM` (`ru_maxrss` carries
  the parent's over a fork: the first run's gamma-floor rows read 466 MB, the parent's
  peak with pyFM).
- Time (defaults table): 1,024 samples lion -> cat 4.93 s end to end, 3.71 s of
  propagation (48 sweeps); cat -> lion 5.22 s, 4.07 s (54 sweeps); targets 15 s and 10 s.
  128 samples: 1.11 s and 1.20 s end to end (target 2 s).  pyFM's ZoomOut in the same run:
  6.49 s / 6.45 s.  The run before: 4.84 / 5.33 s end to end, 3.80 / 4.20 s of
  propagation, 1.12 / 1.29 s at 128 samples.  The machine was faster today than on
  2026-12-03 (pyFM ZoomOut 6.5 s against 8.5 s), so compare within a run: at 1,024
  samples otgeo is 1.3x faster than pyFM's ZoomOut end to end, against 1.14x slower on
  12-03.  Without the floor (gamma-floor table, same run) the propagation takes 69 / 101
  sweeps and 4.59 / 5.72 s: the floor saves 30 % / 46 % of the sweeps at 1,024 samples.
- Accuracy (gamma-floor table): refined, the floor changes nothing that shows -- lion ->
  cat 19.37e-3 against 19.36e-3 without it, cat -> lion 16.59e-3 against 16.61e-3; pyFM's
  ZoomOut 21.56e-3 / 21.20e-3 in the same run (ratios 0.899 / 0.782).  Held out (15 pairs):
  lion -> cat median 0.0210 against 0.0200 (largest 0.0774 both), cat -> lion 0.0131 /
  0.0376 both.  Before refinement the floor's blurrier rows are worse: the modes score
  99.3e-3 against 91.2e-3 (lion -> cat) and 129.7e-3 against 103.2e-3 (cat -> lion).  So
  what the default solves at 1,024 samples and more is eq. 3.18 at gamma 0.01, a smoother
  soft map than the sample spacing would allow; the refinement from its functional map
  does not suffer.  Without the floor, the float32 code reproduces the float64 code's
  digits of 2026-12-03 (19.36e-3 / 91.2e-3, 69 sweeps; 16.61e-3 / 103.2e-3, 101 sweeps).
  128 samples: 20.20e-3 / 16.61e-3, as before (gamma 0.046 there, above the floor).
- Memory at 1,024 samples (target 300 MB): process peak 261.1 MB lion -> cat and 259.7 MB
  cat -> lion (defaults table; gamma-floor table 257.8-264.4 MB), from 154 MB after the
  imports and meshes and 225 MB before the timed call.  The run before (`ru_maxrss`, which
  there was the child's own: the parent held less) read 284.9 / 276.4 MB.  The resident
  memory of the same code varies by ~40 MB between runs (baseline 154 MB here, 185 MB in
  the run before, 195 MB in an ad-hoc profile): how many pages of the shared libraries
  (numba's LLVM, scipy) are resident.  The ad-hoc per-stage profile (`VmHWM` reset per
  stage through `/proc/self/clear_refs`, script /work/scratch/softmap28/memprof.py, `cpu
  run`) put the timed call's peak at 282 MB from 249 MB resident, reached both in the
  propagation (the float32 scalings 25 MB, node logs and barycenters 4 MB each, the masses'
  block temporaries) and in the extraction; the first call's at 281 MB.  Step by step (the
  same profile): float32 scalings with float64 barycenters and a separate masses array
  304 MB; the masses in place of the barycenters 295 MB; float32 node logs and barycenters
  286 MB; the masses' blocks of 64 nodes 282 MB.  So the target is met with 15-40 MB to
  spare depending on the run.  (MB here: MiB, as the tables.)
- Growth (table): every size from 128 to 4,096 samples converges to tol 1e-4 with the
  defaults: 22 / 31 / 48 / 48 / 51 / 63 sweeps, 1.15 / 1.30 / 2.65 / 4.74 / 20.6 / 85.9 s
  end to end, peak RSS 253 / 250 / 252 / 260 / 354 / 758 MB; errors 19.4-20.2e-3.  At
  4,096 samples the former default (gamma 1.1e-3) stalled near a residual of 5.2e-4 after
  1,050 sweeps (reading of 2026-12-03).  The load during a row rises to ~2 from the
  solver's own two threads: the first run's 2,048 / 4,096 rows (load 1.55 / 1.72 before
  them) took 20.53 / 84.61 s, the rerun from load 1.07 / 1.53 (0.99 when it began) 20.55 /
  85.89 s.
- The service's memory estimate (`estimated_bytes`) now counts, over a coarse target, the
  float32 arrays per (sample, coarse point), the masses' block temporaries, the
  prolongation, one block of 64 prolonged rows (all rows with an extraction other than the
  mode or a Sinkhorn refinement) and 1,536 bytes per source and target vertex (ZoomOut's
  vertices x 80 products and copies); full resolution as before.  It bounds the measured
  working memory: bench/results/operation_memory.md (soft-maps rows of 2026-12-04) and, at
  1,024 / 2,048 / 4,096 samples on this pair, 78 / 177 / 565 MiB against 37 / 137 / 536 MiB
  measured (peak minus resident before, growth table).  On the operation-memory meshes
  (cow 2,903 and homer 6,002 vertices, the request example: 64 samples, k 20) 17 / 35 MiB
  against 11 / 18 MiB measured warm (ratios 1.57 / 1.91).
"""


READING = """## Reading: the coarse target (runs of 2026-12-03)

The defaults table is of 18:00 UTC (code 31e26c1, `cpu bench`, load 1.2-1.5); the growth
table of 17:32 (code 739e04a, load 1.8-2.1); an earlier run of the defaults at 17:30 (code
f8a73d9, load 2.8-4.0) is quoted below.  The other coarse-target figures are of 12:12-12:31
at load 2.6-5.2, the full-resolution ones of 2026-12-01/02 at 1.6-2.1.  Memory does not
depend on the load.

- What changed: eq. 3.18 is solved by default over the target decimated to about as many
  points as samples (1,025 cat points at 1,024 samples, 130 at 128), rows prolonged to all
  7,207 vertices; the default refinement is symmetric ZoomOut (20, 80, 2) with the steps
  before the last on 1,024 farthest-point vertices of each mesh.
- Time (defaults table, warm, load 1.2-1.5): 1,024 samples lion -> cat 9.66 s end to end,
  8.25 s of propagation (69 sweeps); cat -> lion 11.18 s, 9.85 s (101 sweeps): within the
  10 s (propagation) and 15 s (end to end) targets, cat -> lion's propagation with 2 %
  to spare.  128 samples: 1.24 s and 1.21 s end to end (target 2 s).  The same code but
  for ZoomOut's blockwise start (f8a73d9) took 6.52 / 7.39 s (propagation 5.59 / 6.44 s)
  and 0.84 / 0.88 s at 17:30 at load 2.8-4.0, and pyFM in that run was 19-24 % faster than
  in the 18:00 run (6.88 against 8.50 s for its ZoomOut): the machine's speed varies more
  than the load average shows, so compare within a run (pyFM ZoomOut 8.50 s, otgeo 9.66 s
  end to end at 1,024 samples, 1.24 s at 128).  The full-resolution 1,024-sample solve
  took 85-116 s (tables below).
- Memory, what it means: the tables give the process's peak RSS (`ru_maxrss`, which
  includes the first, cache-building call), its baseline (resident after the imports --
  numpy, scipy, numba, trimesh -- and both meshes, before any soft map: 174-176 MB) and
  its resident memory before the timed call (baseline plus the first call's caches and
  compiled kernels: 268-282 MB).  **The 300 MB target on the process peak is met at 128
  samples (286-293 MB) and missed at 1,024 (370-372 MB, from 427-446 MB).**  The timed
  1,024-sample call itself adds 90 MB to what was resident; the process peak is 195 MB
  above the baseline.
- Where the memory went, and what was cut (per-stage `VmRSS`/`VmHWM`, the high-water mark
  reset after each stage through `/proc/self/clear_refs`; lion -> cat, 1,024 samples;
  script /work/scratch/softmap28/memprof.py, `cpu run`): imports 129 MB (numpy 26, scipy
  +33, solvers +9, numba +53 of it), both meshes +43 (trimesh's import: 42 of it);
  first call: descriptors +53 (eigenpairs of both meshes, heat-method solvers), the first
  compiled kernel +43 (numba's LLVM), the propagation's working arrays ~70-90 MB at their
  peak (the edge-end log-scalings alone, 6,110 x 1,025 float64, are 50 MB).  Before this
  change the peaks came after the propagation: the prolonged rows (1,024 x 7,207 float32,
  30 MB) with their gather (3 entries per vertex, 88 MB), the mode's density (30 MB) and
  ZoomOut's float64 copy of the prolonged rows (59 MB): 485-510 MB at the prolongation, 436
  MB resident after the call.  Now (1) the extraction reads the coarse rows through the
  prolongation: the mode a block of 64 prolonged rows at a time, ZoomOut's start as
  `rows @ (P^T Phi)` (the same functional map), the top-k per block -- no samples x
  n_target matrix is formed (`SoftMapResult.target_rows()` still forms it on demand);
  (2) `Prolongation.apply` works in blocks of 64 rows; (3) the landmark distances are
  cached per landmark set instead of potpourri3d's heat-method solver (22 MB on the cat,
  13 MB on the lion); (4) glibc's freed heap is handed back (`malloc_trim`,
  `solvers.memory.release_free_heap`) before the propagation and after the call: the
  solver's threads each get a malloc arena, and without it 70 MB of freed temporaries
  stayed resident (350 MB against 280 MB after the first call).  Per stage now: first call
  peak 348 MB (in the propagation), resident 289 MB after it; timed call peak 377 MB (in
  the propagation, from 299 MB resident).  What is left above 300 MB is the baseline
  (interpreter, numba, trimesh, meshes: 175 MB) plus the compiled kernels and caches kept
  for later calls (~100 MB) plus the propagation's arrays; reaching 300 MB for the process
  would need the propagation in ~25 MB (float32 log-scalings would save 25 MB of the 50;
  not tried: the compiled sweeps are float64 and the tolerance is 1e-4) or a smaller
  baseline.  Accuracy is unchanged: 19.36e-3 / 16.61e-3 at 1,024 samples and 20.20e-3 /
  16.61e-3 at 128, held-out misses 0.0200 / 0.0774 and 0.0131 / 0.0376, the same digits as
  before the change (12:12 run), against pyFM ZoomOut 21.56e-3 / 21.20e-3 in the same run.
- Growth (table above, load 1.8-2.1, code 739e04a whose only other change was a sweep cap
  of max(1,000, samples), reverted since; no row here reached 1,000 sweeps): 128 / 256 /
  512 / 1,024 / 2,048 samples take 0.91 / 1.11 / 2.05 / 5.84 / 37.5 s (22 / 31 / 50 / 69 /
  262 sweeps, all converged to tol 1e-4), peak RSS 287 / 286 / 302 / 364 / 664 MB.
  **4,096 samples do not converge**, so that row is missing: with the cap raised to 4,096
  sweeps (`cpu bench`, load 2.0-2.4, code 739e04a, stopped by hand after 1,050 sweeps and
  561 s) the residual was 0.217 / 0.065 / 0.014 after 50 / 100 / 150 sweeps, 1.45e-3 after
  600, 1.01e-3 / 6.65e-4 / 5.74e-4 / 5.25e-4 / 5.18e-4 after 700 / 800 / 900 / 1,000 /
  1,050: it stalls near 5e-4, falling ~1.4 % per 50 sweeps, which would need ~6,000 more
  sweeps to reach 1e-4 (log stderr: /work/scratch/softmap28/growth4096_trace.log).  So a
  larger default cap only runs longer, and the cap stays 1,000.  The earlier 4,096 row
  (12:31, code f9a3a4d: 1,000 sweeps, 603 s, 1.9 GB, error 19.58e-3) was taken out of the
  table.  The slow tail of the full-resolution solve comes back as the samples grow: gamma
  (4 h^2 of the coarse mesh) shrinks with them and the coarse target is as fine as the
  samples; a warm start did not help at 1,024 (multiscale table).
- Accuracy (same table, pyFM in the same run): lion -> cat 19.36e-3 (1,024 samples) and
  20.20e-3 (128) against pyFM ZoomOut 21.56e-3 (ratios 0.898, 0.937); cat -> lion 16.61e-3
  at both sizes against 21.20e-3 (0.783).  Held-out landmarks (15 pairs never given):
  median miss 0.020 / largest 0.077 (lion -> cat), 0.013 / 0.038 (cat -> lion), unit-area
  target.  Before refinement the modes are worse than at full resolution (91.2e-3 against
  77.4e-3 at 1,024 samples; 192.8e-3 at 128): the coarse rows are blurrier (larger gamma);
  the refinement starts from their functional map, which does not suffer.
- Where the accuracy gain comes from (ad hoc, lion -> cat / cat -> lion, load ~2.5): the
  coarse target alone gave 21.58e-3 / 21.36e-3 at 1,024 samples with the former one-way
  ZoomOut (20, 50, 1) -- level with pyFM, as at full resolution (21.54e-3 / 21.37e-3).
  Tying the reverse map in (symmetric ZoomOut) gave 19.8e-3 / 17.6e-3 with (20, 60, 1) and
  19.4-20.2e-3 / 16.6e-3 with (20, 80, 2) at 128-1,024 samples; one-way ZoomOut to k 80 or
  100 was worse (22.7e-3, 25.7e-3 at 128 samples).  The range (20, 80, 2) was chosen on
  this pair (both directions).
- Subsampled ZoomOut steps (ad hoc, one-way ZoomOut, 128 samples): 0.68 s instead of 2.61
  s of extraction, error 21.78e-3 against 21.60e-3.
- Multiscale start (table above): starting the 1,024-sample propagation from a 128-sample
  solve prolonged reaches the same fixed point (same errors) but does not save sweeps
  (71 against 69, 108 against 101) and costs more time (8.9-9.2 s against 7.7 s; 12.3-12.5
  s against 9.8 s).  It stays an option (`multiscale=True`), off by default.  Without
  centring the log-scalings at free nodes the same start converged to another point
  (error 64e-3 against 19.4e-3 at 256 samples, ad hoc): Alg. 4's fixed point needs their
  weighted mean at a free node to be 0.
- Viewer (ad hoc, /work/scratch script, Playwright + Chromium against `otgeo serve`, load
  ~3): a default lion -> cat job run from the page took 9.5 s cold; from "succeeded" to
  the soft-map view ready to hover 0.86 s; a hovered row (prolonged on the server) 0.05 s.
- BLAS threads: `soft_map` now runs BLAS on one thread (threadpoolctl).  Unpinned, a cold
  default call took 51 s at load 4.8 (descriptors 12.4 s, ZoomOut 29 s: BLAS threads on
  top of the solver's own threads), pinned 18 s.

## Reading: the full-resolution target (runs of 2026-12-01/02)

- Accuracy (run of 2026-12-02 15:17, load 1.9-2.1): the converged 1,024-sample soft map,
  refined by ZoomOut (20, 50, 1) started from its own functional map, scores 21.54e-3
  against pyFM's best (ZoomOut) 21.56e-3 in the same run: ratio 0.999, level rather than
  ahead.  pyFM ICP 24.60e-3, basic 49.17e-3; POT GW 86.9e-3 at best; the soft map's modes
  alone 77.3e-3, so most of the accuracy is the spectral refinement.  The run of 05:56
  scored 21.46e-3 with the same pipeline; since then the mean of the compatibility cost is
  computed exactly (closed form over all source vertices, no longer estimated from 2,048
  rows), which moved the cost scale by 0.03 % and the refined error by 0.4 %.  ZoomOut's
  result moves by that much under perturbations of its input this small (the arithmetic
  of the nearest-row search, float32 or float64, does not change it: 21.542e-3 either
  way, ad-hoc), so the margin over pyFM is below this noise.  Caveat: the range
  (20, 50, 1) was chosen on this pair.
- The other direction (cat -> lion, run of 15:19, load 1.6-2.0), same settings: otgeo
  21.37e-3 against pyFM ZoomOut 21.20e-3, **0.8 % worse** (ratio 1.008).  Its propagation
  now converges within the default cap: 762 sweeps in 86 s (an ad-hoc run of the code
  before active nodes took 756 sweeps and 485 s).
- Convergence: the defaults converge to 1e-4 at every size: 32 / 45 / 64 / 261 sweeps at
  128 / 256 / 512 / 1,024 samples (table above).  The over-relaxation now measures its
  rate over 3 sweeps instead of 5; the over-relaxation table shows less kernel work at
  every size: 31.8 / 44.5 / 58.7 / 110.2 full sweeps, against 36.9 / 48.3 / 65.1 / 116.8
  with 5.  The refined errors are the same to the printed digits, because both runs stop
  at the tolerance of the same fixed point.
- Time: **the 10 s warm target at 1,024 samples is missed.**  The run above measured
  115.8 s warm (113.6 s of propagation, load 1.9-2.0), and the first call in the accuracy
  table took 97.2 s (load 1.9-2.1).  The same code gave 102.4 s in the previous session's
  run, but this machine is slower today: the code of 6202226 took 1.26-1.37 s per
  1,024-sample sweep today, against ~0.8 s in the previous session.  So compare within a
  run: the sweep-cost table puts one sweep at 0.94-1.02 s against 1.26-1.37 s before
  (1.3x), and at 512 samples 0.36-0.39 s against 0.59-0.63 s (1.65x).  The cause of the
  change: cholespy's solve holds the GIL, so the threads of the previous change ran the
  solves one at a time.  The new ``"triangular"`` factor (SuperLU's symmetric-mode LU,
  compiled triangular solves that release the GIL, one block per chunk of 32 edge ends)
  solves in both threads: 57 us a column against 107-126 us with one thread (ad-hoc,
  7,207 x 32 blocks).
  - The rest of a call is now small.  Descriptors take 0.2-0.5 s warm, against 2.2-3.4 s
    before: the exact mean of the cost is a closed form, and the L1 rows are compiled and
    run in threads.  ZoomOut takes 1.4-1.8 s, against 2.2-2.8 s: inner products by BLAS
    and a compiled arg-min in threads.  At 128 samples, the whole default soft map takes
    4.8 s warm, against 9.4 s in the previous session's run (error 21.56e-3, pyFM
    21.56e-3).
  - Where the time goes at 1,024 samples (ad-hoc trace of a default run with the window
    of 5).  The 281 sweeps apply as many kernel columns as 117 full sweeps (110 with the
    window of 3).  The first ~70 sweeps are full, with
    the residual on a plateau near 1.7e-2 between sweeps 40 and 60.  Active nodes cut the
    last 200 sweeps to the work of 30 full sweeps.
  - What 10 s would need.  A full sweep is 6,110 kernel columns over 7,207 vertices: 0.94-1.02
    s here (table), of which the two-thread solves alone are ~0.35 s (6,110 x 57 us).  So
    10 s needs fewer than ~10 full sweeps at today's cost, or ~25 with the solves alone,
    against 110.  That needs another algorithm than Alg. 4's Gauss-Seidel sweeps.
  - The default gamma shrinks with the samples (twice their squared spacing), so the
    1,024-sample problem is also the sharpest.  At 1,024 samples with 2x / 4x / 8x the
    default gamma, the sweeps were 87 / 59 / 40 and the refined errors 21.54 / 21.54 /
    21.51e-3, against 21.46e-3 at the default (ad-hoc, cost normalization of the earlier
    runs).  The default is kept.
- Residual against time (trace table, load 0.7 before, 1.8 after with the run's own two
  threads): after 10 s the default 1,024-sample propagation has run 11 sweeps and its
  residual is 0.21 (of at most 2): the distributions are nowhere near the fixed point.
  It reaches 1e-1 after 23 sweeps (20.1 s), 1e-2 after 55 (48.1 s), 1e-3 after 124
  (77.5 s) and 1e-4 after 260 (94.5 s).  So no tolerance a user would accept brings 1,024
  samples under 10 s: a hundred times the default tol still takes 48 s.
- Epsilon-scaling (continuation table) does not help either.  Stages at 8 / 4 / 2 x gamma,
  each to tol 1e-2 and warm-starting the next (``wasserstein_propagation(..., initial=,
  keep_scalings=True)``, the potentials gamma log v carried over), cost 22.2 + 22.5 + 27.2
  full sweeps; the final stage at the default gamma then still needs 233 sweeps (99.1 full
  sweeps of work, 78.3 s) against 261 (110.2, 90.3 s) from a cold start: 171.1 full sweeps
  and 135.3 s in all.  The slow part is the tail at the default gamma, whatever the start.
- Why the tail is slow: the nodes that hold the largest gap late in the solve (the same
  few, in one region of the lion) carry bimodal distributions, about 66 % of their mass
  within 0.1 of their mode and 32 % around a second mode 0.48 away on the cat (ad hoc, on
  the converged map: a left/right ambiguity).  Moving mass between two separated modes
  through an entropic kernel is the classic slow mode of Sinkhorn-type iterations, and it
  slows sharply as gamma shrinks (at 2x the default gamma the previous session measured 87
  sweeps, ad hoc; 261 at the default).
- Also measured this session, ad hoc (not kept): letting the over-relaxation go up to
  omega 1.97 instead of 1.9 ended in 191 sweeps instead of 261, but many more nodes stayed
  active (e.g. 733 against 307 visited at sweep 104), so no work was saved; Anderson
  acceleration (depth 3) of the edge log-scalings, started below a residual of 5e-2 or
  1e-2, oscillated and did not converge in 300 sweeps at 256 samples (45 sweeps with the
  default over-relaxation).  Where one sweep's time goes (1,024 samples, one thread, 10
  sweeps, 14.3 s): solves 5.9 s, the compiled node updates 4.5 s, exp/log 1.7 s, row
  maxima 0.75 s; halving any one of them leaves the target out of reach.
- Memory: 684 MiB traced peak at 1,024 samples (below the 1 GB target), about linear in
  the samples (91 / 177 / 346 / 684 MiB at 128 / 256 / 512 / 1,024 in the convergence
  rows): the edge-end log-scalings (2 x 3,055 x 7,207 x 8 bytes = 352 MB) plus five
  (samples x target) arrays; the ~100 bytes per sample x target vertex of
  ``solvers.softmaps.propagation_map.estimated_bytes``.  The cached factorization and
  eigenpairs are not in these figures.
- Alg. 4 batching (run of 2026-12-01 20:34, code before the chunked sweep and before the
  normalization): the same fixed point (cow, run to tol 1e-7: L1 gap 4e-9, 191 vs 187
  sweeps) in 2.34 s instead of 5.82 s.
- POT's entropic Gromov-Wasserstein on 500 samples per shape finds flipped or blurred
  matches.
"""


def main(argv):
    if argv[:1] == ["render"]:
        data = json.loads(RESULTS.read_text())
        RESULTS.with_suffix(".md").write_text(render(data) + "\n")
        return
    if argv[:1] == ["_scaling"]:
        print(json.dumps(_one_scaling(int(argv[1]))))
        return
    if argv[:1] == ["_sweep_cost"]:
        sys.path.insert(0, argv[1])  # the solvers package to measure
        print(json.dumps(_one_sweep_cost(int(argv[2]))))
        return
    if argv[:1] == ["_coarse"]:
        print(json.dumps(_one_coarse(argv[1], int(argv[2]), argv[3:] != ["nofloor"]),
                         default=float))
        return
    if argv[:1] == ["_growth"]:
        print(json.dumps(_one_growth(int(argv[1])), default=float))
        return
    if argv[:1] == ["_convergence"]:
        print(json.dumps(_one_convergence(int(argv[1]))))
        return
    parts = argv or ["propagation", "accuracy", "scaling"]
    for part in parts:
        if f"part_{part}" not in globals():
            raise SystemExit(f"unknown part {part!r}")
    for part in parts:
        rows = globals()[f"part_{part}"]()
        data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
        data[part] = {"rows": rows, "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
        RESULTS.write_text(json.dumps(data, indent=1, default=float))
    if RESULTS.exists():
        RESULTS.with_suffix(".md").write_text(render(json.loads(RESULTS.read_text())) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])
