"""The default decision of a W2 distance: cost models, route coverage and accuracy.

Parts (``.venv/bin/python bench/distance_routes.py PART [--mesh=NAME,...]``):

* ``calibrate`` (timing: run under ``cpu bench`` with BLAS threads pinned) — bounded MMP
  solves (tvb-gdist) on meshes from 700 to 50k vertices at several reach fractions, and
  network-simplex LPs (``ot.emd``) of several sizes; fits the constants of
  ``solvers.geodesics.mmp_solve_seconds`` and ``solvers.transport.exact.LP_COEF`` and
  prints them (they are committed by hand: a decision never reads timings at run time).
* ``validate`` (timing) — the exact route run end to end where the default decision takes it
  (25 + 25 point masses on every mesh, the bench's bumps on the small meshes): measured time
  against the modelled ``exact_seconds``.
* ``coverage`` — the decision only (cheap): route and modelled seconds for bumps of radius
  0.05 / 0.1 / 0.2 near / middle / far and for 25 + 25 points on every shared mesh.
* ``accuracy`` (``cpu run``) — the default ``wasserstein_distance(mesh, mu0, mu1)`` against
  the exact LP with squared exact (MMP) geodesics (:func:`oracle`), cached per mesh and case
  in ``bench/results/distance_routes_oracles.json`` (``oracles`` computes missing ones).
* ``render`` — rewrite ``bench/results/distance_routes.md`` from the json.

Cases (as in ``bench/convolutional.py``): bumps of the README's kind (``{"vertex": i,
"radius": 0.1}``) at vertex 0 and at the vertices at 15 / 50 / 90 % of the largest geodesic
distance from it, and 25 + 25 scattered point masses.  Meshes with several components
(suzanne, beetle, teapot): the cases live on the largest component (vertex 0 is replaced by
its first vertex whose bump stays on it, targets likewise; points drawn on it).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MESHES = ROOT.parent / "shared" / "meshes"

from _common import load1, service_bump  # noqa: E402

from solvers import load_mesh  # noqa: E402

ALL_MESHES = ["woody.obj", "suzanne.obj", "beetle.obj", "cow.obj", "spot.obj", "alligator.obj",
              "teapot.obj", "homer.obj", "fandisk.obj", "cheburashka.obj", "rocker-arm.obj",
              "stanford-bunny.obj", "nefertiti.obj"]
CALIBRATION_MESHES = ["woody.obj", "cow.obj", "homer.obj", "rocker-arm.obj",
                      "stanford-bunny.obj", "nefertiti.obj"]
REACHES = (0.01, 0.05, 0.2, 0.5, 1.0)
LP_SIZES = (25, 100, 300, 1000, 2000)
ORDER = ("near", "middle", "far", "points")
STORE = ROOT / "bench" / "results" / "distance_routes.json"
ORACLES = ROOT / "bench" / "results" / "distance_routes_oracles.json"


def _timed(fn, *args, **kwargs):
    start = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - start


# -- calibration ----------------------------------------------------------------------------
def mmp_rows(names):
    """Bounded MMP solves at the REACHES fractions (edge-path quantiles) from two sources."""
    from solvers.geodesics import edge_path_distances, geodesic_distances_within

    rows = []
    for name in names:
        mesh = load_mesh(MESHES / name)
        geodesic_distances_within(mesh, 0, 0.0)  # junction closure, fan split: one-time
        sources = [0] if mesh.n > 20_000 else [0, mesh.n // 2]
        for s in sources:
            paths = edge_path_distances(mesh, [s])[0]
            finite = np.sort(paths[np.isfinite(paths)])
            for reach in REACHES:
                bound = np.inf if reach >= 1 else float(finite[int(reach * (len(finite) - 1))])
                d, seconds = _timed(geodesic_distances_within, mesh, s, bound)
                rows.append(dict(name=name, n=mesh.n, source=s, want=reach,
                                 reach=float(np.isfinite(d).mean()), seconds=seconds,
                                 load=load1()))
                print(rows[-1], flush=True)
    return rows


def lp_rows(sizes):
    import ot

    rng = np.random.default_rng(0)
    rows = []
    for k in sizes:
        x, y = rng.random((k, 3)), rng.random((k, 3))
        cost = ((x[:, None, :] - y[None, :, :]) ** 2).sum(axis=2)
        a = np.full(k, 1.0 / k)
        _, seconds = _timed(ot.emd, a, a, cost, numItermax=10**8)
        rows.append(dict(k=k, seconds=seconds, load=load1()))
        print(rows[-1], flush=True)
    return rows


def fit_mmp(rows):
    """Least squares on log seconds: ``s n + c n^p reach^q``."""
    from scipy.optimize import least_squares

    n = np.array([r["n"] for r in rows], dtype=float)
    reach = np.array([max(r["reach"], 1e-6) for r in rows])
    t = np.array([r["seconds"] for r in rows])

    def model(x):
        s, c, p, q = np.exp(x[0]), np.exp(x[1]), x[2], x[3]
        return s * n + c * n**p * reach**q

    fit = least_squares(lambda x: np.log(model(x)) - np.log(t),
                        x0=[np.log(1.4e-5), np.log(3e-7), 1.7, 1.1])
    s, c, p, q = np.exp(fit.x[0]), np.exp(fit.x[1]), fit.x[2], fit.x[3]
    ratio = t / model(fit.x)
    return dict(setup=float(s), coef=float(c), power=float(p), reach_power=float(q),
                ratio_min=float(ratio.min()), ratio_max=float(ratio.max()),
                ratio_median=float(np.median(ratio)))


def fit_lp(rows):
    k = np.array([r["k"] for r in rows], dtype=float)
    t = np.array([r["seconds"] for r in rows])
    unit = k * k * np.log2(k * k)
    big = k >= 300  # small LPs are dominated by call overhead
    return dict(coef=float(np.max(t[big] / unit[big])),
                ratios=[float(x) for x in t / unit])


# -- cases ----------------------------------------------------------------------------------
def _largest_component(mesh):
    labels = np.asarray(mesh.component_labels)
    return labels == np.bincount(labels).argmax()


RADIUS = [0.1]  # bump radius of the cases (``--radius=``; 0.1 is the README's)


def key_of(name: str, label: str) -> str:
    """Oracle cache key of a case (the radius is named when it is not 0.1)."""
    r = RADIUS[0]
    return f"{name}|{label}" if r == 0.1 or label == "points" else f"{name}|{label}|r{r:g}"


def _bump_inside(mesh, inside, i):
    m = service_bump(mesh, i, RADIUS[0])
    return m if np.all(inside[m > 0]) else None


def cases(mesh, name):
    """``{label: (mu0, mu1, target)}``: the module docstring's cases."""
    from solvers.geodesics import geodesic_distances

    inside = _largest_component(mesh)
    base = 0
    if not inside.all():
        base = next(int(i) for i in np.flatnonzero(inside)
                    if _bump_inside(mesh, inside, int(i)) is not None)
    d0 = geodesic_distances(mesh, [base])[0]
    d0 = np.where(inside & np.isfinite(d0), d0, np.nan)
    top = np.nanmax(d0)
    out = {}
    for label, frac in (("near", 0.15), ("middle", 0.5), ("far", 0.9)):
        order = np.argsort(np.abs(np.nan_to_num(d0, nan=np.inf) - frac * top), kind="stable")
        j = next(int(k) for k in order if _bump_inside(mesh, inside, int(k)) is not None)
        out[label] = (service_bump(mesh, base, RADIUS[0]), service_bump(mesh, j, RADIUS[0]), j)
    rng = np.random.default_rng(len(name))
    pool = np.flatnonzero(inside)
    p0, p1 = np.zeros(mesh.n), np.zeros(mesh.n)
    p0[rng.choice(pool, 25, replace=False)] = 1 / 25
    p1[rng.choice(pool, 25, replace=False)] = 1 / 25
    out["points"] = (p0, p1, None)
    return out


# -- coverage and validation ---------------------------------------------------------------------
def coverage_rows(names, radii=(0.05, 0.1, 0.2)):
    """The decision on the cases at each bump radius (and the points)."""
    from solvers.transport.decision import decide_distance

    rows, kept = [], RADIUS[0]
    for name in names:
        mesh = load_mesh(MESHES / name)
        for radius in radii:
            RADIUS[0] = radius
            for label, (m0, m1, _) in cases(mesh, name).items():
                if label == "points" and radius != radii[0]:
                    continue
                dec, seconds = _timed(decide_distance, mesh, m0, m1)
                rows.append(dict(name=name, n=mesh.n, case=label,
                                 radius=None if label == "points" else radius,
                                 support=[int(np.count_nonzero(m0)), int(np.count_nonzero(m1))],
                                 route=dec.method, exact_seconds=dec.exact_seconds,
                                 estimated_seconds=dec.estimated_seconds,
                                 substeps=dec.substeps, decide_seconds=seconds))
                print(rows[-1], flush=True)
    RADIUS[0] = kept
    return rows


def validate_rows(names, labels=ORDER):
    """The exact route, timed, where the default decision takes it."""
    from solvers.transport.decision import decide_distance
    from solvers.transport.exact import exact_wasserstein_distance

    rows = []
    for name in names:
        mesh = load_mesh(MESHES / name)
        exact_wasserstein_distance(mesh, *cases(mesh, name)["points"][:2])  # warm: fan split
        for label, (m0, m1, _) in cases(mesh, name).items():
            if label not in labels:
                continue
            dec = decide_distance(mesh, m0, m1)
            if dec.method != "exact":
                continue
            before = load1()
            res, seconds = _timed(exact_wasserstein_distance, mesh, m0, m1)
            rows.append(dict(name=name, case=label, estimate=dec.exact_seconds,
                             seconds=seconds, cost_seconds=res.cost_seconds,
                             lp_seconds=res.lp_seconds, load_before=before,
                             load_after=load1()))
            print(rows[-1], flush=True)
    return rows


# -- accuracy -----------------------------------------------------------------------------------
def _lp(mesh, m0, m1, points=None):
    import ot

    from solvers.geodesics import geodesic_distances
    from solvers.regularization import quantize

    i0, i1 = np.flatnonzero(m0), np.flatnonzero(m1)
    w0, w1 = m0[i0], m1[i1]
    if points is not None:
        i0, w0 = quantize(mesh.vertices, m0, points)
        i1, w1 = quantize(mesh.vertices, m1, points)
    cost = geodesic_distances(mesh, i0, i1) ** 2
    return float(ot.emd2(w0 / w0.sum(), w1 / w1.sum(), cost, numItermax=10**8))


FULL_ROWS = 1500  # the oracle solves from every point of the smaller support up to this,
FULL_MESH = 20_000  # on meshes up to this many vertices ...
QUANTIZED = (64, 256)  # ... else the exact LP between quantizations of these sizes (the last
# is the oracle; the first shows how far the quantization still moves it)


def _quantized(mesh, m, k):
    from solvers.regularization import quantize

    idx, w = quantize(mesh.vertices, m, k)
    out = np.zeros(mesh.n)
    out[idx] = w
    return out / out.sum()


def oracle(mesh, m0, m1):
    """The exact LP with squared exact (MMP) geodesics: ``ot.emd2`` on the full cost matrix
    between the supports (``solvers.geodesics.geodesic_distances``: one solve per point of
    the smaller support, independent of the exact route's bounded plan) when that support
    has at most FULL_ROWS points and the mesh at most FULL_MESH vertices; else the exact
    route between the QUANTIZED-point quantizations (mass-weighted farthest points, each
    point's mass moved to its nearest representative)."""
    from solvers.transport.exact import exact_wasserstein_distance

    rows = min(np.count_nonzero(m0), np.count_nonzero(m1))
    if rows <= FULL_ROWS and mesh.n <= FULL_MESH:
        return {"lp": _lp(mesh, m0, m1), "lp_kind": "full"}
    out = {}
    for k in QUANTIZED:
        out[f"lp_q{k}"] = exact_wasserstein_distance(mesh, _quantized(mesh, m0, k),
                                                     _quantized(mesh, m1, k)).value
    return {**out, "lp": out[f"lp_q{QUANTIZED[-1]}"],
            "lp_kind": f"quantized to {QUANTIZED[-1]} (q{QUANTIZED[0]}: "
                       f"{out[f'lp_q{QUANTIZED[0]}'] / out[f'lp_q{QUANTIZED[-1]}'] - 1:+.2%})"}


def oracle_rows(names, oracles, labels=ORDER):
    for name in names:
        mesh = load_mesh(MESHES / name)
        for label, (m0, m1, _) in cases(mesh, name).items():
            key = key_of(name, label)
            if label not in labels or key in oracles:
                continue
            before = load1()
            entry, seconds = _timed(oracle, mesh, m0, m1)
            oracles[key] = {**entry, "lp_s": seconds, "load_before": before,
                            "load_after": load1()}
            print(key, oracles[key], flush=True)
            _save_oracles(oracles)


def accuracy_rows(names, oracles, labels=ORDER):
    from solvers.convolutional import wasserstein_distance

    rows = []
    for name in names:
        mesh = load_mesh(MESHES / name)
        for label, (m0, m1, j) in cases(mesh, name).items():
            if label not in labels:
                continue
            key = key_of(name, label)
            if key not in oracles:
                oracle_rows([name], oracles, [label])
            before = load1()
            res, seconds = _timed(wasserstein_distance, mesh, m0, m1)
            dec = res.decision
            rows.append(dict(name=name, n=mesh.n, case=label, target=j, radius=RADIUS[0],
                             support=[int(np.count_nonzero(m0)), int(np.count_nonzero(m1))],
                             value=res.value, route=res.method, seconds=seconds,
                             gamma=dec.gamma, substeps=dec.substeps,
                             exact_seconds=dec.exact_seconds, converged=bool(res.converged),
                             lp=oracles[key]["lp"], lp_kind=oracles[key]["lp_kind"],
                             load_before=before, load_after=load1()))
            print(rows[-1], flush=True)
            yield rows


SWEEP_FACTORS = (0.5, 1.0, 2.0, 4.0)


def sweep_rows(names, oracles, labels=("near", "middle", "far")):
    """The debiased convolutional value at ``c`` x the policy's gamma (substeps by the
    policy's rule for that gamma), against the exact LP: is extrapolation in gamma
    (Richardson) of any use?"""
    from solvers.convolutional import wasserstein_distance
    from solvers.kernels import heat_time
    from solvers.regularization import VALUE_MIN_H, value_substeps
    from solvers.transport.decision import decide_distance

    rows = []
    for name in names:
        mesh = load_mesh(MESHES / name)
        for label, (m0, m1, _) in cases(mesh, name).items():
            if label not in labels:
                continue
            if key_of(name, label) not in oracles:
                oracle_rows([name], oracles, [label])
            policy = decide_distance(mesh, m0, m1, method="convolutional")
            reg = policy.regularization
            d_eff = max(reg.distance, 4 * max(reg.h, VALUE_MIN_H))  # as the policy
            row = dict(name=name, case=label, lp=oracles[key_of(name, label)]["lp"],
                       gamma=reg.gamma, values={}, load_before=load1())
            for c in SWEEP_FACTORS:
                gamma = c * reg.gamma
                steps, _ = value_substeps(mesh, d_eff, heat_time(gamma))
                res = wasserstein_distance(mesh, m0, m1, gamma=gamma, substeps=steps,
                                           debiased=True)
                row["values"][str(c)] = [res.value, steps]
            row["load_after"] = load1()
            rows.append(row)
            print(row, flush=True)
    return rows


def _save_oracles(oracles):
    merged = json.loads(ORACLES.read_text()) if ORACLES.exists() else {}
    merged.update(oracles)
    ORACLES.write_text(json.dumps(merged, indent=1))


# -- rendering ----------------------------------------------------------------------------------
def _merge(old, new, key):
    fresh = {key(r) for r in new}
    return [r for r in old if key(r) not in fresh] + new


def render(data) -> str:
    lines = ["# Default W2 distances: route decision, cost models, accuracy", "",
             "The default `wasserstein_distance(domain, mu0, mu1)` (and `POST .../distances` "
             "without options) decides its route and regularization from the request and the "
             "stored domain alone (`solvers/transport/decision.py`).  Script: "
             "`bench/distance_routes.py` (module docstring: parts and cases).  All 13 shared "
             "meshes are used; suzanne (3 components), beetle (2) and teapot (4) have several "
             "components: their cases lie on the largest one (a bump that would straddle two "
             "components is replaced by the next admissible vertex)."]
    lines += _calibration_lines(data.get("calibration"))
    lines += _validation_lines(data.get("validation", []))
    lines += _coverage_lines(data.get("coverage", []))
    lines += _accuracy_lines(data.get("accuracy", []))
    lines += _sweep_lines(data.get("sweep", []))
    return "\n".join(lines) + "\n"


def _calibration_lines(cal):
    if not cal:
        return []
    f, lp = cal["fit"], cal["lp_fit"]
    lines = ["", "## Cost models (calibration)", "",
             f"Command: `{cal['command']}`; load {cal['load_before']:.2f} before, "
             f"{cal['load_after']:.2f} after.", "",
             f"MMP solve (tvb-gdist) fit: `{f['setup']:.3g} n + {f['coef']:.3g} n^"
             f"{f['power']:.3f} reach^{f['reach_power']:.3f}` seconds; measured/model "
             f"{f['ratio_min']:.2f}-{f['ratio_max']:.2f} (median {f['ratio_median']:.2f}).  "
             f"LP (`ot.emd`): `{lp['coef']:.3g} n0 n1 log2(n0 n1)` (largest ratio of the "
             "sizes >= 300).", "",
             "| mesh | n | source | reach | seconds | load |", "|---|---|---|---|---|---|"]
    for r in cal["mmp"]:
        lines.append(f"| {r['name']} | {r['n']} | {r['source']} | {r['reach']:.3f} | "
                     f"{r['seconds']:.3f} | {r['load']:.2f} |")
    lines += ["", "| LP size | seconds |", "|---|---|"]
    lines += [f"| {r['k']} x {r['k']} | {r['seconds']:.3f} |" for r in cal["lp"]]
    return lines


def _validation_lines(rows):
    if not rows:
        return []
    lines = ["", "## Exact route: modelled against measured time", "",
             "Command: `cpu bench env OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 "
             ".venv/bin/python bench/distance_routes.py validate` (warm: fan split and "
             "junction closure built).", "",
             "| mesh | case | modelled s | measured s | measured/modelled | geodesics s | "
             "LP s | load |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['name']} | {r['case']} | {r['estimate']:.1f} | {r['seconds']:.1f}"
                     f" | {r['seconds'] / r['estimate']:.2f} | {r['cost_seconds']:.1f} | "
                     f"{r['lp_seconds']:.2f} | {r['load_before']:.2f}/{r['load_after']:.2f} |")
    return lines


def _coverage_lines(rows):
    if not rows:
        return []
    from solvers.transport.decision import EXACT_BUDGET_SECONDS

    lines = ["", "## Which inputs take the exact route", "",
             "Command: `.venv/bin/python bench/distance_routes.py coverage` (the decision "
             f"only).  Exact when the modelled time is at most {EXACT_BUDGET_SECONDS:.0f} s.  "
             "Cells: route (modelled exact seconds; supports).", "",
             "| mesh | n | case | r = 0.05 | r = 0.1 | r = 0.2 | 25 + 25 points |",
             "|---|---|---|---|---|---|---|"]
    by = {}
    for r in rows:
        by.setdefault((r["name"], r["n"], r["case"]), {})[r["radius"]] = r
    for (name, n, case), cells in by.items():
        def cell(r):
            if r is None:
                return "-"
            est = "-" if r["exact_seconds"] is None else f"{r['exact_seconds']:.3g} s"
            return f"{r['route']} ({est}; {r['support'][0]}/{r['support'][1]})"
        if case == "points":
            lines.append(f"| {name} | {n} | points | | | | {cell(cells.get(None))} |")
        else:
            lines.append(f"| {name} | {n} | {case} | {cell(cells.get(0.05))} | "
                         f"{cell(cells.get(0.1))} | {cell(cells.get(0.2))} | |")
    return lines


def _accuracy_lines(rows):
    if not rows:
        return []
    lines = ["", "## Accuracy of the default against the exact LP (exact geodesics)", "",
             "Command: `cpu run env OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 .venv/bin/python "
             "bench/distance_routes.py accuracy [--mesh=...]`.  LP = `ot.emd2` on the full matrix "
             "of squared exact (MMP, `solvers.geodesics`) geodesics between the supports when "
             f"the smaller one has at most {FULL_ROWS} points and the mesh at most "
             f"{FULL_MESH} vertices (independent of the exact route's bounded solves); else "
             "the exact route between "
             f"{QUANTIZED[-1]}-point quantizations of both inputs (the 'LP oracle' column "
             f"gives the {QUANTIZED[0]}-point value against it); cached in "
             "`bench/results/distance_routes_oracles.json`.  Times: wall clock of the default "
             "call, warm after the first case of a mesh; load: 1-minute load average "
             "before/after.", "",
             "| mesh | case | supports | route | default | exact LP | error | default s | "
             "modelled exact s | gamma (substeps) | LP oracle | load |", "|" + "---|" * 12]
    for r in rows:
        reg = "-" if r["gamma"] is None else f"{r['gamma']:.4g} ({r['substeps']})"
        case = r["case"] if r.get("radius", 0.1) == 0.1 else f"{r['case']} (r {r['radius']:g})"
        model = "-" if r["exact_seconds"] is None else f"{r['exact_seconds']:.3g}"
        lines.append(f"| {r['name']} | {case} | {r['support'][0]}/{r['support'][1]} | "
                     f"{r['route']} | {r['value']:.5g} | {r['lp']:.5g} | "
                     f"{r['value'] / r['lp'] - 1:+.2%} | {r['seconds']:.2f} | {model} | {reg} | "
                     f"{r['lp_kind']} | {r['load_before']:.1f}/{r['load_after']:.1f} |")
    worst = {}
    for r in rows:
        err = abs(r["value"] / r["lp"] - 1)
        if err > worst.get(r["route"], (0.0, None))[0]:
            worst[r["route"]] = (err, f"{r['name']} {r['case']} r {r.get('radius', 0.1):g}")
    lines += ["", "Worst error by route: " + ", ".join(
        f"{route} {err:.2%} ({where})" for route, (err, where) in worst.items()) + "."]
    from solvers.transport.decision import EXACT_BUDGET_SECONDS as budget

    exact = [(r["seconds"] / r["exact_seconds"], r) for r in rows
             if r["route"] == "exact" and r["exact_seconds"] and r["seconds"] > 1.0]
    if exact:
        hi, top = max(exact, key=lambda x: x[0])
        lo = min(x[0] for x in exact)
        lines += ["", f"Exact rows above 1 s, measured/modelled time: {lo:.2f}-{hi:.2f} (worst: "
                  f"{top['name']} {top['case']} r {top.get('radius', 0.1):g}, load "
                  f"{top['load_before']:.1f}).  The model prices the first round of bounded "
                  "solves (times ROUNDS_FACTOR); on near and wide bumps the loop regrows many "
                  "rows' bounds several times (more rounds than modelled), and a loaded "
                  f"machine slows every run.  A run modelled at the {budget:.0f} s budget "
                  f"would take {budget * hi:.0f} s at the worst ratio seen (job limit 600 s); "
                  "a model of the later rounds is still to do."]
    return lines


def _sweep_lines(rows):
    if not rows:
        return []
    head = " | ".join(f"{c:g} gamma" for c in SWEEP_FACTORS)
    lines = ["", "## Extrapolation in gamma (convolutional route)", "",
             "Command: `cpu run .venv/bin/python bench/distance_routes.py sweep`.  The debiased "
             "value at c x the policy's gamma (substeps by the policy's rule), error against "
             "the exact LP; R(1,2) = 2 V(gamma) - V(2 gamma), R(2,4) = 2 V(2 gamma) - V(4 "
             "gamma) (Richardson, first order).", "",
             f"| mesh | case | {head} | R(1,2) | R(2,4) |", "|---|---|" + "---|" * 6]
    worst = {}
    for r in rows:
        v = {float(c): x[0] for c, x in r["values"].items()}
        errs = {f"{c:g}": v[c] / r["lp"] - 1 for c in SWEEP_FACTORS}
        errs["R(1,2)"] = (2 * v[1.0] - v[2.0]) / r["lp"] - 1
        errs["R(2,4)"] = (2 * v[2.0] - v[4.0]) / r["lp"] - 1
        for k, e in errs.items():
            worst[k] = max(worst.get(k, 0.0), abs(e))
        lines.append(f"| {r['name']} | {r['case']} | " + " | ".join(
            f"{e:+.1%}" for e in errs.values()) + " |")
    lines.append("| worst | | " + " | ".join(f"{e:.1%}" for e in worst.values()) + " |")
    return lines


def main(argv):
    parts = [a for a in argv if not a.startswith("--")] or ["render"]
    names = [n for a in argv if a.startswith("--mesh=") for n in a[7:].split(",")]
    labels = [c for a in argv if a.startswith("--cases=") for c in a[8:].split(",")] or ORDER
    RADIUS[0] = next((float(a[9:]) for a in argv if a.startswith("--radius=")), 0.1)
    data = json.loads(STORE.read_text()) if STORE.exists() else {}

    def save():
        STORE.write_text(json.dumps(data, indent=1))

    if "calibrate" in parts:
        before = load1()
        mmp = mmp_rows(names or CALIBRATION_MESHES)
        lp = lp_rows(LP_SIZES)
        data["calibration"] = dict(mmp=mmp, lp=lp, fit=fit_mmp(mmp), lp_fit=fit_lp(lp),
                                   load_before=before, load_after=load1(),
                                   command="cpu bench env OMP_NUM_THREADS=1 "
                                   "OPENBLAS_NUM_THREADS=1 .venv/bin/python "
                                   "bench/distance_routes.py calibrate")
        print(json.dumps(data["calibration"]["fit"]), json.dumps(data["calibration"]["lp_fit"]))
        save()
    if "validate" in parts:
        fresh = validate_rows(names or ALL_MESHES, labels)
        data["validation"] = _merge(data.get("validation", []), fresh,
                                    lambda r: (r["name"], r["case"]))
        save()
    if "coverage" in parts:
        fresh = coverage_rows(names or ALL_MESHES)
        data["coverage"] = _merge(data.get("coverage", []), fresh,
                                  lambda r: (r["name"], r["case"], r["radius"]))
        save()
    if "oracles" in parts:
        oracles = json.loads(ORACLES.read_text()) if ORACLES.exists() else {}
        oracle_rows(names or ALL_MESHES, oracles, labels)
    if "sweep" in parts:
        oracles = json.loads(ORACLES.read_text()) if ORACLES.exists() else {}
        fresh = sweep_rows(names or ["cow.obj", "spot.obj", "alligator.obj", "homer.obj",
                                     "fandisk.obj", "cheburashka.obj"], oracles)
        data["sweep"] = _merge(data.get("sweep", []), fresh, lambda r: (r["name"], r["case"]))
        save()
    if "accuracy" in parts:
        oracles = json.loads(ORACLES.read_text()) if ORACLES.exists() else {}
        for rows in accuracy_rows(names or ALL_MESHES, oracles, labels):
            # merged into the file as it is now: another accuracy run may be writing it
            data = json.loads(STORE.read_text()) if STORE.exists() else {}
            data["accuracy"] = _merge(data.get("accuracy", []), rows,
                                      lambda r: (r["name"], r["case"], r.get("radius", 0.1)))
            data["accuracy"].sort(key=lambda r: (r.get("radius", 0.1),
                                                 ALL_MESHES.index(r["name"]),
                                                 ORDER.index(r["case"])))
            save()
    out = ROOT / "bench" / "results" / "distance_routes.md"
    out.write_text(render(data))
    print(f"wrote {out}")


if __name__ == "__main__":
    os.chdir(ROOT)
    main(sys.argv[1:])
