"""Library quick start: `.venv/bin/python examples/quickstart.py` from the repository root
(the shared test meshes lie beside the checkout, in ../shared/meshes)."""

from pathlib import Path

import numpy as np

from solvers import Grid, load_mesh
from solvers.convolutional import barycenter, wasserstein_distance
from solvers.emd import earth_movers_distance, pointwise_distances

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
mesh = load_mesh(MESHES / "spot.obj")  # seams welded, unit area, operators cached on it
print(mesh.summary()["vertices"], "vertices, genus", mesh.genus)


def bump(center: int, radius: float = 0.08) -> np.ndarray:
    """Masses of a Gaussian bump around a vertex (non-negative, summing to 1)."""
    d = np.linalg.norm(mesh.vertices - mesh.vertices[center], axis=1)
    masses = mesh.areas * np.exp(-((d / radius) ** 2))
    return masses / masses.sum()


mu0, mu1 = bump(0), bump(1500)

# W2^2 with the defaults: the method (exact LP or convolutional Alg. 1) and its
# regularization are chosen from the inputs and reported (see "Choosing gamma and t").
w2 = wasserstein_distance(mesh, mu0, mu1)
print(f"W2^2 = {w2.value:.4f}  method={w2.method}  residual={w2.residual:.1e}")

# Earth mover's distance W1 (thesis ch. 2): the certified interior point over all per-face
# flows (method="auto" -> "ipm"), with the flow field J per face.
w1 = earth_movers_distance(mesh, mu0, mu1)
print(f"W1 = {w1.value:.4f}  flow {w1.flow.shape}  method={w1.method}  "
      f"converged={w1.converged}")

# Spectral pointwise distance d_W^0 from vertex 0 to two others.
d0 = pointwise_distances(mesh, 0, k=0, targets=[1500, 2000])
print("d_W^0:", np.round(d0.distances, 4))

# Barycenter of two blobs on a 64 x 64 grid (thesis Alg. 2).
grid = Grid((64, 64))
x, y = grid.points.T
blobs = np.stack([np.exp(-((x - cx) ** 2 + (y - 0.5) ** 2) / 0.005) for cx in (0.25, 0.75)], 1)
bary = barycenter(grid, blobs / blobs.sum(0), weights=[0.5, 0.5], gamma=0.002)
print(f"grid barycenter peak at {np.round(grid.points[np.argmax(bary.masses)], 2)}, "
      f"converged={bary.converged}")
