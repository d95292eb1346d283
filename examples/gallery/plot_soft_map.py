"""
Two soft maps from flipped landmarks: the symmetry ambiguity (Fig. 3.14)
========================================================================

Thesis, Fig. 3.14 (paraphrased; the thesis text is not reproduced here): *soft maps
between two animals computed by Wasserstein propagation from a few landmarks; flipping the
landmarks left to right gives the mirrored map, equally good by every intrinsic measure.*

A soft map sends every point of a source surface to a *distribution* on the target
(§3.7, eq. 3.18): source samples form a graph, a few landmark pairs are fixed, and
Wasserstein propagation with a descriptor compatibility cost fills in the rest.
:func:`solvers.softmaps.soft_map` solves it over a coarse version of the target and
prolongs each row to every target vertex; a pointwise correspondence is then extracted and
refined by ZoomOut.

The TOSCA lion and cat are left-right symmetric and their descriptors (wave kernel
signatures) are intrinsic, so nothing but the landmarks tells the left paws from the
right ones.  Two maps are computed here with the same five lion landmarks (head, tail tip,
both hind paws, one front paw): sent to their true cat partners, and sent to the *mirror
images* of those partners.

**What to look for:** the two maps are mirror images: the lion's near legs take the near
legs' colours in the first map and the far legs' colours in the second.  Against the
ground truth the second map misses by the width of the body on the legs and flanks, and
hardly at all along the plane of symmetry (spine, head, tail); against the mirrored ground
truth the two maps swap scores.
"""

import matplotlib.pyplot as plt
import numpy as np
from _cache import cached
from _plotting import MESHES, View, mark_vertices, mesh_axes, shared_mesh
from scipy.spatial import cKDTree

from solvers.softmaps import soft_map
from solvers.softmaps.transfer import coordinate_colors

lion = shared_mesh("pairs/lion-00.off", weld=False)
cat = shared_mesh("pairs/cat-00.off", weld=False)
pairs_file = MESHES / "pairs" / "cat-lion-landmarks.txt"
landmarks = np.loadtxt(pairs_file, dtype=int)[:5, ::-1]  # (lion vertex, cat vertex)
truth = np.loadtxt(MESHES / "pairs" / "lion-to-cat.txt", dtype=int)
mirror = cKDTree(cat.vertices).query(cat.vertices * [-1, 1, 1])[1]  # x is left-right
flipped = np.c_[landmarks[:, 0], mirror[landmarks[:, 1]]]


def compute():
    out = {}
    for name, pairs in (("true", landmarks), ("flipped", flipped)):
        result = soft_map(lion, cat, pairs)
        out[f"{name}_map"] = result.correspondence
        out[f"{name}_converged"] = result.converged
    return out


r = cached(compute, inputs=[MESHES / "pairs" / "lion-00.off", MESHES / "pairs" / "cat-00.off",
                   pairs_file, landmarks])
scale = np.sqrt(cat.areas.sum())  # 1: the meshes are scaled to unit area
misses = {}
for name in ("true", "flipped"):
    m = r[f"{name}_map"]
    misses[name] = np.linalg.norm(cat.vertices[m] - cat.vertices[truth], axis=1) / scale
    mirrored = np.linalg.norm(cat.vertices[m] - cat.vertices[mirror[truth]], axis=1) / scale
    print(f"{name:>7} landmarks: mean miss {misses[name].mean():.3f} against the ground truth, "
          f"{mirrored.mean():.3f} against its mirror image "
          f"(converged {bool(r[name + '_converged'])})")

# %%
# One row per map.  Left: the lion coloured by the cat's coordinate colours pulled back
# through the correspondence, with the five landmarks (white).  Middle: the cat, with the
# five landmark targets.  Right: how far each lion vertex lands from its ground-truth
# partner (Euclidean, unit-area units, colour scale from 0).
colors = coordinate_colors(cat)
cat_view = View(cat.vertices, azim=-25, elev=15)
lion_view = View(lion.vertices, azim=-25, elev=15)
fig, axes = plt.subplots(2, 3, figsize=(13, 7.5))
for row, (name, pairs, title) in enumerate((("true", landmarks, "true landmarks"),
                                            ("flipped", flipped, "flipped landmarks"))):
    mesh_axes(axes[row, 0], lion, colors=colors[r[f"{name}_map"]], view=lion_view,
              title=f"{title}: lion, colours pulled back")
    mark_vertices(axes[row, 0], lion, pairs[:, 0], lion_view, color="white")
    mesh_axes(axes[row, 1], cat, colors=colors, view=cat_view, title="cat and landmark targets")
    mark_vertices(axes[row, 1], cat, pairs[:, 1], cat_view, color="white")
    _, mapper = mesh_axes(axes[row, 2], lion, misses[name], view=lion_view, cmap="magma_r",
                          vmin=0, vmax=float(max(v.max() for v in misses.values())),
                          title=f"miss against the ground truth (mean {misses[name].mean():.3f})")
    fig.colorbar(mapper, ax=axes[row, 2], shrink=0.7, label="distance on the cat")
fig.tight_layout()
plt.show()

# %%
# Where this differs from the thesis
# ----------------------------------
# The shapes are the public TOSCA lion and cat (as distributed with the pyFM examples, MIT;
# TOSCA for research use), not the thesis' pair, and the five landmarks are the first five
# of the pair's published landmark list; the mirrored targets are found by reflecting the
# cat across its plane of symmetry (x = 0) and taking the nearest vertex.  The drawn
# correspondence is the extracted and ZoomOut-refined point map, not the soft map itself:
# the soft map's rows are broad here (one front paw's row puts only a few per cent of its
# mass on either front paw of the cat), so the flip shows in the extracted maps rather than
# in single rows.  The miss is measured in space, not along the surface (a lower bound of
# the geodesic error).  Landmarks hidden behind the body are drawn through it.
#
# The same soft map from the service
# ----------------------------------
# ``POST /v1/soft-maps`` runs this call in a worker (defaults as here). Upload both meshes
# with ``POST /v1/domains/upload`` (they keep their vertex order), then send, with their ids
# and the landmark pairs::
#
#     {"source_id": "<lion id>", "target_id": "<cat id>",
#      "landmarks": [{"source": 123, "target": 456}, ...]}
#
# The job's result holds the energies and the correspondence; the distribution of one lion
# vertex, as drawn on the right, is ``GET /v1/jobs/{id}/arrays/soft_map/rows/{labels[x]}``.
# :doc:`/guide/softmaps` explains the parameters.
print({"source_id": "<lion id>", "target_id": "<cat id>",
       "landmarks": [{"source": int(s), "target": int(t)} for s, t in flipped]})
