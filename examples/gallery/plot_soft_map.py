"""
Soft maps between a lion and a cat (Fig. 3.14)
==============================================

A soft map sends every point of a source surface to a *distribution* on the target
(§3.7, eq. 3.18): source samples form a graph, five landmark pairs are fixed, and
Wasserstein propagation with a descriptor compatibility cost fills in the rest.
:func:`solvers.softmaps.soft_map` solves it over a coarse version of the target (about as
many points as source samples) and prolongs each row to every target vertex; a pointwise
correspondence is then extracted and refined by ZoomOut.

The TOSCA lion and cat come with a ground-truth correspondence (``lion-to-cat.txt``), so the
map can be scored.
"""

import matplotlib.pyplot as plt
import numpy as np
from _plotting import MESHES, View, mark_vertices, mesh_axes, shared_mesh

from solvers.softmaps import soft_map
from solvers.softmaps.transfer import coordinate_colors

lion = shared_mesh("pairs/lion-00.off", weld=False)
cat = shared_mesh("pairs/cat-00.off", weld=False)
landmarks = np.loadtxt(MESHES / "pairs" / "cat-lion-landmarks.txt", dtype=int)[:5, ::-1]
truth = np.loadtxt(MESHES / "pairs" / "lion-to-cat.txt", dtype=int)

result = soft_map(lion, cat, landmarks)  # (lion vertex, cat vertex) landmark pairs
miss = np.linalg.norm(cat.vertices[result.correspondence] - cat.vertices[truth], axis=1)
print(f"{len(result.samples)} lion samples over {result.target_points} coarse cat points; "
      f"{result.iterations} sweeps, converged {result.converged}")
print(f"mean Euclidean miss of the correspondence: {miss.mean():.4f} (unit-area units; "
      f"a lower bound of the geodesic error)")

# %%
# Left: the cat colored by its coordinates. Middle: the lion colored by the cat's colors
# pulled back through the correspondence — matching parts get matching colors. Right: the
# distribution over the cat of one lion vertex (the red dot), which is not a landmark: it
# spreads over the matching region of the cat, with some mass on the symmetric side.
paw = int(np.argmin(lion.vertices[:, 1] - 0.3 * lion.vertices[:, 2]))  # a front paw
fig, axes = plt.subplots(1, 3, figsize=(13, 4.5))
colors = coordinate_colors(cat)
cat_view = View(cat.vertices, azim=-25, elev=15)
lion_view = View(lion.vertices, azim=-25, elev=15)
mesh_axes(axes[0], cat, colors=colors, view=cat_view, title="cat (target)")
mesh_axes(axes[1], lion, colors=colors[result.correspondence], view=lion_view,
          title="lion, colors pulled back")
mark_vertices(axes[1], lion, [paw], lion_view)
row = result.row(result.labels[paw])
density = row / cat.areas
mesh_axes(axes[2], cat, density, view=cat_view, cmap="magma", vmax=np.percentile(density, 99.5),
          title="distribution of the red vertex")
plt.show()

# %%
# The same soft map from the service
# ----------------------------------
# ``POST /v1/soft-maps`` runs this call in a worker (defaults as here). Upload both meshes
# with ``POST /v1/domains/upload`` (they keep their vertex order), then send, with their ids
# and the same landmark pairs::
#
#     {"source_id": "<lion id>", "target_id": "<cat id>",
#      "landmarks": [{"source": 123, "target": 456}, ...]}
#
# The job's result holds the energies and the correspondence; the distribution of one lion
# vertex, as drawn on the right, is ``GET /v1/jobs/{id}/arrays/soft_map/rows/{labels[x]}``.
# :doc:`/guide/softmaps` explains the parameters, and the browser viewer draws the same
# picture when a source vertex is hovered.
print({"source_id": "<lion id>", "target_id": "<cat id>",
       "landmarks": [{"source": int(s), "target": int(t)} for s, t in landmarks]})
