r"""Geodesic distances on triangle meshes by the heat method, many sources at once.

Crane, Weischedel & Wardetzky, *Geodesics in Heat* (2013):

1. diffuse a unit spike at each source for a short time :math:`t_h = h^2`
   (:math:`h` the mean edge length): :math:`(D_a + t_h L)\, u = \delta_s`;
2. normalize the gradient on every face: :math:`X = -\nabla u / |\nabla u|`;
3. solve the Poisson equation :math:`L \phi = G^\top A X` (:math:`L = G^\top A G` the
   cotangent Laplacian, ``A`` the face areas) and shift :math:`\phi` to vanish at the source.

Steps 1 and 3 are one multi-column solve each on factorizations kept in the mesh's operator
store, so ``k`` sources cost two ``k``-column solves.  The distances are approximate (first
order in ``h``; ``bench/results/sharp_transport.md`` measures them against exact MMP
geodesics); they are what :class:`~solvers.kernels.GeodesicGaussianKernel` exponentiates.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.linalg import factorize_spd

# Sources per block of solves: bounds the (n, block) and (3F, block) work arrays.
SOURCE_BLOCK = 512
# Relative weight of the mass matrix added to the singular cotangent Laplacian of the
# Poisson step: fixes its constant (removed again by the shift to the source).
POISSON_SHIFT = 1e-10


def _poisson_factor(mesh):
    def build():
        system = mesh.cotan_laplacian + POISSON_SHIFT * sp.diags(mesh.areas)
        return factorize_spd(sp.csc_matrix(system))

    return mesh.operators.get(("heat_method_poisson",), build)


def heat_time_for_distances(mesh) -> float:
    """The heat method's diffusion time :math:`t_h = h^2` (``h`` the mean edge length)."""
    return float(mesh.mean_edge_length) ** 2


def heat_method_distances(mesh, sources) -> np.ndarray:
    """``(len(sources), n)`` approximate geodesic distances from each source vertex.

    Parameters
    ----------
    mesh : :class:`~solvers.domains.TriangleMesh` (unit area).
    sources : ``(k,)`` vertex indices.

    Returns
    -------
    ``(k, n)`` non-negative distances (0 at each row's source).
    """
    sources = np.asarray(sources, dtype=np.int64).reshape(-1)
    heat = mesh.heat_kernel(heat_time_for_distances(mesh), 1).factor
    poisson = _poisson_factor(mesh)
    grad, div = mesh.gradient, mesh.divergence  # div = -G^T diag(A)
    nf = mesh.n_faces
    out = np.empty((len(sources), mesh.n))
    for start in range(0, len(sources), SOURCE_BLOCK):
        block = sources[start:start + SOURCE_BLOCK]
        spikes = np.zeros((mesh.n, len(block)))
        spikes[block, np.arange(len(block))] = 1.0
        u = heat.solve(spikes)
        g = (grad @ u).reshape(nf, 3, len(block))
        norm = np.sqrt(np.einsum("fcb,fcb->fb", g, g))
        g /= np.where(norm > 0, norm, 1.0)[:, None, :]
        # L phi = G^T A X with X = -g (g the normalized gradient of u): div g
        phi = poisson.solve(div @ g.reshape(3 * nf, len(block)))
        phi -= phi[block, np.arange(len(block))]
        out[start:start + len(block)] = np.maximum(phi, 0.0).T
    return out


def all_pairs_heat_distances(mesh) -> np.ndarray:
    """``(n, n)`` symmetric heat-method distances (the mean of both directions), kept in the
    mesh's operator store."""

    def build():
        d = heat_method_distances(mesh, np.arange(mesh.n))
        d += d.T
        d *= 0.5
        return d

    return mesh.operators.get(("heat_method_all_pairs",), build)
