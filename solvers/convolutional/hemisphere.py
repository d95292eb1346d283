r"""The hemisphere of outgoing directions as a domain for BRDF transport (thesis §3.7).

:class:`HemisphereGrid` is a regular :math:`(\theta, \phi)` grid (cell centres,
:math:`\theta \in (0, \pi/2)` polar angle from the normal, :math:`\phi` periodic), with
area weights :math:`a_{ij} \propto \sin\theta_i\,\Delta\theta\,\Delta\phi` normalized to
sum 1.  The sphere is scaled to unit hemisphere area (radius :math:`R = 1/\sqrt{2\pi}`),
the convention of :func:`solvers.load_mesh`, so ``gamma`` means the same as on a mesh.

Its kernel (:class:`HemisphereHeatKernel`) is the thesis' latitude-modulated separable
Gaussian, evaluated exactly (no recursive Deriche approximation): with the local metric
:math:`ds^2 = R^2(d\theta^2 + \sin^2\theta\, d\phi^2)`,

.. math::  K[(i,j),(k,l)] = \frac{1}{4\pi t}
           \exp\!\Big(-\frac{R^2(\theta_i-\theta_k)^2}{4t}\Big)\,
           \exp\!\Big(-\frac{R^2 \sin^2\bar\theta_{ik}\, d_\phi(\phi_j,\phi_l)^2}{4t}\Big),
           \qquad \bar\theta_{ik} = \tfrac12(\theta_i+\theta_k),

a product of a Gaussian in :math:`\theta` and a Gaussian in :math:`\phi` whose width is
divided by :math:`\sin\bar\theta` (wider near the pole, as on the sphere); using the
mid-latitude keeps :math:`K` symmetric, so ``apply(x) = K (a ⊙ x)`` is self-adjoint in the
``a``-weighted product like every heat kernel here.  ``K`` is then rescaled symmetrically,
:math:`D K D` with :math:`D K D a = 1` (a few symmetric Sinkhorn steps, residual in
``kernel.normalization_residual``), so it conserves mass like the mesh kernel (Neumann
equator) instead of losing it past the equator and near the pole.  ``t = gamma/4`` (Varadhan, see
:mod:`solvers.kernels`).  The kernel is assembled once as a dense ``n × n`` matrix (cached
in the domain's operator store) and applied with one BLAS product per block.

``method="separable"`` is this kernel; ``method="geodesic"`` (default) replaces the
product by the exact great-circle Gaussian :math:`\exp(-d(\omega,\omega')^2/4t)` -- the
same dense cost here.  The separable metric overestimates distances across the pole (a
coordinate singularity), and barycenters of lobes spanning the pole pile spurious mass on
the first ring (measured in ``bench/results/applications.md``); the geodesic kernel has no
such artifact.

For comparison, :func:`triangulated_hemisphere` builds a :class:`~solvers.TriangleMesh`
whose vertices are the grid points plus the pole (rings joined by triangle strips), whose
mesh heat kernel (implicit Euler on the robust Laplacian, Neumann at the equator) is the
reference; :func:`kernel_discrepancy` reports how far the two kernels are apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.domains.base import Domain
from solvers.errors import InputError
from solvers.kernels import heat_time
from solvers.validation import check_choice, check_int, check_positive

RADIUS = 1.0 / np.sqrt(2.0 * np.pi)  # unit hemisphere area
EXTENT = float(np.pi * RADIUS)  # pole-to-pole geodesic length of the full sphere / 2
METHODS = ("separable", "geodesic")  # kernel: the thesis' product, or exact great circles
MAX_POINTS = 8192  # the dense kernel holds n^2 floats (512 MB at this size)


class HemisphereHeatKernel:
    """Dense Gaussian on a :class:`HemisphereGrid`: the latitude-modulated separable product
    (``method="separable"``) or the great-circle one (``"geodesic"``), see the module.

    Parameters
    ----------
    grid, t : HemisphereGrid, float
        The grid and the heat time.
    """

    supports_log = False

    def __init__(self, grid: HemisphereGrid, t: float):
        t = check_positive(t, "t")
        self.t = float(t)
        self.n = grid.n
        self.substeps = 1
        th, ph = grid.theta_axis, grid.phi_axis
        dth = th[:, None] - th[None, :]
        mid = 0.5 * (th[:, None] + th[None, :])
        dph = np.abs(ph[:, None] - ph[None, :])
        dph = np.minimum(dph, 2.0 * np.pi - dph)
        log_t = -(RADIUS * dth) ** 2 / (4.0 * t)  # (nt, nt)
        s2 = (RADIUS * np.sin(mid)) ** 2  # (nt, nt)
        nt, nphi = grid.shape
        if grid.method == "separable":
            log_k = (log_t[:, None, :, None]
                     - s2[:, None, :, None] * (dph ** 2)[None, :, None, :] / (4.0 * t))
            log_k = log_k.reshape(self.n, self.n)
        else:  # exact great-circle distances
            cosd = np.clip(grid.directions @ grid.directions.T, -1.0, 1.0)
            log_k = -(RADIUS * np.arccos(cosd)) ** 2 / (4.0 * t)
        log_k = log_k - np.log(4.0 * np.pi * t)
        with np.errstate(under="ignore"):
            K = np.exp(log_k)
        self.areas = grid.areas
        # Symmetric scaling D K D with D K D a = 1 (mass conserving, like the mesh's heat
        # kernel with its Neumann boundary): the plain product loses mass past the equator
        # and near the pole (where the approximate metric is poorest), which the
        # barycenters would turn into spurious peaks there.
        d = np.ones(self.n)
        for _ in range(200):
            d = np.sqrt(d / (K @ (self.areas * d)))
            self.normalization_residual = float(np.max(np.abs(d * (K @ (self.areas * d)) - 1)))
            if self.normalization_residual < 1e-12:
                break
        self.matrix = d[:, None] * K * d[None, :]

    def apply(self, block: np.ndarray) -> np.ndarray:
        """Apply the kernel to a block: :math:`H_t x` per column.

        Parameters
        ----------
        block : (n,) or (n, k) array
            Densities on the grid points.

        Returns
        -------
        (n,) or (n, k) array
        """
        x = np.asarray(block, dtype=np.float64)
        a = self.areas if x.ndim == 1 else self.areas[:, None]
        return self.matrix @ (a * x)

    def log_apply(self, log_block):  # pragma: no cover - protocol completeness
        """Not offered (``supports_log`` is False): raises ``NotImplementedError``; the solvers
        apply this kernel through log-domain bands.

        Parameters
        ----------
        log_block : (n,) or (n, k) array
            Logarithms.
        """
        raise NotImplementedError("the hemisphere kernel is applied through LogKernel bands")


class HemisphereGrid(Domain):
    r"""``n_theta × n_phi`` cell centres of the upper hemisphere, point ``i * n_phi + j``.

    ``theta`` / ``phi`` ``(n,)`` angles per point, ``directions`` ``(n, 3)`` unit vectors
    (z = normal), ``areas`` ``(n,)`` :math:`\propto \sin\theta`, summing to 1.

    Parameters
    ----------
    n_theta, n_phi : int
        Rings and points per ring.
    method : {"geodesic", "separable"}
        The kernel: great-circle Gaussian, or the latitude-modulated separable product.
    """

    kind = "hemisphere"

    def __init__(self, n_theta: int = 16, n_phi: int = 64, method: str = "geodesic"):
        super().__init__()
        check_choice(method, METHODS, "method")
        self.method = method
        nt = check_int(n_theta, "n_theta", low=2)
        nphi = check_int(n_phi, "n_phi", low=4)
        if nt * nphi > MAX_POINTS:
            raise InputError(f"n_theta * n_phi = {nt * nphi} exceeds {MAX_POINTS}",
                             field="n_theta")
        self.shape = (nt, nphi)
        self.n = nt * nphi
        self.theta_axis = (np.arange(nt) + 0.5) * (0.5 * np.pi / nt)
        self.phi_axis = np.arange(nphi) * (2.0 * np.pi / nphi) - np.pi  # phi = pi is a node
        self.theta = np.repeat(self.theta_axis, nphi)
        self.phi = np.tile(self.phi_axis, nt)
        w = np.sin(self.theta)
        self.areas = w / w.sum()
        self.directions = spherical_to_vector(self.theta, self.phi)

    @property
    def extent(self) -> float:
        return EXTENT

    @property
    def points(self) -> np.ndarray:
        return RADIUS * self.directions

    def _adjacency(self) -> sp.spmatrix:
        nt, nphi = self.shape
        idx = np.arange(self.n).reshape(nt, nphi)
        rows = np.r_[idx[:, :].ravel(), idx[:-1, :].ravel()]
        cols = np.r_[np.roll(idx, -1, axis=1).ravel(), idx[1:, :].ravel()]
        return sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(self.n, self.n)).tocsr()

    def heat_kernel(self, t: float, substeps: int = 1, backend="auto") -> HemisphereHeatKernel:
        """The latitude-modulated Gaussian at heat time ``t`` (``substeps`` ignored: exact)."""
        return self.operators.get(("hemisphere_kernel", float(t)),
                                  lambda: HemisphereHeatKernel(self, float(t)))

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"shape": np.asarray(self.shape)}

    def parameters(self) -> dict:
        return {"method": self.method}


def spherical_to_vector(theta, phi) -> np.ndarray:
    """Unit vectors ``(..., 3)`` of polar angle ``theta`` and azimuth ``phi`` (z = normal).

    Parameters
    ----------
    theta, phi : array
        Polar angle and azimuth.

    Returns
    -------
    (..., 3) array
    """
    theta, phi = np.asarray(theta, float), np.asarray(phi, float)
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def triangulated_hemisphere(grid: HemisphereGrid):
    """A :class:`~solvers.TriangleMesh` on the grid points plus the pole (vertex ``n``).

    Vertex ``i < grid.n`` is grid point ``i``; neighbouring latitude rings are joined by
    triangle strips, the first ring to the pole by a fan; the equator ring is the boundary.

    Parameters
    ----------
    grid : HemisphereGrid
        The grid.

    Returns
    -------
    TriangleMesh
    """
    from solvers.domains.mesh import TriangleMesh

    nt, nphi = grid.shape
    idx = np.arange(grid.n).reshape(nt, nphi)
    pole = grid.n
    faces = [[pole, idx[0, j], idx[0, (j + 1) % nphi]] for j in range(nphi)]
    for i in range(nt - 1):
        for j in range(nphi):
            j1 = (j + 1) % nphi
            faces.append([idx[i, j], idx[i + 1, j], idx[i + 1, j1]])
            faces.append([idx[i, j], idx[i + 1, j1], idx[i, j1]])
    vertices = np.vstack([grid.directions, [[0.0, 0.0, 1.0]]])
    return TriangleMesh(vertices, np.asarray(faces, dtype=np.int64))


@dataclass
class KernelDiscrepancy:
    """Grid kernel vs mesh kernel on the same points, one diffused Dirac per source.

    ``l1``: per source, the L1 distance between the two diffused distributions (masses on
    the grid points, each normalized to 1; the mesh's pole vertex dropped); ``spread``:
    per source the RMS geodesic radius (unit-area units) of the grid and of the mesh
    distribution, ``(S, 2)``; ``sources``: grid point indices.

    Attributes
    ----------
    sources : (S,) int array
        Grid point indices.
    l1 : (S,) array
        L1 distance between the two diffused distributions.
    spread : (S, 2) array
        RMS geodesic radius of the grid's and of the mesh's distribution.
    gamma : float
        Regularization.
    substeps : int
        Implicit Euler steps of the mesh kernel.
    """

    sources: np.ndarray
    l1: np.ndarray
    spread: np.ndarray
    gamma: float
    substeps: int


def kernel_discrepancy(grid: HemisphereGrid, gamma: float, *, substeps: int = 8,
                       sources=None) -> KernelDiscrepancy:
    """How far the grid kernel is from the triangulated hemisphere's heat kernel.

    For each source point ``s`` both kernels diffuse a unit mass at ``s`` for heat time
    ``t = gamma/4``; the results are compared as distributions on the grid points (L1 of
    the normalized masses, in ``[0, 2]``) and by their RMS geodesic spread around ``s``.

    Parameters
    ----------
    grid : HemisphereGrid
        The grid.
    gamma : float
        Regularization (``t = gamma/4``).
    substeps : int
        Implicit Euler steps of the mesh kernel.
    sources : array of int, optional
        Source grid points.

    Returns
    -------
    KernelDiscrepancy
    """
    gamma = check_positive(gamma, "gamma")
    t = heat_time(gamma)
    mesh = triangulated_hemisphere(grid)
    nt, nphi = grid.shape
    if sources is None:
        sources = np.array([i * nphi + nphi // 3 for i in (0, nt // 4, nt // 2,
                                                           (3 * nt) // 4, nt - 1)])
    sources = np.asarray(sources, dtype=np.int64)
    K = grid.heat_kernel(t)
    dirac = np.zeros((grid.n, len(sources)))
    dirac[sources, np.arange(len(sources))] = 1.0 / grid.areas[sources]
    g = grid.areas[:, None] * K.apply(dirac)
    Hm = mesh.heat_kernel(t, substeps)  # the mesh is rescaled to unit area too: same t
    md = np.zeros((mesh.n, len(sources)))
    md[sources, np.arange(len(sources))] = 1.0 / mesh.areas[sources]
    m = (mesh.areas[:, None] * Hm.apply(md))[: grid.n]
    g = g / g.sum(axis=0)
    m = np.maximum(m, 0.0)
    m = m / m.sum(axis=0)
    cosd = np.clip(grid.directions @ grid.directions[sources].T, -1.0, 1.0)
    d2 = (RADIUS * np.arccos(cosd)) ** 2
    spread = np.stack([np.sqrt((g * d2).sum(axis=0)), np.sqrt((m * d2).sum(axis=0))], axis=1)
    return KernelDiscrepancy(sources=sources, l1=np.abs(g - m).sum(axis=0), spread=spread,
                             gamma=float(gamma), substeps=int(substeps))
