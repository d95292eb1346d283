r"""Low-rank analysis of soft correspondences (thesis §4.6).

A soft map on ``N`` source nodes is a row-stochastic matrix ``P`` (``N × n`` target masses).
§4.6.1: its SVD in the area-weighted inner products, with the uniform vector kept as the
first basis function: :math:`P` maps the constant to the constant, so writing
:math:`\tilde P = D_{a_0}^{1/2}(P D_a^{-1})D_a^{1/2}` (densities, symmetric weights), the
constant singular pair is split off exactly and the rest is the SVD of
:math:`\tilde P - \sqrt{a_0}\sqrt{a}^\top`.  The rank-``r`` approximation keeps the uniform
pair and ``r - 1`` others; its error is reported in the same weighted Frobenius norm.
§4.6.2: bases from a collection of maps -- the SVD of the maps' source-side factors stacked
side by side gives one target-side basis shared by all of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solvers.errors import InputError
from solvers.validation import check_int


@dataclass
class SoftMapBasis:
    """SVD bases of a soft map (§4.6.1), from :func:`soft_map_svd`.

    Columns are area-orthonormal, the first the constant; the density
    :math:`P_{xy} / a(y)` is approximated by ``source_basis @ diag(singular_values) @
    target_basis.T`` (see :func:`low_rank_approximation`).

    Attributes
    ----------
    source_basis : (N, r) array
        Left singular vectors.
    singular_values : (r,) array
        Singular values.
    target_basis : (n, r) array
        Right singular vectors.
    source_areas : (N,) array
        Source areas the bases are orthonormal for.
    target_areas : (n,) array
        Target areas the bases are orthonormal for.
    """

    source_basis: np.ndarray
    singular_values: np.ndarray
    target_basis: np.ndarray
    source_areas: np.ndarray
    target_areas: np.ndarray


def _weighted(P, a0, a):
    P = np.asarray(P, np.float64)
    if P.ndim != 2 or P.shape != (len(a0), len(a)):
        raise InputError(f"soft map must have shape ({len(a0)}, {len(a)})", field="soft_map")
    P = P / np.maximum(P.sum(axis=1, keepdims=True), 1e-300)
    # Density kernel rho(x, y) = P[x, y] / a(y), in the symmetric weighted inner product.
    return np.sqrt(a0)[:, None] * (P / a[None, :]) * np.sqrt(a)[None, :]


def soft_map_svd(P, source_areas, target_areas, rank: int | None = None) -> SoftMapBasis:
    """§4.6.1 SVD bases of a soft map with the uniform vector kept first.

    Parameters
    ----------
    P : (N, n) array
        Soft map: target masses per source row.
    source_areas : (N,) array
        Source areas (cell areas of the rows).
    target_areas : (n,) array
        Target vertex areas.
    rank : int, optional
        Columns kept (default all).

    Returns
    -------
    SoftMapBasis
    """
    a0 = np.asarray(source_areas, np.float64) / np.sum(source_areas)
    a = np.asarray(target_areas, np.float64) / np.sum(target_areas)
    M = _weighted(P, a0, a)
    u0, v0 = np.sqrt(a0), np.sqrt(a)
    R = M - np.outer(u0, v0)  # rho integrates to 1 on M and to |M0| on M0: exact split
    full = min(M.shape) + 1  # the uniform pair and every pair of the remainder
    rank = full if rank is None else check_int(rank, "rank", low=1, high=full)
    U, s, Vt = np.linalg.svd(R, full_matrices=False)
    U, s, Vt = U[:, :rank - 1], s[:rank - 1], Vt[:rank - 1]
    src = np.concatenate([u0[:, None], U], axis=1) / np.sqrt(a0)[:, None]
    tgt = np.concatenate([v0[:, None], Vt.T], axis=1) / np.sqrt(a)[:, None]
    sv = np.concatenate([[1.0], s])
    return SoftMapBasis(src, sv, tgt, a0, a)


def low_rank_approximation(P, source_areas, target_areas, rank: int):
    """Rank-``rank`` approximation of the masses ``P`` and its relative error (§4.6.1).

    Parameters
    ----------
    P, source_areas, target_areas
        As in :func:`soft_map_svd`.
    rank : int
        Rank kept.

    Returns
    -------
    approx : (N, n) array
        The rank-``rank`` masses.
    error : float
        Relative area-weighted Frobenius error.
    """
    basis = soft_map_svd(P, source_areas, target_areas, rank)
    a0, a = basis.source_areas, basis.target_areas
    density = (basis.source_basis * basis.singular_values) @ basis.target_basis.T
    approx = density * a[None, :]
    M = _weighted(P, a0, a)
    Ma = np.sqrt(a0)[:, None] * density * np.sqrt(a)[None, :]
    err = float(np.linalg.norm(M - Ma) / np.linalg.norm(M))
    return approx, err


def collection_basis(maps, source_areas, target_areas, rank: int) -> np.ndarray:
    """§4.6.2: one area-orthonormal target basis (constant first) for several soft maps.

    The weighted, de-meaned kernels are stacked along the source axis and their leading
    right singular vectors kept.

    Parameters
    ----------
    maps : list of (N_i, n) array
        Soft maps to one target.
    source_areas : list of (N_i,) array
        Their source areas.
    target_areas : (n,) array
        Target vertex areas.
    rank : int
        Columns of the basis.

    Returns
    -------
    (n, rank) array
    """
    if len(maps) == 0 or len(maps) != len(source_areas):
        raise InputError("give one source_areas per map", field="maps")
    a = np.asarray(target_areas, np.float64) / np.sum(target_areas)
    blocks = []
    for P, a0 in zip(maps, source_areas, strict=True):
        a0 = np.asarray(a0, np.float64) / np.sum(a0)
        blocks.append(_weighted(P, a0, a) - np.outer(np.sqrt(a0), np.sqrt(a)))
    stacked = np.concatenate(blocks, axis=0)
    rank = check_int(rank, "rank", low=1, high=min(stacked.shape))
    _, _, Vt = np.linalg.svd(stacked, full_matrices=False)
    basis = np.concatenate([np.sqrt(a)[:, None], Vt[:rank - 1].T], axis=1)
    return basis / np.sqrt(a)[:, None]
