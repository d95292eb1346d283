"""
Skeleton layout (Fig. 3.13)
===========================

Given a skeleton graph and the positions of a few of its joints inside a closed surface,
where should the other joints go? A straight-line (harmonic) layout along the graph ignores
the shape and leaves bones outside it. Solomon's §3.7 lays the skeleton out by Wasserstein
propagation instead: each fixed joint becomes a distribution on the surface (its mean value
coordinates), Alg. 4 propagates distributions to the free joints along the graph, and each
free joint sits at the barycenter of its distribution.

Here the four hooves of spot are fixed and joined by four chains of five joints each.
"""

import matplotlib.pyplot as plt
import numpy as np
from _plotting import View, mesh_axes, shared_mesh

from solvers.convolutional.skeleton import skeleton_layout

mesh = shared_mesh("spot.obj")
hooves = np.array([[0.09, -0.272, 0.009], [-0.09, -0.272, 0.009],
                   [0.083, -0.271, 0.314], [-0.083, -0.271, 0.314]])
edges, n_nodes = [], 4  # four chains of five free joints between pairs of hooves
for a, b in ((0, 1), (2, 3), (0, 2), (1, 3)):
    previous = a
    for _ in range(5):
        edges.append((previous, n_nodes))
        previous, n_nodes = n_nodes, n_nodes + 1
    edges.append((previous, b))

result = skeleton_layout(mesh, n_nodes, edges, {i: hooves[i] for i in range(4)})
inside = result.winding > 0.5
linear_inside = result.linear_winding > 0.5
print(f"joints inside: {inside.sum()} / {n_nodes} (straight-line layout: "
      f"{linear_inside.sum()} / {n_nodes}); propagation converged {result.converged}")

# %%
# Joints inside the surface are green, outside red; the surface is drawn translucent.
fig, axes = plt.subplots(1, 2, figsize=(11, 5))
view = View(mesh.vertices, azim=-120, elev=10)
for ax, positions, ok, title in ((axes[0], result.positions, inside, "Wasserstein propagation"),
                                 (axes[1], result.linear, linear_inside, "straight-line layout")):
    mesh_axes(ax, mesh, view=view, alpha=0.25, title=title)
    p = view(positions)
    for i, j in edges:
        ax.plot(p[[i, j], 0], p[[i, j], 1], color="0.2", lw=1.5, zorder=5)
    ax.scatter(p[:, 0], p[:, 1], c=np.where(ok, "tab:green", "tab:red"), s=28, zorder=6,
               edgecolors="white")
plt.show()
