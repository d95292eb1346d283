"""
Distance to features (Fig. 2.14)
================================

How far is every point of a surface from a feature — a set of points, or a curve? Solomon's
§2.7 answers with transport: the Kantorovich potential of :math:`W_1` between the uniform
distribution and a distribution on the feature (each feature vertex weighted by the area of
its Voronoi cell) is, up to a constant, the distance to the feature, and it is robust to
noise in a way a shortest-path distance is not. :func:`solvers.emd.distance_to_features`
returns it per vertex.

Here the feature is a curve: the loop where spot's plane of symmetry cuts its surface, over
the spine and under the belly, plus a single point on one ear.
"""

import matplotlib.pyplot as plt
import numpy as np
from _plotting import View, mark_vertices, mesh_axes, shared_mesh

from solvers.emd import distance_to_features
from solvers.geodesics import geodesic_distances

mesh = shared_mesh("spot.obj")
x = mesh.vertices
curve = np.flatnonzero(np.abs(x[:, 0]) < 0.5 * mesh.mean_edge_length)  # the symmetry plane
ear = int(np.argmax(x[:, 0] + x[:, 1]))
result = distance_to_features(mesh, np.r_[curve, ear])
print(f"{len(curve)} curve vertices + 1 point; largest distance "
      f"{np.nanmax(result.distances):.3f} (unit-area units); W1 converged "
      f"{result.emd.converged}")

# The exact polyhedral geodesic distance to the same feature set, for comparison.
exact = geodesic_distances(mesh, np.r_[curve, ear]).min(axis=0)
error = np.abs(result.distances - exact)
print(f"against exact geodesics: mean |difference| {error.mean():.4f}, "
      f"{error.mean() / exact.mean():.1%} of the mean distance")

# %%
# Banded colors show the level sets of the distance: parallel to the curve near it, then
# circles around the ear's point where that point is the nearest feature.
fig, axes = plt.subplots(1, 2, figsize=(11, 5))
for ax, azim in zip(axes, (-60, 120), strict=True):
    view = View(mesh.vertices, azim=azim, elev=20)
    mesh_axes(ax, mesh, result.distances, view=view, cmap=plt.get_cmap("viridis", 12))
    mark_vertices(ax, mesh, [ear], view, size=20)
plt.show()
