"""
Color transfer between two photographs (Fig. 3.12)
==================================================

Thesis §3.7 recolors an image by transporting its chrominance histogram (CIE a*, b*)
towards a Wasserstein barycenter of several images' histograms; with weights
:math:`\\alpha = (1-s, s)` the palette moves from one photograph's to the other's
(Fig. 3.12).  The thesis' map sends every pixel of one ab bin to the *barycentric
projection* of the plan (``mode="barycentric"``): when the plan splits a colour between
two targets, the pixels get their average, a colour neither image has.

The default ``mode="split"`` keeps the plan itself: the exact plan between the binned
histograms (network simplex), each bin's pixels split among its targets in the plan's
proportions in a spatially coherent order, then an edge-aware (guided) filter of the
colour shift.  For :math:`\\alpha = (1-s, s)` each pixel moves the fraction :math:`s` of
its shift (McCann's interpolation).  Bottom rows: ab histograms (a* to the right, b* up)
of each result, next to the target's.
"""

import matplotlib.pyplot as plt
import numpy as np
from skimage import data

from solvers.color import ab_histogram, color_transfer, histogram_picture, rgb_to_lab

source = np.ascontiguousarray(data.coffee()[::2, ::2])
target = np.ascontiguousarray(data.chelsea()[::2, ::2])
steps = [0.0, 0.5, 1.0]
alphas = [[1 - s, s] for s in steps]
results = {mode: color_transfer([source, target], alphas, mode=mode, recolor=[0])
           for mode in ("barycentric", "split")}
for mode, r in results.items():
    print(f"{mode}: residual {r.residual:.1e}, converged {r.converged}, "
          f"timings {', '.join(f'{k} {v:.2f} s' for k, v in r.timings.items())}")


def picture(img, bins=64):
    return histogram_picture(ab_histogram(rgb_to_lab(img)[..., 1:], bins))


# %%
# Rows: each mode's images for s = 0, 0.5, 1 and the target, then their ab histograms.
fig, axes = plt.subplots(4, len(steps) + 1, figsize=(11, 9))
for row, (mode, r) in enumerate(results.items()):
    for j, s in enumerate(steps):
        out = r.images[j][0]
        axes[2 * row, j].imshow(out)
        axes[2 * row, j].set_title(f"{mode}, s = {s:g}", fontsize=9)
        axes[2 * row + 1, j].imshow(picture(out))
    axes[2 * row, -1].imshow(target)
    axes[2 * row, -1].set_title("target", fontsize=9)
    axes[2 * row + 1, -1].imshow(picture(target))
for ax in axes.ravel():
    ax.set_xticks([])
    ax.set_yticks([])
plt.tight_layout()
plt.show()
