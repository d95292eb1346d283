"""
BRDF interpolation (Fig. 3.11)
==============================

A BRDF says how much light arriving from one direction leaves in each other direction.
For a fixed incoming direction, the outgoing slice :math:`f(\\omega_o)\\cos\\theta_o` of a
material is a distribution on the hemisphere. Blending two materials by a weighted average
of their BRDFs cross-fades two highlights; blending them by Wasserstein barycenters on the
hemisphere moves *one* highlight from one shape to the other (§3.7).

:func:`solvers.convolutional.brdf.interpolate_brdfs` does it for closed-form materials
(Blinn–Phong, Ashikhmin–Shirley) on a :class:`~solvers.convolutional.hemisphere.HemisphereGrid`
with the exact great-circle Gaussian kernel, every incoming direction and weight in one
batch of Alg. 2; :func:`~solvers.convolutional.brdf.render_spheres` shades spheres with the
result.
"""

import matplotlib.pyplot as plt
import numpy as np

from solvers.convolutional.brdf import bilinear_weights, interpolate_brdfs, render_spheres
from solvers.convolutional.hemisphere import HemisphereGrid

corners = [
    {"model": "blinn-phong", "exponent": 6},                   # broad, glossy
    {"model": "ashikhmin-shirley", "nu": 300, "nv": 300},      # sharp, mirror-like
    {"model": "blinn-phong", "exponent": 40, "kd": 0.3},       # diffuse + highlight
    {"model": "ashikhmin-shirley", "nu": 20, "nv": 200, "rd": 0.4},  # anisotropic
]
grid = HemisphereGrid(16, 64)
incoming = np.radians([0, 20, 40, 60, 80])
weights = bilinear_weights(3, 3)            # a 3 × 3 grid of blends of the four corners
gamma = (2 * 0.399 * np.pi / 2 / 16) ** 2   # about two grid spacings, squared
result = interpolate_brdfs(grid, corners, weights, incoming, gamma=gamma, max_iter=500)
print(f"{result.iterations} iterations, residual {result.residual:.1e}, "
      f"converged {result.converged}")

# %%
# Left: spheres lit by the interpolated materials (corners are the inputs). Right: the
# same blend weights applied linearly to the BRDFs. The transport blends keep a single
# highlight that changes shape and size; the linear ones show two overlapping highlights.
spheres = render_spheres(grid, result.masses, result.scale, incoming, 3, 3, size=96)
linear = render_spheres(grid, result.linear, result.scale, incoming, 3, 3, size=96)
fig, axes = plt.subplots(1, 2, figsize=(10, 5))
for ax, image, title in ((axes[0], spheres, "Wasserstein barycenters"),
                         (axes[1], linear, "linear blend")):
    ax.imshow(image)
    ax.set_title(title)
    ax.axis("off")
plt.show()
