"""Shape of default barycenters on meshes (issue 40): the geodesic kernel against the thesis'
implicit-Euler heat kernel, on a flat square (against the exact-Gaussian grid) and on curved
shared meshes (against the exact geodesic midpoint).

    python bench/sharp_transport.py [flat] [curved] [--meshes spot cow ...]

Standard deviations along / across the line between the inputs (flat), or in the tangent
plane at the result's centre (curved); the centre's distance from the exact geodesic midpoint
(potpourri3d's edge-flip geodesic path between the inputs' centres) in edge lengths; seconds
cold (first call on the domain: all-pairs heat-method geodesics and the kernel) and warm.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from solvers import load_mesh  # noqa: E402
from solvers.convolutional.barycenter import barycenter  # noqa: E402
from solvers.domains import Grid, TriangleMesh  # noqa: E402
from solvers.geodesics import geodesic_distances  # noqa: E402

MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"
RESULTS = Path(__file__).resolve().parent / "results"


def flat_square(n: int = 60) -> TriangleMesh:
    """The unit square as an ``n x n`` vertex triangle mesh (two triangles per cell)."""
    xs = np.linspace(0.0, 1.0, n)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    idx = np.arange(n * n).reshape(n, n)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return TriangleMesh(vertices, np.r_[np.c_[a, b, c], np.c_[a, c, d]])


def tent(points, areas, centre, radius):
    return areas * np.clip(1.0 - np.linalg.norm(points - centre, axis=1) / radius, 0.0, None)


def planar_spread(points, masses):
    """Centre of mass and standard deviations along each coordinate axis."""
    w = masses / masses.sum()
    centre = w @ points
    return centre, np.sqrt(w @ (points - centre) ** 2)


def flat(method: str) -> dict:
    """Two radius-0.1 tents 0.4 apart on the flat square: the barycenter's spread along /
    across and its centre's offset from the midpoint (edge lengths)."""
    mesh = flat_square()
    p = mesh.vertices[:, :2]
    m = np.c_[tent(p, mesh.areas, (0.3, 0.5), 0.1), tent(p, mesh.areas, (0.7, 0.5), 0.1)]
    start = time.perf_counter()
    res = barycenter(mesh, m, [0.5, 0.5], method=method)
    cold = time.perf_counter() - start
    start = time.perf_counter()
    barycenter(mesh, m, [0.5, 0.5], method=method)
    warm = time.perf_counter() - start
    centre, sd = planar_spread(p, res.masses)
    offset = float(np.linalg.norm(centre - (0.5, 0.5)) / mesh.mean_edge_length)
    return {"method": res.method, "along": float(sd[0]), "across": float(sd[1]),
            "input_sd": float(planar_spread(p, m[:, 0])[1][0]), "offset_edges": offset,
            "iterations": res.iterations, "cold_s": cold, "warm_s": warm}


def flat_grid() -> dict:
    grid = Grid((64, 64))
    p = grid.points
    m = np.c_[tent(p, grid.areas, (0.3, 0.5), 0.1), tent(p, grid.areas, (0.7, 0.5), 0.1)]
    res = barycenter(grid, m, [0.5, 0.5])
    _, sd = planar_spread(p, res.masses)
    return {"method": "grid", "along": float(sd[0]), "across": float(sd[1])}


def tangent_spread(mesh, masses):
    """Centre (the vertex nearest the mass's 3-D centroid) and the two standard deviations
    of the mass projected on the tangent plane there (principal axes)."""
    w = masses / masses.sum()
    centroid = w @ mesh.vertices
    centre = int(np.argmin(np.linalg.norm(mesh.vertices - centroid, axis=1)))
    normal = np.zeros(3)
    for f in np.flatnonzero((mesh.faces == centre).any(axis=1)):
        normal += mesh.face_normals[f] * mesh.face_areas[f]
    normal /= np.linalg.norm(normal)
    rel = mesh.vertices - mesh.vertices[centre]
    tangent = rel - np.outer(rel @ normal, normal)
    mean = w @ tangent
    cov = (tangent - mean).T @ (w[:, None] * (tangent - mean))
    sds = np.sqrt(np.clip(np.sort(np.linalg.eigvalsh(cov))[::-1][:2], 0.0, None))
    return centre, sds


def frechet_mean(mesh, sources, weights) -> int:
    """The vertex minimizing the weighted sum of squared exact (MMP) geodesic distances to
    ``sources``: the weighted geodesic Frechet mean, to within an edge length."""
    d = geodesic_distances(mesh, np.asarray(sources))
    return int(np.argmin(np.asarray(weights) @ d**2))


def curved(name: str, radius: float, pairs: int, method: str, seed: int = 0,
           debiased: bool = False) -> list[dict]:
    mesh = load_mesh(MESHES / f"{name}.obj")
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(pairs):
        i = int(rng.integers(mesh.n))
        d = np.linalg.norm(mesh.vertices - mesh.vertices[i], axis=1)
        candidates = np.flatnonzero((d > 0.3) & (d < 0.5))
        j = int(rng.choice(candidates))
        m = np.c_[tent(mesh.vertices, mesh.areas, mesh.vertices[i], radius),
                  tent(mesh.vertices, mesh.areas, mesh.vertices[j], radius)]
        start = time.perf_counter()
        res = barycenter(mesh, m, [0.5, 0.5], method=method, debiased=debiased)
        seconds = time.perf_counter() - start
        centre, sds = tangent_spread(mesh, res.masses)
        inputs = np.mean([tangent_spread(mesh, m[:, k])[1] for k in range(2)], axis=0)
        mid = mesh.vertices[frechet_mean(mesh, [i, j], [0.5, 0.5])]
        rows.append({"mesh": name, "method": res.method, "debiased": debiased,
                     "sources": [i, j], "radius": radius,
                     "sd": sds.tolist(), "input_sd": inputs.tolist(),
                     "spread_ratio": float(sds[0] / inputs[0]),
                     "offset_edges": float(np.linalg.norm(mesh.vertices[centre] - mid)
                                           / mesh.mean_edge_length),
                     "seconds": seconds})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("parts", nargs="*", default=["flat", "curved"])
    parser.add_argument("--meshes", nargs="*", default=["spot", "cow", "homer"])
    parser.add_argument("--pairs", type=int, default=3)
    args = parser.parse_args()
    out = {"processor": platform.processor() or platform.machine(),
           "load_start": os.getloadavg()[0]}
    if "flat" in args.parts:
        out["flat"] = [flat_grid(), flat("geodesic"), flat("convolutional")]
        for row in out["flat"]:
            print(json.dumps(row))
    if "curved" in args.parts:
        out["curved"] = []
        for name in args.meshes:
            for method in ("geodesic", "convolutional"):
                for row in curved(name, 0.1, args.pairs, method):
                    out["curved"].append(row)
                    print(json.dumps(row))
    out["load_end"] = os.getloadavg()[0]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "sharp_transport.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
