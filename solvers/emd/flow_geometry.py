r"""The flow block of the W1 (Beckmann) cone programs on a triangle mesh (thesis ch. 2).

One tangent vector per face, written ``(s_t, u_t)`` with ``u_t = A_t J_t`` in a tangent
frame: the faces that carry flow, the weak divergence in these interleaved variables, and
the way back from a block to face vectors and its cost.  Shared by the conic programs of
:mod:`solvers.emd.exact` and :mod:`solvers.emd.path_planning` and by the interior point of
:mod:`solvers.emd.interior_point`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

if TYPE_CHECKING:
    from solvers.domains.mesh import TriangleMesh


@dataclass
class FlowGeometry:
    """The flow block of a mesh's Beckmann problem: which faces carry flow, their weights,
    the weak divergence in interleaved variables and the tangent frames."""

    faces: np.ndarray  # indices of faces that carry flow (finite weight)
    weights: np.ndarray  # (len(faces),)
    div: sp.csr_matrix  # (V, 3*len(faces)) weak divergence in interleaved variables
    frames: np.ndarray  # (len(faces), 2, 3) tangent frame


def flow_geometry(mesh: TriangleMesh, weights: np.ndarray) -> FlowGeometry:
    """The :class:`FlowGeometry` of ``mesh`` for per-face ``weights`` ``(F,)`` (an infinite
    weight blocks its face)."""
    free = np.flatnonzero(np.isfinite(weights))
    v, f = mesh.vertices, mesh.faces
    e1 = v[f[:, 1]] - v[f[:, 0]]
    e1 /= np.linalg.norm(e1, axis=1)[:, None]
    e2 = np.cross(mesh.face_normals, e1)
    nf = mesh.n_faces
    rows = np.repeat(3 * np.arange(nf)[:, None] + np.arange(3), 2, axis=1).ravel()
    cols = np.tile(2 * np.arange(nf)[:, None] + np.array([0, 1]), (1, 3)).ravel()
    vals = np.stack([e1, e2], axis=2).reshape(nf, 6).ravel()
    frame = sp.csr_matrix((vals, (rows, cols)), shape=(3 * nf, 2 * nf))
    # mesh.divergence @ J with J = E u / A_t  ==  -(E^T G)^T u
    div_u = (-(frame.T @ mesh.gradient).T).tocoo()
    face_of_col, d = np.divmod(div_u.col, 2)
    position = -np.ones(nf, dtype=np.int64)
    position[free] = np.arange(len(free))
    keep = position[face_of_col] >= 0
    div = sp.csr_matrix(
        (div_u.data[keep], (div_u.row[keep], 3 * position[face_of_col[keep]] + 1 + d[keep])),
        shape=(mesh.n, 3 * len(free)))
    return FlowGeometry(free, weights[free], div, np.stack([e1, e2], axis=1)[free])


def flow_vectors(mesh: TriangleMesh, geo: FlowGeometry, x_block: np.ndarray) -> np.ndarray:
    """(F, 3) tangent J from the interleaved block ``[s, u1, u2]`` per free face."""
    u = x_block.reshape(-1, 3)[:, 1:]
    J = np.zeros((mesh.n_faces, 3))
    J[geo.faces] = np.einsum("fd,fdc->fc", u, geo.frames) / mesh.face_areas[geo.faces, None]
    return J


def flow_cost(geo: FlowGeometry, x_block: np.ndarray) -> float:
    """sum_t w_t A_t |J_t| = sum_t w_t |u_t| of an interleaved flow block."""
    return float(geo.weights @ np.linalg.norm(x_block.reshape(-1, 3)[:, 1:], axis=1))
