"""Sparse symmetric positive definite factorizations behind one small interface.

``factorize_spd(A)`` factors once; ``factor.solve(B)`` then solves for a vector
or an ``n×k`` block of right-hand sides.  cholespy (a CHOLMOD-based supernodal
Cholesky shipped as a wheel) is the default backend; scipy's ``splu`` is the
fallback when cholespy is unavailable, and can be asked for explicitly to
compare in benchmarks.
"""

from __future__ import annotations

from typing import Literal, Protocol

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

try:  # pragma: no cover - import guard
    from cholespy import CholeskySolverD, MatrixType

    HAVE_CHOLESPY = True
except ImportError:  # pragma: no cover
    HAVE_CHOLESPY = False

Backend = Literal["auto", "cholespy", "splu"]


class Factorization(Protocol):
    """A factored matrix ``A`` (n×n); ``solve`` returns ``A⁻¹ B``."""

    n: int
    backend: str

    def solve(self, rhs: np.ndarray) -> np.ndarray: ...


# The factor of a mesh Laplacian-like matrix has a few times the matrix's nonzeros
# (nested-dissection fill); cholespy keeps it in C++, so its size is estimated at this
# fill and 12 bytes per nonzero (value + index).
FACTOR_FILL = 8.0


def estimated_factor_bytes(matrix: sp.spmatrix) -> int:
    return int(FACTOR_FILL * matrix.nnz * 12)


class CholespyFactor:
    """Supernodal sparse Cholesky via cholespy (``nbytes``: estimated factor size)."""

    backend = "cholespy"

    def __init__(self, matrix: sp.spmatrix):
        # Pass CSR, never CSC: for CSC input cholespy (<= 2.2) sorts the caller's
        # arrays in place and then realloc()s numpy-owned buffers (heap corruption:
        # "free(): invalid pointer" or hangs later); CSR/COO input is first copied
        # into buffers cholespy owns.  The arrays below are read only.
        csr = sp.csr_matrix(matrix)
        self.n = csr.shape[0]
        self.nbytes = estimated_factor_bytes(csr)
        self._solver = CholeskySolverD(
            self.n,
            np.array(csr.indptr, dtype=np.int32),
            np.array(csr.indices, dtype=np.int32),
            np.array(csr.data, dtype=np.float64),
            MatrixType.CSR,
        )

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        b = np.ascontiguousarray(rhs, dtype=np.float64)
        x = np.empty_like(b)
        self._solver.solve(b, x)
        return x


class SpluFactor:
    """scipy SuperLU; slower than Cholesky but always available."""

    backend = "splu"

    def __init__(self, matrix: sp.spmatrix):
        self.n = matrix.shape[0]
        self.nbytes = estimated_factor_bytes(matrix)
        self._lu = spla.splu(sp.csc_matrix(matrix, copy=True))  # splu sums duplicates in place

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._lu.solve(np.asarray(rhs, dtype=np.float64))


def factorize_spd(matrix: sp.spmatrix, backend: Backend = "auto") -> Factorization:
    """Factor a sparse symmetric positive definite ``matrix`` for repeated solves.

    Parameters
    ----------
    matrix : (n, n) sparse SPD matrix.
    backend : ``"auto"`` (cholespy if installed, else splu), ``"cholespy"`` or ``"splu"``.
    """
    if matrix.shape[0] != matrix.shape[1]:
        raise ValueError(f"matrix must be square, got shape {matrix.shape}")
    if backend == "auto":
        backend = "cholespy" if HAVE_CHOLESPY else "splu"
    if backend == "cholespy":
        if not HAVE_CHOLESPY:
            raise RuntimeError("cholespy is not installed")
        return CholespyFactor(matrix)
    if backend == "splu":
        return SpluFactor(matrix)
    raise ValueError(f"unknown backend {backend!r}")
