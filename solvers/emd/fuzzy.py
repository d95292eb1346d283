r"""Fuzzy geodesics (thesis §2.7, Fig. 2.13): the magnitude of the optimal W1 flow between
two bumps.

For :math:`\rho_0, \rho_1` concentrated near points :math:`a, b`, the Beckmann flow
(eq. 2.3) :math:`J` minimizing :math:`\int\lVert J\rVert` with
:math:`\nabla\cdot J = \rho_0 - \rho_1` runs along the geodesics from :math:`a` to
:math:`b`; :math:`\lVert J\rVert` is a "fuzzy" geodesic whose ridge follows the shortest
path and which widens where several paths are (nearly) as short.  Solved by the certified
interior-point route of :func:`solvers.emd.earth_movers_distance`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.emd.beckmann import earth_movers_distance
from solvers.errors import InputError
from solvers.geodesics import geodesic_distances_within
from solvers.monitor import SolverResult

# Bump radius in mean edge lengths when none is given.
DEFAULT_RADIUS_EDGES = 3.0


@dataclass
class FuzzyGeodesicResult(SolverResult):
    r"""``face_norms`` (F,) ‖J‖ per face, ``vertex_norms`` (V,) their area-weighted mean over
    each vertex's faces, ``flow`` (F, 3), ``value`` = W1 between the bumps ``mu0``, ``mu1``
    (V,) and the ``radius`` used.  ``residual`` is the certified relative gap.

    Attributes
    ----------
    face_norms : (F,) array
        :math:`\|J\|` per face.
    vertex_norms : (V,) array
        Their area-weighted mean over each vertex's faces.
    flow : (F, 3) array
        The W1 flow :math:`J`.
    value : float
        :math:`W_1` between the bumps.
    mu0, mu1 : (V,) array
        The two bumps.
    radius : float
        The bumps' radius.
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
    """

    face_norms: np.ndarray
    vertex_norms: np.ndarray
    flow: np.ndarray
    value: float
    mu0: np.ndarray
    mu1: np.ndarray
    radius: float


def geodesic_bump(mesh, center: int, radius: float) -> np.ndarray:
    """(V,) masses ``∝ A_v exp(-(d(center, v) / radius)^2)`` with exact geodesic ``d``, cut
    at ``3 radius``; normalized to sum 1."""
    d = geodesic_distances_within(mesh, int(center), 3.0 * radius)
    w = np.where(np.isfinite(d), np.exp(-((np.nan_to_num(d, posinf=0.0) / radius) ** 2)), 0.0)
    m = mesh.areas * w
    return m / m.sum()


def fuzzy_geodesic(mesh, a: int, b: int, *, radius: float | None = None, tol: float = 1e-6,
                   max_iter: int | None = None, progress=None,
                   should_cancel=None) -> FuzzyGeodesicResult:
    r"""‖J‖ of the W1 flow between geodesic bumps at vertices ``a`` and ``b`` (Fig. 2.13).

    :math:`J` is the Beckmann flow (eq. 2.3)
    :math:`\arg\min_J \int \lVert J \rVert` subject to
    :math:`\nabla\cdot J = \rho_0 - \rho_1`, for bumps :math:`\rho_0, \rho_1` at ``a``, ``b``.

    Parameters
    ----------
    mesh : TriangleMesh.
    a, b : vertex indices of the two points (same connected component).
    radius : bump radius at unit area (default ``DEFAULT_RADIUS_EDGES`` mean edge lengths).
    tol, max_iter, progress, should_cancel : as in
        :func:`solvers.emd.earth_movers_distance` (interior-point route; ``tol`` is the
        certified relative gap).

    Returns
    -------
    FuzzyGeodesicResult (face_norms (F,), vertex_norms (V,), flow (F, 3), value, mu0, mu1).
    """
    for name, v in (("a", a), ("b", b)):
        if not isinstance(v, (int, np.integer)) or not 0 <= v < mesh.n:
            raise InputError(f"{name} must be a vertex index in [0, {mesh.n - 1}]", field=name)
    if mesh.component_labels[a] != mesh.component_labels[b]:
        raise InputError("a and b must lie on the same connected component", field="b")
    r = DEFAULT_RADIUS_EDGES * mesh.mean_edge_length if radius is None else float(radius)
    if not (np.isfinite(r) and r > 0):
        raise InputError("radius must be positive", field="radius")
    mu0, mu1 = geodesic_bump(mesh, a, r), geodesic_bump(mesh, b, r)
    res = earth_movers_distance(mesh, mu0, mu1, method="ipm", tol=tol, max_iter=max_iter,
                                progress=progress, should_cancel=should_cancel)
    face_norms = np.linalg.norm(res.flow, axis=1)
    fa = np.repeat(mesh.face_areas, 3)
    idx = mesh.faces.ravel()
    vertex_norms = np.bincount(idx, fa * np.repeat(face_norms, 3), minlength=mesh.n) / \
        np.bincount(idx, fa, minlength=mesh.n)
    return FuzzyGeodesicResult(face_norms=face_norms, vertex_norms=vertex_norms,
                               flow=res.flow, value=res.value, mu0=mu0, mu1=mu1, radius=r,
                               iterations=res.iterations, residual=res.residual,
                               converged=res.converged)
