r"""Anisotropic earth mover's distances (thesis §2.7, Fig. 2.15).

The cost of moving mass may depend on where and in which direction it moves:

.. math::
    W_1^A(\mu_0, \mu_1) = \min_J \sum_t A_t \lVert M_t J_t\rVert
    \quad\text{s.t.}\quad \nabla\cdot J = \rho_0 - \rho_1 ,

with a scalar weight :math:`M_t = w_t I` (isotropic but position-dependent) or a 3×3 matrix
per face.  Scalar weights go to :func:`solvers.emd.earth_movers_distance` (interior point
over all flows).  Matrix weights are solved over *all* piecewise-constant flows too, by a
change of variables that turns them into a scalar problem: in the tangent frame
:math:`E_t` (2×3) of face ``t`` the cost is :math:`\lVert M_t E_t^\top j\rVert = \lVert R_t
j\rVert` with :math:`M_t E_t^\top = Q_t R_t` (QR, :math:`R_t` 2×2 invertible when
:math:`M_t` is injective on the tangent plane), so with :math:`v_t = R_t u_t`
(:math:`u_t = A_t j_t`) the problem is :math:`\min \sum_t \lVert v_t\rVert` s.t.
:math:`D R^{-1} v = m_0 - m_1`: the interior-point method of
:mod:`solvers.emd.interior_point` with a modified divergence, certified the same way.  (The
thesis' curl basis, ``basis="full"``, is a subspace of these flows and overestimates; with
matrix weights by a wide margin, see ``tests/test_anisotropy.py``.)

:func:`mean_curvature_weights` derives scalar weights from the mean curvature, as Fig. 2.15b
weights transport by curvature: :math:`w_t = 1 + \alpha\,|H_t| / \overline{|H|}`, so mass
avoids (``alpha > 0``) highly curved regions such as ridges and creases.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.curvature import mean_curvature
from solvers.emd.beckmann import (
    IPM_MAX_ITER,
    IPM_PATIENCE,
    METHODS,
    EMDResult,
    check_face_weights,
    check_mesh,
    check_pair,
    earth_movers_distance,
)
from solvers.errors import InputError
from solvers.monitor import Monitor
from solvers.validation import check_choice, check_finite

# A face's matrix must keep at least this fraction of the largest stretch of the tangent
# plane (relative to the largest singular value over all faces), else it is refused.
MIN_TANGENT_STRETCH = 1e-8


def mean_curvature_weights(mesh, strength: float = 1.0) -> np.ndarray:
    r"""``(F,)`` scalar face weights :math:`w_t = 1 + \alpha |H_t| / \overline{|H|}`.

    :math:`H` is the cotangent mean curvature per vertex
    (:func:`solvers.curvature.mean_curvature`), averaged over each face's corners;
    :math:`\overline{|H|}` its area-weighted mean over the faces, so ``strength``
    :math:`\alpha \ge 0` is dimensionless: ``alpha = 1`` doubles the cost where the curvature
    is average.  On a sphere the weights are the constant ``1 + alpha``.
    """
    alpha = check_finite(strength, "strength")
    if alpha < 0:
        raise InputError(f"strength must be >= 0, got {alpha}", field="strength")
    h = np.abs(mean_curvature(mesh))[mesh.faces].mean(axis=1)
    a = np.asarray(mesh.face_areas, dtype=np.float64)
    mean = float(a @ h / a.sum())
    if not (np.isfinite(mean) and mean > 0):  # flat: every weight is 1
        return np.ones(mesh.n_faces)
    return 1.0 + alpha * h / mean


def _tangent_factors(frames: np.ndarray, matrices: np.ndarray,
                     field: str = "face_weights") -> np.ndarray:
    """``(F, 2, 2)`` upper-triangular :math:`R_t` with :math:`M_t E_t^\\top = Q_t R_t`."""
    B = np.einsum("fij,fdj->fid", matrices, frames)  # (F, 3, 2) = M_t E_t^T
    R = np.linalg.qr(B, mode="r")
    sv = np.linalg.svd(R, compute_uv=False)  # (F, 2)
    top = float(sv[:, 0].max())
    bad = np.flatnonzero(~(sv[:, 1] > MIN_TANGENT_STRETCH * top))
    if len(bad):
        raise InputError(f"{field}[{int(bad[0])}] collapses the face's tangent plane (a "
                         "matrix must be injective on it)", field=field)
    return R


def check_face_matrices(vertices, faces, matrices, field: str = "face_weights") -> None:
    """Refuse (F, 3, 3) matrices that collapse the tangent plane of their face (the check
    :func:`anisotropic_w1` makes, from the geometry alone: for validation at submission)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    m = np.asarray(matrices, dtype=np.float64)
    if m.shape != (len(f), 3, 3) or not np.all(np.isfinite(m)):
        raise InputError(f"{field} must be finite ({len(f)}, 3, 3) matrices", field=field)
    e1 = v[f[:, 1]] - v[f[:, 0]]
    normal = np.cross(e1, v[f[:, 2]] - v[f[:, 0]])
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    _tangent_factors(np.stack([e1, np.cross(normal, e1)], axis=1), m, field)


def _matrix_ipm(mesh, m0, m1, matrices, tol, max_iter, monitor) -> EMDResult:
    """W1 with per-face matrices over all flows (module docstring)."""
    from solvers.emd.interior_point import beckmann_interior_point, normal_structure

    ops = check_mesh(mesh)
    geo, _ = ops.interior_point_structure
    R = _tangent_factors(geo.frames, matrices)
    R_inv = np.linalg.inv(R)
    nf = mesh.n_faces
    # columns (3t + 1 + d) of the interleaved divergence: u_t = R_t^{-1} v_t
    rows = (3 * np.arange(nf)[:, None, None] + 1 + np.arange(2)[None, :, None]
            ).repeat(2, axis=2)
    cols = (3 * np.arange(nf)[:, None, None] + 1 + np.arange(2)[None, None, :]
            ).repeat(2, axis=1)
    T = sp.csr_matrix((R_inv.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * nf, 3 * nf))
    div = (geo.div @ T).tocsr()
    structure = normal_structure(div, np.asarray(mesh.faces)[geo.faces], ops._keep)
    _, v = ops.particular_flow(m1 - m0)
    u0 = np.einsum("fc,fdc->fd", v, geo.frames) * ops.face_areas[:, None]
    out = beckmann_interior_point(div, structure.faces, np.ones(nf), m0 - m1, ops._keep,
                                  np.einsum("fij,fj->fi", R, u0), tol, max_iter, monitor,
                                  structure=structure)
    u = np.einsum("fij,fj->fi", R_inv, out.u)
    flow = np.einsum("fd,fdc->fc", u, geo.frames) / ops.face_areas[:, None]
    potential = -out.y
    labels, a = ops.labels, mesh.areas
    potential -= (np.bincount(labels, a * potential) / np.bincount(labels, a))[labels]
    value = float(ops.face_areas @ np.linalg.norm(np.einsum("fij,fj->fi", matrices, flow),
                                                  axis=1))
    scale = max(float(np.abs(m0 - m1).max()), 1e-300)
    return EMDResult(value=value, flow=flow, potential=potential,
                     lower_bound=out.lower_bound, iterations=out.iterations,
                     primal_residual=out.feasibility / scale, dual_residual=0.0,
                     residual=out.gap, converged=out.converged, method="ipm", basis="flow")


def anisotropic_w1(mesh, mu0, mu1, face_weights, *, method: str = "auto",
                   basis: str = "auto", k: int | None = None, tol: float | None = None,
                   max_iter: int | None = None, progress=None,
                   should_cancel=None) -> EMDResult:
    r"""W1 with the anisotropic cost :math:`\sum_t A_t\lVert M_t J_t\rVert` (§2.7, Fig. 2.15).

    Parameters
    ----------
    mesh : TriangleMesh.
    mu0, mu1 : (V,) masses (normalized to sum 1).
    face_weights : (F,) positive scalars or (F, 3, 3) matrices (each injective on its face's
        tangent plane).
    method, basis : ``"auto"``: the interior point over all flows (matrix weights by
        the change of variables of the module docstring); otherwise as
        :func:`~solvers.emd.earth_movers_distance` (``"admm"``/``"weiszfeld"`` in the curl
        basis ``"full"`` or a ``"spectral"`` one, an overestimate).
    tol : certified relative gap (interior point; default 1e-4) or the ADMM/Weiszfeld rule.

    Returns
    -------
    EMDResult: ``value``, ``flow`` (F, 3), ``potential`` (V,), ``lower_bound`` (certified,
    interior point), convergence report.
    """
    weights = check_face_weights(face_weights, mesh.n_faces)
    if weights is None:
        raise InputError("face_weights are required", field="face_weights")
    check_choice(method, METHODS, "method")
    matrix = weights.ndim == 3
    over_all_flows = method in ("auto", "ipm") and basis in ("auto", "flow")
    if not (matrix and over_all_flows):
        return earth_movers_distance(mesh, mu0, mu1, method=method, basis=basis, k=k,
                                     face_weights=weights, tol=tol, max_iter=max_iter,
                                     progress=progress, should_cancel=should_cancel)
    m0, m1 = check_pair(mesh, mu0, mu1)
    tol = 1e-4 if tol is None else check_finite(tol, "tol")
    if not tol > 0:
        raise InputError(f"tol must be positive, got {tol}", field="tol")
    monitor = Monitor(progress, should_cancel, tol=tol, patience=IPM_PATIENCE)
    return _matrix_ipm(mesh, m0, m1, weights, tol,
                       IPM_MAX_ITER if max_iter is None else int(max_iter), monitor)
