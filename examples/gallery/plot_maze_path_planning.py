"""
Evacuating a maze by W1 (Fig. 2.12)
===================================

*Thesis caption, paraphrased (the thesis text is not at hand):* path planning by W1 —
occupants leave a maze through its exits; the optimal flow and the two parts of its Hodge
decomposition.

Occupants with density :math:`\\rho_0` leave through a set of exits :math:`S` by the
cheapest flow (thesis eq. 2.6):
:math:`\\inf_{\\rho_1} W_1(\\rho_0, \\rho_1) + \\varepsilon\\int\\rho_1^2` over
:math:`\\rho_1 \\ge 0` of unit mass on :math:`S`.  With :math:`\\varepsilon = 0` every
occupant walks to its nearest exit *through the maze*; :math:`\\varepsilon > 0` charges for
crowding at an exit.  :func:`solvers.emd.w1_path_planning` solves it on the maze of
:func:`solvers.domains.maze_mesh` (a certified interior point over all face flows) and
splits the flow as :math:`J = \\nabla f + R\\nabla g` (:func:`solvers.emd.hodge_decomposition`;
the maze is a disk, so there is no harmonic part).

**What to look for.** The two occupants A and B each leave by the exit nearest *through the
corridors* (top right: exact walking distances): B walks to F although E is nearer as the
crow flies.  The flow stays in the corridors and hugs the inner corners, as shortest paths
do.  Its gradient part's potential :math:`f` changes only along the routes and is flat in
the dead ends; the stream function :math:`g` has a closed ring of contour lines around each
route, the rotational part that turns the flow round the maze's corners.  The printout also
solves with congestion (:math:`\\varepsilon = 10^{-2}`): the arrivals spread (smaller
:math:`\\int\\rho_1^2`) and the mean walk grows.
"""

import matplotlib.pyplot as plt
import numpy as np
from matplotlib import colors
from matplotlib.tri import Triangulation

from solvers.domains import maze_mesh
from solvers.emd import w1_path_planning
from solvers.geodesics import geodesic_distances

maze = maze_mesh(subdivisions=3)
mesh, regions = maze.mesh, maze.regions
xy = mesh.vertices[:, :2]
tri = Triangulation(xy[:, 0], xy[:, 1], mesh.faces)

occupants = np.zeros(mesh.n)  # half of the people in A's cell, half in B's
for name in "AB":
    occupants[regions[name]] += 0.5 / len(regions[name])
exits = np.union1d(regions["E"], regions["F"])
plan = w1_path_planning(mesh, occupants, exits)
crowded = w1_path_planning(mesh, occupants, exits, epsilon=1e-2)
for label, r in (("epsilon = 0", plan), ("epsilon = 1e-2", crowded)):
    share = {e: r.target_masses[regions[e]].sum() for e in "EF"}
    crowding = np.sum(r.target_masses[exits] ** 2 / mesh.areas[exits])  # ∫ rho1²
    print(f"{label}: W1 = {r.value:.4f}, arrivals E {share['E']:.3f} / F {share['F']:.3f}, "
          f"∫ρ1² = {crowding:.1f}, converged {r.converged}, "
          f"Hodge residual {r.hodge.residual:.1e}")

centroid = xy[mesh.faces].mean(axis=1)
h = maze.cell_size
speed = np.linalg.norm(plan.flow, axis=1)


def frame(ax, title):
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title(title, fontsize=10)
    for name, colour in (("A", "tab:red"), ("B", "tab:red"), ("E", "tab:green"),
                         ("F", "tab:green")):
        c = xy[regions[name]].mean(axis=0)
        ax.text(c[0] + 0.3 * h, c[1] + 0.3 * h, name, color=colour, ha="center", va="center",
                fontsize=12, fontweight="bold")


fig, axes = plt.subplots(2, 2, figsize=(10, 9.5))
ax = axes[0, 0]
im = ax.tripcolor(tri, facecolors=speed, cmap="magma_r",
                  norm=colors.PowerNorm(0.4, vmin=0, vmax=speed.max()))
cells = np.floor(centroid / h).astype(int)  # one arrow per maze cell that carries flow
arrows = []
for cell in np.unique(cells[speed > 0.02 * speed.max()], axis=0):
    inside = np.flatnonzero((cells == cell).all(axis=1))
    total = plan.flow[inside, :2].sum(axis=0)
    if np.linalg.norm(total) > 0:
        arrows.append(((cell + 0.5) * h, total / np.linalg.norm(total)))
at, way = (np.array(a) for a in zip(*arrows, strict=True))
ax.quiver(at[:, 0], at[:, 1], way[:, 0], way[:, 1], color="tab:blue", scale=22,
          width=0.006, headwidth=4)
fig.colorbar(im, ax=ax, shrink=0.8, label="|J| (flux density, power scale)")
frame(ax, "optimal flow J from the occupants to the exits")

walk = geodesic_distances(mesh, exits).min(axis=0)  # exact polyhedral geodesics
ax = axes[0, 1]
im = ax.tripcolor(tri, walk, shading="gouraud", cmap="viridis", vmin=0)
ax.tricontour(tri, walk, levels=16, colors="white", linewidths=0.6)
fig.colorbar(im, ax=ax, shrink=0.8, label="distance (unit-area units)")
frame(ax, "walking distance to the nearest exit (exact)")

f, g = plan.hodge.f, plan.hodge.g_vertices
ax = axes[1, 0]
im = ax.tripcolor(tri, f - f.min(), shading="gouraud", cmap="viridis", vmin=0)
ax.tricontour(tri, f - f.min(), levels=16, colors="white", linewidths=0.6)
fig.colorbar(im, ax=ax, shrink=0.8, label="f − min f")
frame(ax, "gradient part ∇f: potential f")

ax = axes[1, 1]
lim = np.abs(g).max()
im = ax.tripcolor(tri, g, shading="gouraud", cmap="coolwarm", vmin=-lim, vmax=lim)
ax.tricontour(tri, g, levels=12, colors="k", linewidths=0.5)
fig.colorbar(im, ax=ax, shrink=0.8, label="g")
frame(ax, "rotated part R∇g: stream function g")
fig.tight_layout()

# %%
# **Where this differs from the thesis.** The maze is this library's own layout
# (``FIG_2_12_LAYOUT``: a perfect maze of 13 × 13 cells with two occupants and two exits),
# drawn to show the same phenomenon, not the thesis' maze; each cell is split into
# 3 × 3 squares (18 triangles).  The occupants are uniform on their cells rather than the
# thesis' blobs.  The solver is an interior-point method over all piecewise-constant flows
# (certified gap), not the thesis' ADMM over a truncated curl basis, so nothing smooths the
# flow: it is as concentrated as the exact W1 flow is.  The walking-distance panel and the
# congestion run are additions.

# sphinx_gallery_thumbnail_number = 1
