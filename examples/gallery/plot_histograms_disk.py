"""
Histograms propagated over a disk (Fig. 5.3)
============================================

Every node on the rim of a disk carries a two-peaked histogram whose peaks drift as we go
around; the interior is unknown. Chapter 5 fills it in by minimizing the Wasserstein
Dirichlet energy :math:`\\sum_{(u,v)} \\omega_{uv} W_2^2(\\rho_u, \\rho_v)`. On the line this
is the harmonic extension of the inverse CDFs, one sparse factorization and one block solve
for all quantile levels (:func:`solvers.histograms.propagate_histograms`).

The naive alternative, harmonic extension of the densities themselves (``method="pdf"``),
averages histograms bin by bin: peaks at different places blur into a flat smear. The
Wasserstein method moves the peaks instead, so interior histograms keep the labels' shape.
"""

import matplotlib.pyplot as plt
import numpy as np
from scipy.spatial import Delaunay

from solvers import TriangleMesh
from solvers.histograms import make_bins, propagate_histograms, summarize

rings = 14  # a triangulated disk: rings of 6r points around the center
points = [[0.0, 0.0]]
for r in range(1, rings + 1):
    angles = 2 * np.pi * np.arange(6 * r) / (6 * r)
    points += list(np.c_[r / rings * np.cos(angles), r / rings * np.sin(angles)])
points = np.asarray(points)
disk = TriangleMesh(np.c_[points, np.zeros(len(points))], Delaunay(points).simplices)
rim = np.flatnonzero(np.isclose(np.linalg.norm(points, axis=1), 1.0))

bins = make_bins(lo=0.0, hi=1.0, count=80)


def gauss(mean, width=0.035):
    h = np.exp(-0.5 * ((bins.centers - mean) / width) ** 2)
    return h / h.sum()


theta = np.arctan2(points[rim, 1], points[rim, 0])
labels = np.stack([0.5 * gauss(0.3 + 0.12 * np.cos(t)) + 0.5 * gauss(0.7 + 0.12 * np.sin(t))
                   for t in theta])
wasserstein = propagate_histograms(disk, rim, labels, bins=bins)
pdf = propagate_histograms(disk, rim, labels, bins=bins, method="pdf")

# %%
# Left: the entropy of each node's histogram (low = peaked). Right: the histograms at three
# nodes on a ray from the rim to the center, by both methods.
fig, axes = plt.subplots(1, 3, figsize=(13, 4))
entropies = [summarize(r.histograms, bins)["entropy"] for r in (wasserstein, pdf)]
low, high = min(e.min() for e in entropies), max(e.max() for e in entropies)
for ax, entropy, title in ((axes[0], entropies[0], "Wasserstein"),
                           (axes[1], entropies[1], "PDF")):
    shown = ax.tripcolor(points[:, 0], points[:, 1], disk.faces, entropy, shading="gouraud",
                         cmap="magma", vmin=low, vmax=high)
    ax.set_title(f"{title} method: entropy")
    ax.set_aspect("equal")
    ax.axis("off")
fig.colorbar(shown, ax=axes[:2], shrink=0.8)
ray = [int(np.argmin(np.linalg.norm(points - [x, 0.0], axis=1))) for x in (1.0, 0.5, 0.0)]
for node, shade in zip(ray, ("0.7", "0.4", "0.0"), strict=True):
    radius = np.linalg.norm(points[node])
    axes[2].plot(bins.centers, wasserstein.histograms[node], color=shade,
                 label=f"Wasserstein, r = {radius:.1f}")
    axes[2].plot(bins.centers, pdf.histograms[node], color=shade, ls=":",
                 label=f"PDF, r = {radius:.1f}")
axes[2].legend(fontsize=7)
axes[2].set_xlabel("value")
plt.show()
