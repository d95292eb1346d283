"""§3.7 applications: hemisphere grid kernel vs mesh kernel, BRDF interpolation timings and
pictures, skeleton layouts (capsule, spot) against linear interpolation.

Run: ``.venv/bin/python bench/applications.py`` (BLAS pinned to 1 thread).  Writes
``bench/results/applications.md`` and the pictures ``bench/results/applications_spheres.png``
(Wasserstein barycenters) and ``bench/results/applications_linear.png`` (linear mix).
Every figure records the 1-minute load average before / after it (2 shared cores).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MESHES = ROOT.parent / "shared" / "meshes"
OUT = ROOT / "bench" / "results"

from solvers import TriangleMesh, load_mesh  # noqa: E402
from solvers.convolutional.brdf import (  # noqa: E402
    bilinear_weights,
    interpolate_brdfs,
    local_maxima,
    peak_direction,
    png_bytes,
    render_spheres,
)
from solvers.convolutional.hemisphere import HemisphereGrid, kernel_discrepancy  # noqa: E402
from solvers.convolutional.skeleton import (  # noqa: E402
    segment_inside_fraction,
    skeleton_layout,
)


def load() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


class Figure:
    def __init__(self, title: str):
        self.title = title
        self.lines: list[str] = []

    def __enter__(self):
        self.before = load()
        return self

    def __exit__(self, *exc):
        self.after = load()


def kernels() -> Figure:
    with Figure("Grid kernel vs triangulated-hemisphere heat kernel") as fig:
        fig.lines += [
            "One Dirac per source (5 sources from pole to equator) diffused by both kernels "
            "at t = gamma/4; L1 between the normalized results on the grid points (0 = same, "
            "2 = disjoint) and the ratio of their RMS geodesic spreads (grid / mesh). "
            "Mesh kernel: implicit Euler, 8 substeps, robust Laplacian, Neumann at the "
            "equator; grid kernels: the latitude-modulated separable Gaussian (route separable) "
            "or the great-circle Gaussian (route geodesic), both rescaled symmetrically to "
            "conserve mass.", "",
            "| grid | route | gamma | L1 mean | L1 max | spread ratio min-max | "
            "kernel build |", "|---|---|---|---|---|---|---|"]
        for shape in ((12, 48), (16, 64), (24, 96)):
            for route in ("separable", "geodesic"):
                grid = HemisphereGrid(*shape, method=route)
                for gamma in (2e-3, 5e-3, 2e-2):
                    t0 = time.perf_counter()
                    grid.heat_kernel(gamma / 4)
                    build = time.perf_counter() - t0
                    d = kernel_discrepancy(grid, gamma)
                    ratio = d.spread[:, 0] / d.spread[:, 1]
                    fig.lines.append(
                        f"| {shape[0]}×{shape[1]} | {route} | {gamma:g} | {d.l1.mean():.3f} | "
                        f"{d.l1.max():.3f} | {ratio.min():.3f}-{ratio.max():.3f} | "
                        f"{build * 1e3:.0f} ms |")
    return fig


BROAD = {"model": "blinn-phong", "exponent": 6}
SHARP = {"model": "ashikhmin-shirley", "nu": 300, "nv": 300}
CORNERS = [BROAD, SHARP, {"model": "blinn-phong", "exponent": 40, "kd": 0.3},
           {"model": "ashikhmin-shirley", "nu": 20, "nv": 200, "rd": 0.4}]


def brdf() -> Figure:
    with Figure("BRDF interpolation") as fig:
        th = np.radians([65.0])
        lam = np.linspace(0, 1, 11)
        W = np.stack([1 - lam, lam], axis=1)
        fig.lines += [
            "Highlight motion: Blinn-Phong (e = 6) -> Ashikhmin-Shirley (nu = nv = 300) at "
            "theta_i = 65°, grid 20×40 (cell 4.5°), gamma = 0.002, 11 weights; local maxima "
            "counted at >= 1 % of the largest density.", "",
            "| weight | 0 | 0.1 | 0.2 | 0.3 | 0.4 | 0.5 | 0.6 | 0.7 | 0.8 | 0.9 | 1 |",
            "|---|" + "---|" * 11]
        steps = []
        for route in ("geodesic", "separable"):
            grid = HemisphereGrid(20, 40, method=route)
            t0 = time.perf_counter()
            r = interpolate_brdfs(grid, [BROAD, SHARP], W, th, gamma=2e-3)
            dt = time.perf_counter() - t0
            bary = np.degrees([peak_direction(grid, m)[0] for m in r.masses[0]])
            lin = np.degrees([peak_direction(grid, m)[0] for m in r.linear[0]])
            nmax_lin = [len(local_maxima(grid, m, rel=0.01)) for m in r.linear[0]]
            nmax_bar = [len(local_maxima(grid, m, rel=0.01)) for m in r.masses[0]]
            fig.lines += [
                f"| barycenter ({route}) peak θ_o (°) | "
                + " | ".join(f"{x:.1f}" for x in bary) + " |",
                f"| barycenter ({route}) local maxima | " + " | ".join(map(str, nmax_bar))
                + " |"]
            steps.append(f"{route}: {r.iterations} iterations, residual {r.residual:.2e}, "
                         f"converged {r.converged}, {dt:.2f} s, largest peak step "
                         f"{np.max(np.abs(np.diff(bary))):.1f}°")
        fig.lines += [
            "| linear-mix peak θ_o (°) | " + " | ".join(f"{x:.1f}" for x in lin) + " |",
            "| linear-mix local maxima | " + " | ".join(map(str, nmax_lin)) + " |",
            "", "Barycenters: " + "; ".join(steps) + f". Linear mix: largest peak step "
            f"{np.max(np.diff(lin)):.1f}°.", "",
            "Timings (4 corners, 3×3 bilinear weights, incoming 0-80° in 5 steps; one batch "
            "of n_in × B × k columns):", "",
            "| grid | points | columns | entropy bound | iterations | residual | converged "
            "| time |", "|---|---|---|---|---|---|---|---|"]
        inc = np.radians([0, 20, 40, 60, 80])
        Wb = bilinear_weights(3, 3)
        for shape in ((12, 48), (16, 64)):
            g = HemisphereGrid(*shape)
            for bound in (None, "inputs"):
                t0 = time.perf_counter()
                rb = interpolate_brdfs(g, CORNERS, Wb, inc, gamma=(2 * 0.399 * np.pi / 2
                                                                   / shape[0]) ** 2,
                                       entropy_bound=bound, max_iter=500)
                dt = time.perf_counter() - t0
                fig.lines.append(f"| {shape[0]}×{shape[1]} | {g.n} | {5 * 9 * 4} | {bound} | "
                                 f"{rb.iterations} | {rb.residual:.2e} | {rb.converged} | "
                                 f"{dt:.1f} s |")
                if shape == (16, 64) and bound is None:
                    pic = (g, rb)
        g, rb = pic
        img = render_spheres(g, rb.masses, rb.scale, inc, 3, 3, size=96)
        lin_img = render_spheres(g, rb.linear, rb.scale, inc, 3, 3, size=96)
        (OUT / "applications_spheres.png").write_bytes(png_bytes(img))
        (OUT / "applications_linear.png").write_bytes(png_bytes(lin_img))
        fig.lines += ["", "Pictures (16×64 grid, plain barycenters): "
                      "`applications_spheres.png` (barycenters), `applications_linear.png` "
                      "(linear mix of the same corners)."]
    return fig


def _loop(inner=5):
    edges, n = [], 4
    for a, b in ((0, 1), (2, 3), (0, 2), (1, 3)):
        prev = a
        for _ in range(inner):
            edges.append((prev, n))
            prev, n = n, n + 1
        edges.append((prev, b))
    return n, edges


def skeleton() -> Figure:
    import trimesh

    with Figure("Skeleton layout") as fig:
        fig.lines += ["| mesh | skeleton | gamma | nodes inside (propagation / linear) | "
                      "bones inside (propagation / linear) | iterations | converged | time |",
                      "|---|---|---|---|---|---|---|---|"]
        c = trimesh.creation.capsule(height=2.0, radius=0.35, count=[24, 24])
        cap = TriangleMesh(c.vertices, c.faces)
        z = cap.vertices[:, 2]
        cases = [("capsule (578 v)", cap, "chain of 7, ends fixed", 7,
                  [(i, i + 1) for i in range(6)],
                  {0: [0, 0, 0.8 * z.min()], 6: [0, 0, 0.8 * z.max()]})]
        spot = load_mesh(MESHES / "spot.obj", weld=True)
        hooves = np.array([[0.09, -0.272, 0.009], [-0.09, -0.272, 0.009],
                           [0.083, -0.271, 0.314], [-0.083, -0.271, 0.314]])
        n, e = _loop()
        cases.append(("spot (2930 v)", spot, "4 hooves fixed, 4 chains of 5", n, e,
                      {i: hooves[i] for i in range(4)}))
        cases.append(("spot (2930 v)", spot, "front hoof -> hind hoof, chain of 7", 7,
                      [(i, i + 1) for i in range(6)], {0: hooves[0], 6: hooves[2]}))
        for name, mesh, what, nn, edges, fixed in cases:
            for gamma in (None, (2.0 * mesh.mean_edge_length) ** 2):  # default, (2h)^2
                t0 = time.perf_counter()
                r = skeleton_layout(mesh, nn, edges, fixed, gamma=gamma)
                dt = time.perf_counter() - t0
                ins = int(np.sum(r.winding > 0.5))
                lins = int(np.sum(r.linear_winding > 0.5))
                bones = segment_inside_fraction(mesh, r.positions, edges)
                lbones = segment_inside_fraction(mesh, r.linear, edges)
                fig.lines.append(
                    f"| {name} | {what} | {r.gamma:.4g}"
                    f"{' (default, (4h)²)' if gamma is None else ' ((2h)²)'}"
                    f" | {ins}/{nn} / {lins}/{nn} | {bones:.2f} / {lbones:.2f} | "
                    f"{r.iterations} | {r.converged} | {dt:.2f} s |")
    return fig


def main() -> None:
    figs = [kernels(), brdf(), skeleton()]
    text = ["# §3.7 applications: BRDF interpolation, skeleton layout", "",
            "Command: `.venv/bin/python bench/applications.py` (1 BLAS thread). Machine: "
            f"{platform.machine()}, 2 cores shared with other jobs, Python "
            f"{platform.python_version()}, numpy {np.__version__}.", ""]
    for fig in figs:
        text += [f"## {fig.title}", "",
                 f"1-minute load average before / after: {fig.before:.1f} / {fig.after:.1f}"
                 + ("  (high: timings are pessimistic)" if max(fig.before, fig.after) > 1.5
                    else ""), ""]
        text += fig.lines + [""]
    (OUT / "applications.md").write_text("\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
