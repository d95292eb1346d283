"""Correspondence refinements of one lion -> cat soft map: with and without Sinkhorn projection.

``.venv/bin/python bench/softmaps_refinement.py [compute] [compare] [render]``

compute
    the soft map of bench/softmaps.py's accuracy run (lion -> cat, the first 5 landmark
    pairs of ``cat-lion-landmarks.txt``, 1,024 farthest-point samples, 50 sweeps, defaults
    otherwise, ``refine="none"``), computed ONCE and saved to ``SOFTMAPS_NPZ`` (default
    ``/tmp/otgeo-softmap-lion-cat-1024.npz``) with the commit it was computed at; skipped if
    the file exists.
compare
    on that saved map: extraction (mode, barycentric) x Sinkhorn projection (none, or a few
    iteration counts) x ZoomOut (none, (20, 50, 1)); mean geodesic error on the cat over all
    5,000 lion vertices / sqrt(cat area) (the evaluator of bench/softmaps.py), the
    projection's marginal residual and time.  Results to
    ``bench/results/softmaps_refinement.json`` and ``.md``.

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
sys.path.insert(0, str(ROOT / "bench"))
NPZ = Path(os.environ.get("SOFTMAPS_NPZ", "/tmp/otgeo-softmap-lion-cat-1024.npz"))
RESULTS = ROOT / "bench" / "results" / "softmaps_refinement.json"
SAMPLES = 1024
SWEEPS = 50
ZOOMOUT = (20, 50, 1)  # soft_map's default range
SINKHORN_ITERATIONS = (5, 20, 100)


def loadavg() -> str:
    return " ".join(open("/proc/loadavg").read().split()[:3])


def load():
    from softmaps import load as load_pair  # bench/softmaps.py: the same inputs

    return load_pair()


def part_compute():
    from solvers.softmaps import soft_map

    if NPZ.exists():
        print(f"{NPZ} exists: not recomputed", flush=True)
        return None
    cat, lion, gt, lm = load()
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    before = loadavg()
    t0 = time.perf_counter()
    # The full-resolution map these refinements were measured on (target_points=None).
    res = soft_map(lion, cat, lm[:, ::-1], samples=SAMPLES, max_iter=SWEEPS, refine="none",
                   target_points=None)
    seconds = time.perf_counter() - t0
    info = {"commit": commit, "seconds": seconds, "iterations": res.iterations,
            "residual": res.residual, "converged": res.converged, "load_before": before,
            "load_after": loadavg(), "when": time.strftime("%Y-%m-%d %H:%M UTC",
                                                           time.gmtime())}
    np.savez(NPZ, soft_map=res.soft_map, samples=res.samples, labels=res.labels,
             cell_areas=res.cell_areas, edges=res.edges, edge_weights=res.edge_weights,
             sample_correspondence=res.sample_correspondence, info=json.dumps(info))
    print(info, flush=True)
    return info


def _saved():
    if not NPZ.exists():
        raise SystemExit(f"{NPZ} missing: run the compute part first")
    z = np.load(NPZ)
    return {k: z[k] for k in z.files if k != "info"}, json.loads(str(z["info"]))


def part_compare():
    from softmaps import Evaluator

    from solvers.softmaps.descriptors import eigenpairs
    from solvers.softmaps.extraction import extract_correspondence, sinkhorn_projection

    cat, lion, gt, lm = load()
    saved, info = _saved()
    ev = Evaluator(cat, gt)
    eigenpairs(lion, ZOOMOUT[1])  # cached before timing anything (ZoomOut needs them)
    eigenpairs(cat, ZOOMOUT[1])
    fixed = np.arange(len(lm))  # the landmark rows (samples 0..4: seeds first)
    common = dict(labels=saved["labels"], samples=saved["samples"],
                  cell_areas=saved["cell_areas"], edges=saved["edges"], fixed=fixed,
                  zoomout_range=ZOOMOUT)
    rows = []
    for iterations in (0,) + SINKHORN_ITERATIONS:
        before = loadavg()
        t0 = time.perf_counter()
        if iterations:
            proj = sinkhorn_projection(saved["soft_map"], saved["cell_areas"], cat.areas,
                                       fixed=fixed, max_iter=iterations, tol=1e-12)
            projected = proj.rows
            sk = {"iterations": proj.iterations, "residual": proj.residual,
                  "initial_residual": proj.initial_residual}
        else:
            projected = saved["soft_map"]
            sk = {"iterations": 0, "residual": None, "initial_residual": None}
        t_proj = time.perf_counter() - t0
        for extraction in ("mode", "barycentric"):
            for refine in ("none", "zoomout"):
                t1 = time.perf_counter()
                out = extract_correspondence(lion, cat, projected, extraction=extraction,
                                             refine=refine, **common)
                row = {"sinkhorn_iterations": iterations, **sk,
                       "sinkhorn_seconds": t_proj, "extraction": extraction,
                       "refine": refine, "error": ev(out.correspondence),
                       "distinct_targets": int(len(np.unique(out.correspondence))),
                       "seconds": time.perf_counter() - t1, "load_before": before,
                       "load_after": loadavg()}
                rows.append(row)
                print(row, flush=True)
        del projected
    # The library route: soft_map's default projection (SINKHORN_ITERATIONS, SINKHORN_TOL).
    from solvers.softmaps.extraction import SINKHORN_ITERATIONS as DEFAULT_IT
    from solvers.softmaps.extraction import SINKHORN_TOL

    before = loadavg()
    t0 = time.perf_counter()
    out = extract_correspondence(lion, cat, saved["soft_map"], extraction="mode",
                                 refine="sinkhorn+zoomout", **common)
    rows.append({"library_default": f"refine='sinkhorn+zoomout' (max {DEFAULT_IT} "
                 f"scalings, tol {SINKHORN_TOL:g})", "sinkhorn_iterations":
                 out.sinkhorn.iterations, "residual": out.sinkhorn.residual,
                 "initial_residual": out.sinkhorn.initial_residual, "extraction": "mode",
                 "refine": "zoomout", "error": ev(out.correspondence),
                 "distinct_targets": int(len(np.unique(out.correspondence))),
                 "seconds": time.perf_counter() - t0, "load_before": before,
                 "load_after": loadavg()})
    print(rows[-1], flush=True)
    return {"map": info, "rows": rows}


def render(data) -> str:
    out = ["# Soft maps: refinements with and without Sinkhorn projection "
           "(bench/softmaps_refinement.py)", "",
           "Each section: one lion -> cat soft map (first 5 landmark pairs, 1,024 "
           f"farthest-point lion samples, {SWEEPS} sweeps, soft_map's defaults at the commit "
           "named), computed once by `SOFTMAPS_NPZ=<file> .venv/bin/python "
           "bench/softmaps_refinement.py compute` and saved to npz; every row of the section "
           "extracts from that same map (`SOFTMAPS_NPZ=<file> ... compare`).", "",
           "Error: mean geodesic error on the cat over all 5,000 lion vertices / sqrt(cat "
           "area) (heat-method distances, the evaluator of bench/softmaps.py). Sinkhorn: KL "
           "projection of the map onto the doubly-stochastic set w.r.t. source cell areas and "
           "cat vertex areas, landmark rows fixed; residual = L1 violation of the target "
           "marginal (before: initial). ZoomOut: range (20, 50, 1), soft_map's default. "
           "Distinct targets: cat vertices hit by the 5,000 lion vertices.", ""]
    for cmp_ in data["maps"]:
        out += _render_map(cmp_)
    out += ["", READING]
    return "\n".join(out)


def _render_map(cmp_) -> list[str]:
    info = cmp_["map"]
    out = [f"## Map computed at commit {info['commit']} ({info['when']})", "",
           f"`{cmp_['npz']}`: {info['iterations'] + 1} sweeps, residual "
           f"{info['residual']:.3g}, converged {info['converged']}; {info['seconds']:.0f} s at "
           f"load {info['load_before']} -> {info['load_after']}. Compared {cmp_['when']}.", "",
           "| Sinkhorn scalings | marginal residual (before -> after) | extraction | ZoomOut "
           "| error | distinct targets | seconds (projection + extraction) | load before "
           "| load after |", "|---|---|---|---|---|---|---|---|---|"]
    for r in cmp_["rows"]:
        if r.get("library_default"):
            res = f"{r['initial_residual']:.3g} -> {r['residual']:.3g}"
            out.append(f"| {r['library_default']}: {r['sinkhorn_iterations']} | {res} | "
                       f"{r['extraction']} | (20, 50, 1) | {1e3 * r['error']:.2f}e-3 | "
                       f"{r['distinct_targets']} | {r['seconds']:.1f} | {r['load_before']} "
                       f"| {r['load_after']} |")
            continue
        res = "" if r["residual"] is None else \
            f"{r['initial_residual']:.3g} -> {r['residual']:.3g}"
        zo = "(20, 50, 1)" if r["refine"] == "zoomout" else "-"
        out.append(f"| {r['sinkhorn_iterations'] or '-'} | {res} | {r['extraction']} | {zo} "
                   f"| {1e3 * r['error']:.2f}e-3 | {r['distinct_targets']} | "
                   f"{r['sinkhorn_seconds']:.1f} + {r['seconds']:.1f} | {r['load_before']} "
                   f"| {r['load_after']} |")
    out.append("")
    return out


READING = """## Reading

Two maps: commit 47c8bac (plain Alg. 4 sweeps) and commit b723707 (soft_map's default
adaptive over-relaxation, same fixed point); both stopped after 51 sweeps, far from
converged (residual 0.906 / 0.999), and they give nearly the same errors.

- The Sinkhorn projection does not improve the lion -> cat correspondence.  Before ZoomOut
  it makes it worse, on both maps: mode 77.2e-3 -> 86.4e-3 to 86.8e-3, barycentric
  79.8e-3 -> 86.4e-3 to 86.7e-3 (5 to 100 scalings), although the extracted map reaches
  more cat vertices (521 -> about 710 distinct targets with the mode).  The soft map is far
  from bijective (L1 target-marginal violation 0.434 / 0.435 before projection, for a total
  mass of ~1); our reading, not measured further: scaling the columns up where b is small
  pulls the maxima of ambiguous rows towards regions the map hardly reaches, mostly to the
  wrong places there.
- After ZoomOut the difference is within 0.6 % (21.44e-3 to 21.52e-3 with the projection,
  21.54e-3 / 21.56e-3 without): ZoomOut's spectral re-reading erases what the projection
  changed.  One pair, no held-out data: not a measurable improvement.
- The projection is cheap next to the map: 5 / 20 / 100 scalings cost 0.7-0.9 / 1.5-1.6 /
  5.8-6.6 s on 1,024 x 7,207 rows at load 9-14 (times inflated by the load), and converge
  linearly (residual 0.041 / 3.1e-3 / 1.3e-8); the library default (at most 50 scalings,
  stop at 1e-3) took 28.
- Decision: `refine="sinkhorn"` and `"sinkhorn+zoomout"` stay options; the default stays
  `refine="zoomout"` without projection.
"""


def main(argv):
    parts = argv or ["compute", "compare"]
    for part in parts:
        if part == "render":
            continue
        result = globals()[f"part_{part}"]()
        if part == "compare":
            data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
            entry = {**result, "npz": str(NPZ),
                     "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
            maps = [m for m in data.get("maps", []) if m["npz"] != str(NPZ)]
            data["maps"] = [*maps, entry]
            RESULTS.write_text(json.dumps(data, indent=1, default=float))
    if RESULTS.exists():
        RESULTS.with_suffix(".md").write_text(render(json.loads(RESULTS.read_text())) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])
