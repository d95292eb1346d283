r"""Energies of soft maps (thesis ch. 4): Dirichlet (eq. 4.1-4.2), transportation potential
and momentum (eq. 4.3-4.4), bijectivity (eq. 4.5), descriptor (eq. 4.6).

A soft map :math:`\mu: M_0 \to \mathrm{Prob}(M)` is given on the nodes of a source graph
(vertices or samples, :mod:`solvers.softmaps.sampling`) as rows of target *masses*
``rows[u] = a * rho_u`` (each row sums to 1).

* Dirichlet energy, eq. 4.2 discretized over the source edges:
  :math:`E_D[\mu] = \sum_{e=(u,u')} \omega_e\, W_2^2(\mu_u, \mu_{u'})`, with the
  convolutional :math:`W_2` (ch. 3; debiased by default so that a constant map has
  energy 0) or ``method="potential"``: the linearized :math:`W_2^2 = \int \rho |\nabla Q|^2`
  of eq. 4.3-4.4.
* Transportation potential: the derivative of :math:`\rho` along a source direction is
  carried by a flow, :math:`\partial_v \rho = -\nabla\cdot(\rho\nabla Q)` (eq. 4.3); along an
  edge :math:`\partial_v\rho \approx \rho_{u'} - \rho_u`, and where :math:`\rho` vanishes the
  thesis regularizes with :math:`\rho + \epsilon` -- one anisotropic Poisson problem
  :math:`G^\top D_{A_f(\rho_f + \epsilon)} G\, Q = m_{u'} - m_u` per source point and
  direction.  The momentum is :math:`\rho \nabla Q` per target face (eq. 4.4).
* Dirichlet energy density: :math:`\tfrac12\sum_{e \ni u}\omega_e W^2_e` divided by the
  area of the cell of ``u``, so that it integrates to :math:`E_D`.
* Bijectivity (eq. 4.5): :math:`b(y) = \int_{M_0}\rho_x(y)\,dx` and
  :math:`E_B = \int_M b^2`; 1 for a bijective isometry of unit-area surfaces
  (Proposition 11), larger when the map piles mass up.
* Descriptor energy (eq. 4.6): :math:`\int_{M_0}\int_M c(x, y)\, d\mu_x(y)\, dx`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from solvers.errors import InputError
from solvers.linalg import factorize_spd
from solvers.validation import check_choice, check_positive

DIRICHLET_METHODS = ("w2", "potential")


@dataclass
class DirichletEnergy:
    """``total``; ``per_edge`` ``(m,)`` :math:`W_2^2` of each edge; ``density`` per node."""

    total: float
    per_edge: np.ndarray
    density: np.ndarray

    def vertex_density(self, labels) -> np.ndarray:
        r"""``(n_source,)`` density per source vertex: that of its node's cell (``labels``
        ``(n_source,)``), so that :math:`\sum_x a_0(x)\,e(x) = E_D` with the cell areas the
        density was built with."""
        return self.density[np.asarray(labels, np.int64)]


def _check_rows(rows, n_nodes: int | None, n: int) -> np.ndarray:
    r = np.asarray(rows, dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != n or (n_nodes is not None and r.shape[0] != n_nodes):
        raise InputError(f"soft map rows must have shape ({n_nodes}, {n}), got {r.shape}",
                         field="soft_map")
    if not np.all(np.isfinite(r)) or np.any(r < 0):
        raise InputError("soft map rows must be finite non-negative masses", field="soft_map")
    return r / np.maximum(r.sum(axis=1, keepdims=True), 1e-300)


def potential_operator(target, masses: np.ndarray, eps: float = 1e-3) -> sp.csr_matrix:
    r""":math:`G^\top D_{A_f (\rho_f + \epsilon)} G`: the weighted Laplacian of eq. 4.3."""
    rho = masses / target.areas
    rho_f = rho[target.faces].mean(axis=1) + check_positive(eps, "eps")
    D = sp.diags(np.repeat(target.face_areas * rho_f, 3))
    G = target.gradient
    return (G.T @ D @ G).tocsr()


def transportation_potential(target, masses_from, masses_to, *, eps: float = 1e-3,
                             with_energy: bool = False):
    r"""Transportation potential :math:`Q` of eq. 4.3.

    Solves :math:`\nabla\cdot((\rho+\epsilon)\nabla Q) = -(\rho' - \rho)` on the target.

    Parameters
    ----------
    target : TriangleMesh
        The target surface (``n`` vertices, areas :math:`a`).
    masses_from, masses_to : (n,) array
        Target masses (:math:`\rho = m / a`).
    eps : float
        Regularization :math:`\epsilon` where :math:`\rho` vanishes (density units; the mean
        density is 1).
    with_energy : bool
        Also return the energy.

    Returns
    -------
    Q : (n,) array
        The potential (zero area-weighted mean).
    energy : float
        Only with ``with_energy``: :math:`\int (\rho+\epsilon)|\nabla Q|^2`, the
        linearized :math:`W_2^2`.
    """
    m0 = np.asarray(masses_from, dtype=np.float64)
    m1 = np.asarray(masses_to, dtype=np.float64)
    m0, m1 = m0 / m0.sum(), m1 / m1.sum()
    Lr = potential_operator(target, m0, eps)
    gauge = 1e-9 * float(Lr.diagonal().mean()) / float(target.areas.mean())
    factor = factorize_spd((Lr + gauge * sp.diags(target.areas)).tocsc())
    q = factor.solve(m1 - m0)
    q = q - target.areas @ q
    if with_energy:
        return q, float(q @ (Lr @ q))
    return q


def momentum(target, masses, q, *, eps: float = 1e-3) -> np.ndarray:
    r"""Momentum :math:`(\rho + \epsilon)\nabla Q` per target face (eq. 4.4).

    Parameters
    ----------
    target : TriangleMesh
        The target surface (``n`` vertices, areas :math:`a`).
    masses : (n,) array
        Target masses (:math:`\rho = m / a`).
    q : (n,) array
        Transportation potential (:func:`transportation_potential`).
    eps : float
        Regularization :math:`\epsilon` where :math:`\rho` vanishes (density units; the mean
        density is 1).

    Returns
    -------
    (F, 3) array
    """
    rho = np.asarray(masses, dtype=np.float64) / target.areas
    rho_f = rho[target.faces].mean(axis=1) + eps
    return (target.gradient @ q).reshape(-1, 3) * rho_f[:, None]


def dirichlet_energy(target, rows, edges, edge_weights, *, cell_areas=None,
                     method: str = "w2", gamma: float | None = None, substeps: int = 1,
                     debiased: bool = True, eps: float = 1e-3, tol: float = 1e-6
                     ) -> DirichletEnergy:
    r"""Dirichlet energy of a soft map, eq. 4.2 over the source edges.

    .. math:: E_D[\mu] = \sum_{e=(u,u')} \omega_e\, W_2^2(\mu_u, \mu_{u'})

    Parameters
    ----------
    target : TriangleMesh
        The target surface (``n`` vertices, areas :math:`a`).
    rows : (N, n) array
        Target masses per source node (each row sums to 1).
    edges : (m, 2) int array
        Source graph edges.
    edge_weights : (m,) array
        Edge weights :math:`\omega_e`.
    cell_areas : (N,) array, optional
        Source area per node, for the density (default: equal).
    method : {"w2", "potential"}
        ``"w2"``: convolutional :math:`W_2^2`; ``"potential"``:
        :math:`\int(\rho_u+\epsilon)|\nabla Q_e|^2` (eq. 4.3).
    gamma : float, optional
        Entropic regularization of ``"w2"`` (default ``4 * h^2``, ``h`` the target's mean
        edge length).
    substeps : int
        Implicit Euler steps of the heat kernel.
    debiased : bool
        Debiased (Sinkhorn divergence) :math:`W_2^2`, so a constant map has energy 0.
    eps : float
        Regularization :math:`\epsilon` where :math:`\rho` vanishes (density units; the mean
        density is 1).
    tol : float
        Stopping tolerance of each :math:`W_2` solve.

    Returns
    -------
    DirichletEnergy
        ``total``, ``per_edge`` ``(m,)`` and ``density`` ``(N,)`` per node.
    """
    from solvers.convolutional import wasserstein_distance

    e = np.asarray(edges, np.int64)
    w = np.asarray(edge_weights, np.float64)
    r = _check_rows(rows, None, target.n)
    check_choice(method, DIRICHLET_METHODS, "method")
    gamma = 4.0 * target.mean_edge_length**2 if gamma is None else check_positive(gamma,
                                                                                  "gamma")
    per = np.zeros(len(e))
    for k, (u, v) in enumerate(e):
        if method == "w2":
            per[k] = max(wasserstein_distance(target, r[u], r[v], gamma=gamma, tol=tol,
                                              substeps=substeps, debiased=debiased).value, 0.0)
        else:
            per[k] = transportation_potential(target, r[u], r[v], eps=eps, with_energy=True)[1]
    return _assemble(per, e, w, len(r), cell_areas)


def _assemble(per, e, w, n_nodes, cell_areas) -> DirichletEnergy:
    cells = np.full(n_nodes, 1.0 / n_nodes) if cell_areas is None else np.asarray(cell_areas)
    node = np.zeros(n_nodes)
    np.add.at(node, e[:, 0], 0.5 * w * per)
    np.add.at(node, e[:, 1], 0.5 * w * per)
    return DirichletEnergy(total=float(w @ per), per_edge=per, density=node / cells)


def dirichlet_from_edge_values(edge_values, edges, edge_weights, n_nodes: int,
                               cell_areas=None) -> DirichletEnergy:
    """Dirichlet energy from per-edge :math:`W^2` already measured (e.g. by the propagation)."""
    per = np.maximum(np.asarray(edge_values, np.float64), 0.0)
    return _assemble(per, np.asarray(edges, np.int64), np.asarray(edge_weights, np.float64),
                     n_nodes, cell_areas)


def bijectivity_density(target, rows, cell_areas) -> np.ndarray:
    r"""eq. 4.5: :math:`b(y) = \sum_u |\text{cell}_u|\, \rho_u(y)` per target vertex.

    Parameters
    ----------
    target, rows, cell_areas : TriangleMesh, (N, n) array, (N,) array
        The target (``n`` vertices), the masses per source node (rows sum to 1) and the
        nodes' cell areas.

    Returns
    -------
    (n,) array
    """
    r = _check_rows(rows, None, target.n)
    cells = np.asarray(cell_areas, np.float64)
    return (cells @ r) / target.areas


def bijectivity_density_top_k(target, indices, masses, cell_areas) -> np.ndarray:
    r""":func:`bijectivity_density` of a top-k soft map (``indices``/``masses`` ``(N, k)``).

    The kept masses are used as they are (not renormalized), so
    :math:`\int_M b = 1 - \sum_u |\text{cell}_u|\,\text{dropped}_u`: the dropped mass is
    missing from ``b`` rather than moved onto the kept entries.
    """
    idx = np.asarray(indices, np.int64)
    m = np.asarray(masses, np.float64)
    cells = np.asarray(cell_areas, np.float64)
    if idx.shape != m.shape or idx.ndim != 2 or len(cells) != len(m):
        raise InputError("top-k indices and masses must both be (N, k) with N cell areas",
                         field="soft_map")
    if idx.size and (idx.min() < 0 or idx.max() >= target.n):
        raise InputError(f"top-k indices must be target vertices in [0, {target.n - 1}]",
                         field="soft_map")
    mass = np.bincount(idx.ravel(), weights=(cells[:, None] * m).ravel(), minlength=target.n)
    return mass / target.areas


def bijectivity_energy(target, rows, cell_areas) -> float:
    r"""eq. 4.5: :math:`E_B = \int_M b(y)^2\,dy` (1 for a bijective unit-area isometry).

    Parameters
    ----------
    target, rows, cell_areas
        As in :func:`bijectivity_density`.

    Returns
    -------
    float
    """
    b = bijectivity_density(target, rows, cell_areas)
    return float(target.areas @ b**2)


def descriptor_energy(rows, cost, cell_areas) -> float:
    r"""eq. 4.6: :math:`\sum_u |\text{cell}_u| \sum_y \mu_u(y)\, c(u, y)`.

    Parameters
    ----------
    rows : (N, n) array
        Target masses per source node (each row sums to 1).
    cost : (N, n) array
        Compatibility cost :math:`c` (:func:`compatibility_cost`).
    cell_areas : (N,) array
        Source area of each node's cell.

    Returns
    -------
    float
    """
    r = np.asarray(rows, np.float64)
    r = r / np.maximum(r.sum(axis=1, keepdims=True), 1e-300)
    return float(np.asarray(cell_areas, np.float64) @ np.einsum("ij,ij->i", r, cost))


@dataclass
class SoftMapEnergies:
    r"""The energies of one soft map (ch. 4) with their densities.

    ``dirichlet`` :class:`DirichletEnergy` (eq. 4.2; ``density`` per source node) and
    ``dirichlet_vertex_density`` ``(n_source,)`` the same per source vertex;
    ``bijectivity`` :math:`E_B` and ``bijectivity_density`` :math:`b` ``(n_target,)``
    (eq. 4.5); ``descriptor`` eq. 4.6.
    """

    dirichlet: DirichletEnergy
    dirichlet_vertex_density: np.ndarray
    bijectivity: float
    bijectivity_density: np.ndarray
    descriptor: float


def soft_map_energies(target, result) -> SoftMapEnergies:
    r"""Energies of a :class:`~solvers.softmaps.SoftMapResult` on ``target``.

    The Dirichlet energy and descriptor energy are those the propagation measured
    (``result.dirichlet``, ``result.descriptor_energy``); :math:`b` and :math:`E_B =
    \int_M b^2` (eq. 4.5) are computed from the rows on the target's vertices (dense --
    prolonged from a coarse target --, or the kept top-k masses,
    :func:`bijectivity_density_top_k`).

    Parameters
    ----------
    target : TriangleMesh
        The soft map's target.
    result : SoftMapResult
        From :func:`soft_map`.

    Returns
    -------
    SoftMapEnergies
        ``dirichlet`` (eq. 4.2), ``dirichlet_vertex_density``, ``bijectivity`` and
        ``bijectivity_density`` (eq. 4.5), ``descriptor`` (eq. 4.6).
    """
    if result.soft_map is not None and result.prolongation is not None:
        # b is linear in the rows: prolong the cell-weighted coarse masses once.
        cells = np.asarray(result.cell_areas, np.float64)
        b = result.prolongation.apply(cells @ result.soft_map.astype(np.float64)) / target.areas
    elif result.soft_map is not None:
        b = bijectivity_density(target, result.soft_map, result.cell_areas)
    else:
        b = bijectivity_density_top_k(target, result.top_indices, result.top_masses,
                                      result.cell_areas)
    return SoftMapEnergies(dirichlet=result.dirichlet,
                           dirichlet_vertex_density=result.dirichlet.vertex_density(
                               result.labels),
                           bijectivity=float(target.areas @ b**2), bijectivity_density=b,
                           descriptor=float(result.descriptor_energy))
