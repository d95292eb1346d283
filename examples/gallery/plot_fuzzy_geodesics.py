"""
Fuzzy geodesics (Fig. 2.13)
===========================

Put a small bump of mass at each of two points and transport one to the other: the optimal
Beckmann flow :math:`J` of :math:`W_1` (thesis eq. 2.3) runs along the shortest paths
between them, and its magnitude :math:`\\|J\\|` draws a *fuzzy geodesic* — a ridge on the
shortest path that widens where several routes are nearly as short.
:func:`solvers.emd.fuzzy.fuzzy_geodesic` returns :math:`\\|J\\|` per face and per vertex.

The red line is the exact polyhedral geodesic (potpourri3d's edge-flip solver, checked
against the exact MMP distance).
"""

import matplotlib.pyplot as plt
import numpy as np
import potpourri3d as pp3d
from _plotting import View, mark_vertices, mesh_axes, shared_mesh
from scipy.spatial import cKDTree

from solvers.emd.fuzzy import fuzzy_geodesic
from solvers.geodesics import geodesic_distances

mesh = shared_mesh("spot.obj")
solver = pp3d.EdgeFlipGeodesicSolver(mesh.vertices, mesh.faces)
pairs = [(0, 1500), (100, 2500)]
results, paths = [], []
for a, b in pairs:
    res = fuzzy_geodesic(mesh, a, b)
    da, db = geodesic_distances(mesh, [a, b])
    mid = int(np.argmin(da + db + np.abs(da - db)))  # start the straightening near the
    candidates = [solver.find_geodesic_path(a, b),  # shortest path, not only a local one
                  solver.find_geodesic_path_poly([a, mid, b])]
    lengths = [np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in candidates]
    paths.append(candidates[int(np.argmin(lengths))])
    results.append(res)
    print(f"{a} -> {b}: W1 = {res.value:.4f}, geodesic length {min(lengths):.4f} "
          f"(MMP {da[b]:.4f}), certified gap {res.residual:.1e}, {res.iterations} iterations")


def visible_polyline(path, view):
    """Screen points of ``path`` with NaN where the surface there faces away."""
    normals = np.zeros_like(mesh.vertices)
    np.add.at(normals, mesh.faces.ravel(), np.repeat(mesh.face_normals, 3, axis=0))
    _, nearest = cKDTree(mesh.vertices).query(path)
    p = view(path)[:, :2]
    p[normals[nearest] @ view.forward > 0] = np.nan
    return p


# %%
# Left: one shortest route, and the ridge of :math:`\|J\|` sits on it (red: the exact
# geodesic where it faces the camera).  Right: the flow spreads over a wide band across the
# flank.  Here W1 between the bumps is 9 % below the geodesic length between their centres:
# their masses move along other routes than the centres' shortest path, which runs on the
# far side of the body and is hidden in this view.
fig, axes = plt.subplots(1, 2, figsize=(11, 5))
for ax, res, path, (a, b) in zip(axes, results, paths, pairs, strict=True):
    view = View(mesh.vertices, azim=180 if a == 0 else 0, elev=25)
    values = np.sqrt(res.vertex_norms)  # square root: the ridge and its halo both show
    mesh_axes(ax, mesh, values, view=view, cmap="magma_r", vmax=np.percentile(values, 99.5),
              title=f"|J| between vertices {a} and {b}")
    p = visible_polyline(path, view)
    ax.plot(p[:, 0], p[:, 1], color="red", lw=1.0, zorder=5)
    mark_vertices(ax, mesh, [a, b], view, size=25)
plt.show()
