"""Sparse symmetric positive definite factorizations behind one small interface.

``factorize_spd(A)`` factors once; ``factor.solve(B)`` then solves for a vector
or an ``n×k`` block of right-hand sides.  cholespy (CHOLMOD's simplicial Cholesky with
its nested-dissection ordering, shipped as a wheel) is the default backend; scipy's
``splu`` is the fallback when cholespy is unavailable, and can be asked for explicitly to
compare in benchmarks.  ``"pardiso"`` (opt-in; needs the ``mkl`` wheel, the ``pardiso``
extra) is Intel MKL PARDISO's supernodal Cholesky with a METIS ordering, multithreaded
(``MKL_NUM_THREADS``/``OMP_NUM_THREADS``); :data:`HAVE_PARDISO` says whether it loads.
"""

from __future__ import annotations

import atexit
import ctypes
import functools
import glob
import os
import sys
import threading
import weakref
from typing import Literal, Protocol

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

try:  # pragma: no cover - import guard
    from cholespy import CholeskySolverD, MatrixType

    HAVE_CHOLESPY = True
except ImportError:  # pragma: no cover
    HAVE_CHOLESPY = False

Backend = Literal["auto", "cholespy", "splu", "pardiso", "triangular"]


class Factorization(Protocol):
    """A factored matrix ``A`` (n×n); ``solve`` returns ``A⁻¹ B``.

    Attributes
    ----------
    n : int
        Size of ``A``.
    backend : str
        The factorization's backend.
    """

    n: int
    backend: str

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """Solve :math:`A x = b` for each column of ``rhs``.

        Parameters
        ----------
        rhs : (n,) or (n, k) array
            Right-hand side(s).

        Returns
        -------
        (n,) or (n, k) array
        """
        ...


# The factor of a mesh Laplacian-like matrix has a few times the matrix's nonzeros
# (nested-dissection fill); cholespy keeps it in C++, so its size is estimated at this
# fill and 12 bytes per nonzero (value + index).
FACTOR_FILL = 8.0


def estimated_factor_bytes(matrix: sp.spmatrix) -> int:
    """Estimated memory of a sparse Cholesky factor of ``matrix`` (fill ``FACTOR_FILL``).

    Parameters
    ----------
    matrix : (n, n) sparse matrix
        The matrix to factor.

    Returns
    -------
    int
        Bytes.
    """
    return int(FACTOR_FILL * matrix.nnz * 12)


# Every cholespy factor alive; at interpreter exit, before nanobind checks for leaks, the
# ones still held (by a daemon thread's frame, a cache, a cycle) release their solver.
_LIVE_FACTORS: weakref.WeakSet = weakref.WeakSet()


@atexit.register
def _release_factors_at_exit() -> None:
    for factor in list(_LIVE_FACTORS):
        factor._solver = None


class CholespyFactor:
    """Supernodal sparse Cholesky via cholespy (``nbytes``: estimated factor size).

    Parameters
    ----------
    matrix : (n, n) sparse matrix
        Symmetric positive definite.
    """

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
        _LIVE_FACTORS.add(self)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """Two triangular solves by cholespy (holding the GIL).

        Parameters
        ----------
        rhs : (n,) or (n, k) array, as in :meth:`Factorization.solve`
        """
        b = np.ascontiguousarray(rhs, dtype=np.float64)
        x = np.empty_like(b)
        self._solver.solve(b, x)
        return x


class SpluFactor:
    """scipy SuperLU; slower than Cholesky but always available.

    Parameters
    ----------
    matrix : (n, n) sparse matrix
        The matrix (LU with pivoting: SPD is not required).
    """

    backend = "splu"

    def __init__(self, matrix: sp.spmatrix):
        self.n = matrix.shape[0]
        self.nbytes = estimated_factor_bytes(matrix)
        self._lu = spla.splu(sp.csc_matrix(matrix, copy=True))  # splu sums duplicates in place

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """SuperLU's solve, column block at once.

        Parameters
        ----------
        rhs : (n,) or (n, k) array, as in :meth:`Factorization.solve`
        """
        return self._lu.solve(np.asarray(rhs, dtype=np.float64))


MKL_THREADING_SEQUENTIAL = 1  # mkl_service.h: MKL_THREADING_INTEL 0, SEQUENTIAL 1, GNU 3


def _load_mkl_runtime():
    """MKL's single dynamic library (``libmkl_rt``) from the ``mkl`` wheel, or None."""
    names = sorted(glob.glob(os.path.join(sys.prefix, "lib", "libmkl_rt.so*")), key=len)
    names += ["libmkl_rt.so.2", "libmkl_rt.so.3", "libmkl_rt.so"]
    for name in names:
        try:
            lib = ctypes.CDLL(name)
            lib.pardiso  # noqa: B018 - the symbol must exist
        except (OSError, AttributeError):
            continue
        # Sequential MKL, chosen before any other MKL call: with its default (Intel OpenMP)
        # layer PARDISO's bits depended on the process's history (a worker that had started
        # numba's OpenMP pool, e.g. for a colour transfer, gave W1 results differing beyond
        # 1e-12 from a fresh worker's: tests/golden under pytest-xdist found it).
        lib.MKL_Set_Threading_Layer(MKL_THREADING_SEQUENTIAL)
        return lib
    return None


_mkl = None
_mkl_tried = False
_mkl_lock = threading.Lock()


def _pardiso_lib():
    global _mkl, _mkl_tried
    with _mkl_lock:
        if not _mkl_tried:
            _mkl_tried = True
            _mkl = _load_mkl_runtime()
            if _mkl is not None:
                i32 = ctypes.POINTER(ctypes.c_int32)
                _mkl.pardiso.restype = None
                _mkl.pardiso.argtypes = [ctypes.c_void_p, i32, i32, i32, i32, i32,
                                         ctypes.c_void_p, i32, i32, i32, i32, i32, i32,
                                         ctypes.c_void_p, ctypes.c_void_p, i32]
    return _mkl


def have_pardiso() -> bool:
    """Whether MKL PARDISO can be loaded (the ``mkl`` wheel is installed).

    Returns
    -------
    bool
    """
    return _pardiso_lib() is not None


def _pardiso_call(lib, handle, phase: int, n: int, data, indptr, indices, iparm, nrhs: int,
                  b=None, x=None, mtype: int = 2, perm=None) -> int:
    # mtype 2: real symmetric positive definite; -2: real symmetric indefinite; perm: the
    # fill-reducing permutation (int32, n), read or written as iparm[4] says
    i32 = ctypes.c_int32
    err = i32(0)
    one, mtype = i32(1), i32(mtype)  # maxfct = mnum = 1
    lib.pardiso(handle.ctypes.data, ctypes.byref(one), ctypes.byref(one), ctypes.byref(mtype),
                ctypes.byref(i32(phase)), ctypes.byref(i32(n)),
                None if data is None else data.ctypes.data,
                None if indptr is None else indptr.ctypes.data_as(ctypes.POINTER(i32)),
                None if indices is None else indices.ctypes.data_as(ctypes.POINTER(i32)),
                None if perm is None else perm.ctypes.data_as(ctypes.POINTER(i32)),
                ctypes.byref(i32(nrhs)), iparm.ctypes.data_as(ctypes.POINTER(i32)),
                ctypes.byref(i32(0)), None if b is None else b.ctypes.data,
                None if x is None else x.ctypes.data, ctypes.byref(err))
    return int(err.value)


def _pardiso_release(lib, handle, iparm, lock, mtype) -> None:
    with lock:
        _pardiso_call(lib, handle, -1, 0, None, None, None, iparm, 0, mtype=mtype)


PARDISO_ERRORS = {-1: "input inconsistent", -2: "not enough memory", -3: "reordering problem",
                  -4: "zero pivot (the matrix is not positive definite)",
                  -7: "diagonal matrix is singular", -8: "32-bit integer overflow"}


@functools.cache
def _mkl_major_version(lib) -> int:
    """MKL's major version (the release year, e.g. 2026) from ``mkl_get_version``."""
    version = (ctypes.c_int * 16)()  # MKLVersion begins with int MajorVersion
    lib.mkl_get_version(ctypes.byref(version))
    return int(version[0])


# First MKL release whose PARDISO reads iparm[1] as 10 L + K (K the ordering, L the effort
# of the analysis' data-structure and reordering optimizations for phases 2 and 3).
_ANALYSIS_EFFORT_MKL = 2026


class PardisoFactor:
    r"""Supernodal sparse Cholesky by MKL PARDISO (``mtype=2``, METIS nested dissection), or
    with ``pivoting`` its symmetric-indefinite ``L D Lᵀ`` (``mtype=-2``: Bunch–Kaufman
    pivoting inside supernodes, pivots below ``1e-8 ‖A‖`` perturbed, and iterative
    refinement of every solve against the unperturbed matrix).  The latter takes over where
    the Cholesky meets a zero pivot on a symmetric positive (semi)definite matrix whose
    conditioning rounding has spoiled, e.g. interior-point normal equations near the end of
    the central path; ``perturbed`` counts the perturbed pivots of the last factorization.
    ``effort`` (0-10, MKL 2026 and later; 0 elsewhere): how hard the analysis optimizes its
    data structures and ordering for the numeric factorizations and solves that follow
    (``iparm[1] = 10 effort + K``), worth it for a pattern refactored many times.

    The upper triangle is handed over in CSR (0-based, sorted, diagonal stored), copied so
    the caller's arrays are never touched.  ``nbytes``: PARDISO's own report of the
    memory it keeps (symbolic + numeric factor); ``factor_nnz``: nonzeros of ``L``.  Calls
    on one factor are serialized by a lock (a PARDISO handle is not re-entrant); the
    handle's memory is released when the factor is garbage-collected.

    Parameters
    ----------
    matrix : (n, n) sparse matrix
        Symmetric positive (semi)definite.
    ordering : {"metis", "parallel-metis", "amd"} or (n,) int array
        Fill-reducing ordering, or a given permutation.
    pivoting : bool
        Symmetric-indefinite :math:`L D L^\top` with pivoting instead of Cholesky.
    effort : int
        Analysis effort (0-10).
    """

    backend = "pardiso"

    def __init__(self, matrix: sp.spmatrix,
                 ordering: Literal["metis", "parallel-metis", "amd"] | np.ndarray = "metis",
                 pivoting: bool = False, effort: int = 0):
        lib = _pardiso_lib()
        if lib is None:
            raise RuntimeError("PARDISO needs the mkl wheel (pip install mkl)")
        if not 0 <= effort <= 10:
            raise ValueError(f"effort must be in 0..10, got {effort}")
        if _mkl_major_version(lib) < _ANALYSIS_EFFORT_MKL:
            effort = 0  # older PARDISO reads iparm[1] as the ordering alone
        upper = sp.triu(sp.csr_matrix(matrix, dtype=np.float64), format="csr")
        upper.sum_duplicates()  # also sorts the indices
        n = upper.shape[0]
        self.n = n
        rows = np.arange(n)
        first = np.minimum(upper.indptr[:-1], max(upper.nnz - 1, 0))
        if upper.nnz == 0 or np.any((np.diff(upper.indptr) == 0)
                                    | (upper.indices[first] != rows)):
            # every diagonal entry must be stored, even when zero
            upper = (upper + sp.csr_matrix((np.zeros(n), (rows, rows)), shape=(n, n))).tocsr()
            upper.sort_indices()
        self._data = np.ascontiguousarray(upper.data, dtype=np.float64)
        self._indptr = upper.indptr.astype(np.int32)
        self._indices = upper.indices.astype(np.int32)
        self._handle = np.zeros(64, dtype=np.int64)
        iparm = np.zeros(64, dtype=np.int32)
        iparm[0] = 1  # the values below, not the defaults
        if isinstance(ordering, str):
            iparm[1] = {"amd": 0, "metis": 2, "parallel-metis": 3}[ordering] + 10 * effort
            iparm[4] = 2  # return the ordering's permutation in `permutation`
            self.permutation = np.zeros(n, dtype=np.int32)
        else:  # a given fill-reducing permutation (e.g. another factor's `permutation`)
            iparm[1] = 10 * effort + 2 if effort else 0  # K unused with a given ordering
            iparm[4] = 1
            self.permutation = np.array(ordering, dtype=np.int32)
            if self.permutation.shape != (n,):
                raise ValueError(f"ordering must be a ({n},) permutation")
        # pivot perturbation 1e-13 (unused for SPD); 1e-8 for L D Lᵀ (MKL's default there)
        iparm[9] = 8 if pivoting else 13
        # L D Lᵀ: two refinement steps when pivots were perturbed (MKL's default, made
        # explicit); no scaling or weighted matching: the matrix is close to SPD, and both
        # would be frozen at the analysis' values across refactorizations
        iparm[7] = 0
        iparm[17] = -1  # report nnz(L)
        iparm[34] = 1  # 0-based indices
        self.mtype = -2 if pivoting else 2
        self.backend = "pardiso-ldlt" if pivoting else "pardiso"
        self._iparm = iparm
        self._lib = lib
        self._lock = threading.Lock()
        self._finalizer = weakref.finalize(self, _pardiso_release, lib, self._handle, iparm,
                                           self._lock, self.mtype)
        with self._lock:
            for phase in (11, 22):  # analysis (ordering + symbolic), numeric factorization
                err = _pardiso_call(lib, self._handle, phase, n, self._data, self._indptr,
                                    self._indices, iparm, 1, mtype=self.mtype,
                                    perm=self.permutation)
                if err:
                    raise ValueError(f"PARDISO phase {phase} failed ({err}: "
                                     f"{PARDISO_ERRORS.get(err, 'error')})")
        self.factor_nnz = int(iparm[17])
        self.perturbed = int(iparm[13])
        self.nbytes = int(iparm[15] + iparm[16]) * 1024 + self._data.nbytes * 2

    def release(self) -> None:
        """Free PARDISO's memory now (e.g. before a replacement factor is built); the factor
        cannot be used afterwards."""
        self._finalizer()

    def _check_alive(self) -> None:
        if not self._finalizer.alive:
            raise ValueError("this PARDISO factor was released")

    def refactor(self, matrix: sp.spmatrix) -> None:
        """Numeric factorization of a matrix with the same pattern (PARDISO phase 22 only:
        the ordering and symbolic analysis are kept), e.g. the changing weights of an
        interior-point method's normal equations.

        Parameters
        ----------
        matrix : (n, n) sparse matrix
            Same pattern as the analysed matrix.
        """
        upper = sp.triu(sp.csr_matrix(matrix, dtype=np.float64), format="csr")
        upper.sum_duplicates()
        if (upper.nnz != len(self._indices) or not np.array_equal(upper.indptr, self._indptr)
                or not np.array_equal(upper.indices, self._indices)):
            raise ValueError("refactor needs the pattern the factor was analysed with")
        self.refactor_data(upper.data)

    def refactor_data(self, data: np.ndarray) -> None:
        """:meth:`refactor` from the values ``data`` of the analysed upper-triangular CSR
        pattern (``indptr``/``indices`` as handed over), without rebuilding the matrix.

        Parameters
        ----------
        data : (nnz,) array
            Values of the upper-triangular CSR pattern.
        """
        if len(data) != len(self._data):
            raise ValueError("refactor needs the pattern the factor was analysed with")
        self._check_alive()
        with self._lock:
            self._data[:] = data
            err = _pardiso_call(self._lib, self._handle, 22, self.n, self._data, self._indptr,
                                self._indices, self._iparm, 1, mtype=self.mtype,
                                perm=self.permutation)
            self.perturbed = int(self._iparm[13])
        if err:
            raise ValueError(f"PARDISO phase 22 failed ({err}: {PARDISO_ERRORS.get(err, 'error')})")

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A⁻¹ rhs`` for ``(n,)`` or ``(n, k)`` ``rhs``; a block comes back in Fortran
        order (PARDISO works column by column; no copy when ``rhs`` is F-ordered).

        Parameters
        ----------
        rhs : (n,) or (n, k) array
            As in :meth:`Factorization.solve`; iteratively refined with ``pivoting``.
        """
        b = np.asarray(rhs, dtype=np.float64)
        if b.shape[0] != self.n or b.ndim not in (1, 2):
            raise ValueError(f"rhs must be ({self.n},) or ({self.n}, k), got {b.shape}")
        b = np.asfortranarray(b)
        x = np.empty_like(b, order="F")
        nrhs = 1 if b.ndim == 1 else b.shape[1]
        if nrhs == 0:
            return x
        self._check_alive()
        with self._lock:
            iparm = self._iparm.copy()
            err = _pardiso_call(self._lib, self._handle, 33, self.n, self._data, self._indptr,
                                self._indices, iparm, nrhs, b, x, mtype=self.mtype,
                                perm=self.permutation)
        if err:
            raise ValueError(f"PARDISO solve failed ({err}: {PARDISO_ERRORS.get(err, 'error')})")
        return x


class TriangularFactor:
    r"""SuperLU's factorization in symmetric mode (``Pr A Pc = L U``, no pivoting: ``A`` is
    SPD; minimum-degree ordering on :math:`A + A^\top`) with compiled triangular solves
    that release the GIL, so threads solve blocks in parallel (cholespy's solve holds the
    GIL).  ``solve`` takes ``(n,)`` or ``(n, k)``; a C-ordered block is read without a
    copy.  ``factor_nnz``: nonzeros of ``L`` and ``U`` (diagonals counted once).

    Parameters
    ----------
    matrix : (n, n) sparse matrix
        SPD (factored without pivoting).
    """

    backend = "triangular"

    def __init__(self, matrix: sp.spmatrix):
        from solvers._triangular import lu_solve_block

        a = sp.csc_matrix(matrix, dtype=np.float64, copy=True)
        self.n = a.shape[0]
        lu = spla.splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
        lower = sp.tril(lu.L, k=-1, format="csc")
        upper = sp.triu(lu.U, k=1, format="csc")
        diag = lu.U.diagonal()
        if not np.all(diag > 0):
            raise ValueError("matrix is not positive definite")
        self._arrays = (lower.indptr, lower.indices, lower.data, upper.indptr, upper.indices,
                        upper.data, diag, lu.perm_r.astype(np.int64),
                        lu.perm_c.astype(np.int64))
        self._kernel = lu_solve_block
        self.factor_nnz = int(lower.nnz + upper.nnz + self.n)
        self.nbytes = int(sum(x.nbytes for x in self._arrays))

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """Compiled triangular solves that release the GIL.

        Parameters
        ----------
        rhs : (n,) or (n, k) array, as in :meth:`Factorization.solve`
        """
        b = np.asarray(rhs, dtype=np.float64)
        if b.shape[:1] != (self.n,) or b.ndim not in (1, 2):
            raise ValueError(f"rhs must be ({self.n},) or ({self.n}, k), got {b.shape}")
        block = np.ascontiguousarray(b.reshape(self.n, -1))
        x = np.empty_like(block)
        self._kernel(*self._arrays, block, x)
        return x.reshape(b.shape)


def eigsh(matrix, k: int, **kwargs):
    """:func:`scipy.sparse.linalg.eigsh` started from a fixed vector (``v0``, unless given).

    Without ``v0``, scipy (1.15 and later) starts ARPACK from a fresh, unseeded random vector:
    the same matrix then gives eigenvectors differing in their last bits from call to call,
    and any basis of a repeated eigenvalue, so a result built on them (spectral W1 bases,
    WKS descriptors, ZoomOut) would differ between two runs of one request.

    Parameters
    ----------
    matrix : (n, n) sparse matrix or operator
        Symmetric.
    k : int
        Number of eigenpairs.
    **kwargs
        Keywords of :func:`scipy.sparse.linalg.eigsh`.

    Returns
    -------
    eigenvalues : (k,) array
    eigenvectors : (n, k) array
    """
    if kwargs.get("v0") is None:
        kwargs["v0"] = np.random.default_rng(0).uniform(-1.0, 1.0, matrix.shape[0])
    return spla.eigsh(matrix, k=k, **kwargs)


def factorize_spd(matrix: sp.spmatrix, backend: Backend = "auto", *,
                  pardiso_effort: int = 0) -> Factorization:
    """Factor a sparse symmetric positive definite ``matrix`` for repeated solves.

    Parameters
    ----------
    matrix : (n, n) sparse SPD matrix.
    backend : ``"auto"`` (cholespy if installed, else splu), ``"cholespy"``, ``"splu"`` or
        ``"pardiso"`` (MKL PARDISO; never chosen by ``"auto"``).
    pardiso_effort : PARDISO's analysis effort (:class:`PardisoFactor`'s ``effort``), for a
        pattern refactored many times; ignored by the other backends.

    Returns
    -------
    Factorization
        ``solve(rhs)`` returns :math:`A^{-1}` ``rhs``.
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
    if backend == "pardiso":
        return PardisoFactor(matrix, effort=pardiso_effort)
    if backend == "triangular":
        return TriangularFactor(matrix)
    raise ValueError(f"unknown backend {backend!r}")
