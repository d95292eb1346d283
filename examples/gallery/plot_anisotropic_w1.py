"""
Anisotropic earth mover's distances (Fig. 2.15)
===============================================

*Thesis caption, paraphrased (the thesis text is not at hand):* W1 with an anisotropic,
spatially varying cost — the same transport when moving in one direction costs more, and
when moving across curved regions costs more.

Beckmann's problem prices a flow by its length, :math:`\\int \\|J\\|\\,dA`.  §2.7 replaces
the norm by :math:`\\|M_t J_t\\|` with a matrix :math:`M_t` per face (direction-dependent
cost) or a scalar weight :math:`w_t` (position-dependent cost), here
:math:`w_t = 1 + \\alpha |H_t| / \\overline{|H|}` from the mean curvature :math:`H`
(:func:`solvers.emd.anisotropy.mean_curvature_weights`).
:func:`solvers.emd.anisotropy.anisotropic_w1` solves both over all piecewise-constant flows
with a certified interior point.

The surface is fandisk, a CAD part whose flat panels meet at sharp creases.  The same two
bumps are transported three ways: isotropically; with moving along the vertical axis
four times as expensive as moving horizontally (:math:`M = \\mathrm{diag}(1, 4, 1)`,
the same matrix on every face); and with curvature weights, :math:`\\alpha = 4`.

**What to look for.** The isotropic flow runs along the shortest route, diagonally across
the top of the part.  With vertical motion expensive, the route bends: it trades vertical
for horizontal travel.  With curvature weights (left: the weights, dark on the creases) the
flow takes an L-shaped route over the faces of least weight, and part of the second bump,
which straddles a crease, is reached along the front face instead of over the crease.  The
printed values compare each cost with the flow's plain length: the anisotropic flows are
longer but cheaper under their own cost than the isotropic route would be.
"""

import matplotlib.pyplot as plt
import numpy as np
from _plotting import View, face_to_vertex, mesh_axes, shared_mesh

from solvers.emd import earth_movers_distance
from solvers.emd.anisotropy import anisotropic_w1, mean_curvature_weights

mesh = shared_mesh("fandisk.obj")
x = mesh.vertices


def bump(vertex, radius=0.06):
    """Tent bump: masses a_j max(0, 1 - |x_j - x_v| / r), normalized."""
    masses = mesh.areas * np.clip(1 - np.linalg.norm(x - x[vertex], axis=1) / radius, 0, None)
    return masses / masses.sum()


a, b = int(np.argmin(x[:, 2])), int(np.argmax(x[:, 2]))
mu0, mu1 = bump(a), bump(b)
curvature = mean_curvature_weights(mesh, 4.0)
stretch = np.tile(np.diag([1.0, 4.0, 1.0]), (mesh.n_faces, 1, 1))  # y (up) costs 4x
runs = {
    "isotropic": earth_movers_distance(mesh, mu0, mu1),
    "vertical motion costs 4×": anisotropic_w1(mesh, mu0, mu1, stretch),
    "curvature weights (α = 4)": anisotropic_w1(mesh, mu0, mu1, curvature),
}
straight = runs["isotropic"].flow  # what the isotropic route would cost under each metric
priced = {"isotropic": runs["isotropic"].value,
          "vertical motion costs 4×": mesh.face_areas @ np.linalg.norm(
              np.einsum("fij,fj->fi", stretch, straight), axis=1),
          "curvature weights (α = 4)": mesh.face_areas @ (curvature * np.linalg.norm(
              straight, axis=1))}
for name, r in runs.items():
    length = mesh.face_areas @ np.linalg.norm(r.flow, axis=1)
    print(f"{name:26s} cost {r.value:.4f} (isotropic route: {priced[name]:.4f}), "
          f"length ∫|J| {length:.4f}, certified gap {r.residual:.0e}, converged {r.converged}")

view = View(x, elev=25, azim=-35)
fig, axes = plt.subplots(1, 4, figsize=(16, 4.6))
_, mapper = mesh_axes(axes[0], mesh, curvature, view=view, cmap="Greys", vmin=0,
                      vmax=np.percentile(curvature, 99), title="curvature weight w (α = 4)")
fig.colorbar(mapper, ax=axes[0], shrink=0.6, label="w")
for ax, (name, r) in zip(axes[1:], runs.items(), strict=True):
    speed = face_to_vertex(mesh, np.linalg.norm(r.flow, axis=1))
    _, mapper = mesh_axes(ax, mesh, speed, view=view, cmap="magma_r", vmin=0,
                          vmax=np.percentile(speed, 99.5), title=f"|J|: {name}")
    fig.colorbar(mapper, ax=ax, shrink=0.6, label="|J|")
for ax in axes:
    for v, colour in ((a, "tab:blue"), (b, "tab:green")):
        p = view(x[[v]])
        ax.scatter(p[:, 0], p[:, 1], s=40, c=colour, edgecolors="white", zorder=4)
fig.tight_layout()

# %%
# **Where this differs from the thesis.** The thesis' surfaces and its choice of
# anisotropy are not reproduced exactly: fandisk (public, from the common 3-D test models)
# stands in for its models, the matrix is one constant stretch of the vertical axis, and
# the bumps sit at the part's two extreme points.  The thesis solved in its truncated curl
# basis; here the interior point runs over all flows, since the curl basis overestimates
# matrix-weighted costs by a wide margin (see ``solvers/emd/anisotropy.py``).

# sphinx_gallery_thumbnail_number = 1
