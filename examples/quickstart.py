"""Library quick start: run from the repository root with `.venv/bin/python examples/quickstart.py`.

Uses the shared test meshes beside the checkout (../shared/meshes).
"""

from pathlib import Path

import numpy as np

from solvers import Grid, load_mesh
from solvers.convolutional import barycenter, wasserstein_distance
from solvers.emd import earth_movers_distance, pointwise_distances

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"

# A mesh: seams welded, rescaled to unit area, operators built on demand and cached.
mesh = load_mesh(MESHES / "spot.obj")
print(mesh.summary()["vertices"], "vertices, genus", mesh.genus)


def bump(center: int, radius: float = 0.08) -> np.ndarray:
    """Masses of a bump around a vertex (sums to 1)."""
    d = np.linalg.norm(mesh.vertices - mesh.vertices[center], axis=1)
    masses = mesh.areas * np.exp(-((d / radius) ** 2))
    return masses / masses.sum()


mu0, mu1 = bump(0), bump(1500)

# Convolutional W2^2 (thesis Alg. 1): debiased, 64 substeps, gamma ~ 2.5 h d (see README).
w2 = wasserstein_distance(mesh, mu0, mu1, gamma=0.05, substeps=64, debiased=True)
print(f"W2^2 = {w2.value:.4f}  iterations={w2.iterations} residual={w2.residual:.1e}")

# Earth mover's distance W1 (thesis ch. 2, ADMM) with its flow field per face.
w1 = earth_movers_distance(mesh, mu0, mu1)
print(f"W1 = {w1.value:.4f}  flow {w1.flow.shape}  converged={w1.converged}")

# Spectral pointwise distance d_W^0 from one vertex to a few others.
d0 = pointwise_distances(mesh, 0, k=0, targets=[1500, 2000])
print("d_W^0:", np.round(d0.distances, 4))

# Barycenter of two bumps on a 2-D grid (thesis Alg. 2).
grid = Grid((64, 64))
x, y = grid.points.T
blobs = np.stack([np.exp(-((x - cx) ** 2 + (y - 0.5) ** 2) / 0.005) for cx in (0.25, 0.75)], 1)
bary = barycenter(grid, blobs / blobs.sum(0), weights=[0.5, 0.5], gamma=0.002)
peak = grid.points[np.argmax(bary.masses)]
print(f"grid barycenter peak at {np.round(peak, 2)}, converged={bary.converged}")
