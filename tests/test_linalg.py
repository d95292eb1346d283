"""Sparse SPD factorizations: cholespy and scipy splu agree, on vectors and blocks."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from solvers.linalg import HAVE_CHOLESPY, factorize_spd, have_pardiso

REPO = Path(__file__).resolve().parents[1]


def _random_spd(n: int, seed: int) -> sp.csc_matrix:
    rng = np.random.default_rng(seed)
    b = sp.random(n, n, density=4.0 / n, random_state=seed)
    w = abs(b + b.T)
    lap = sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w  # graph Laplacian, PSD
    return (lap + sp.diags(rng.random(n) + 0.01)).tocsc()


def test_cholespy_is_installed():
    assert HAVE_CHOLESPY  # a pyproject dependency; "auto" must not silently fall back
    assert factorize_spd(_random_spd(10, 0)).backend == "cholespy"


@pytest.mark.parametrize("shape", [(300,), (300, 1), (300, 7)])
def test_backends_agree_and_solve(shape):
    a = _random_spd(300, 1)
    rhs = np.random.default_rng(2).normal(size=shape)
    chol = factorize_spd(a, backend="cholespy")
    lu = factorize_spd(a, backend="splu")
    tri = factorize_spd(a, backend="triangular")
    x_chol, x_lu, x_tri = chol.solve(rhs), lu.solve(rhs), tri.solve(rhs)
    assert x_chol.shape == x_lu.shape == x_tri.shape == rhs.shape
    np.testing.assert_allclose(a @ x_chol, rhs, atol=1e-10 * np.abs(rhs).max())
    np.testing.assert_allclose(x_chol, x_lu, rtol=1e-9, atol=1e-12 * np.abs(x_lu).max())
    np.testing.assert_allclose(x_tri, x_lu, rtol=1e-9, atol=1e-12 * np.abs(x_lu).max())
    assert chol.n == lu.n == tri.n == 300


def test_non_contiguous_and_integer_right_hand_sides():
    a = _random_spd(50, 3)
    f = factorize_spd(a)
    block = np.asfortranarray(np.random.default_rng(4).normal(size=(50, 6)))[:, ::2]
    np.testing.assert_allclose(a @ f.solve(block), block, atol=1e-10)
    ones = np.ones(50, dtype=np.int64)
    np.testing.assert_allclose(a @ f.solve(ones), ones, atol=1e-10)


def test_triangular_backend_in_threads_and_refuses_indefinite():
    """The compiled solves (GIL released) give the same blocks from concurrent threads, on
    non-contiguous input; an indefinite matrix is refused at factorization."""
    from concurrent.futures import ThreadPoolExecutor

    a = _random_spd(400, 6)
    f = factorize_spd(a, backend="triangular")
    blocks = [np.asfortranarray(np.random.default_rng(s).normal(size=(400, 32)))[:, ::2]
              for s in range(8)]
    with ThreadPoolExecutor(2) as pool:
        solved = list(pool.map(f.solve, blocks))
    for b, x in zip(blocks, solved, strict=True):
        np.testing.assert_allclose(a @ x, b, atol=1e-10 * np.abs(b).max())
        np.testing.assert_array_equal(x, f.solve(b))
    with pytest.raises(ValueError, match="positive definite"):
        factorize_spd(sp.diags([1.0, -1.0, 2.0]).tocsc(), backend="triangular")


def test_input_matrix_is_not_modified():
    # Unsorted indices and a duplicate entry: cholespy's CSC path would sort the
    # caller's arrays in place and realloc() them; the CSR path copies.
    a = sp.csc_matrix((np.array([1.0, 4.0, 1.0, 3.0, 1.0]),
                       np.array([1, 0, 0, 1, 1]), np.array([0, 2, 5])), shape=(2, 2))
    before = (a.indptr.copy(), a.indices.copy(), a.data.copy())
    for backend in ("cholespy", "splu", "triangular"):
        x = factorize_spd(a, backend=backend).solve(np.array([1.0, 2.0]))
        np.testing.assert_allclose(a.toarray() @ x, [1.0, 2.0])
    for arr, ref in zip((a.indptr, a.indices, a.data), before, strict=True):
        np.testing.assert_array_equal(arr, ref)


def test_no_heap_corruption_after_factorization():
    """Regression: with MatrixType.CSC, cholespy realloc()ed numpy's buffers; the
    process then died with "free(): invalid next size" / "invalid pointer" (or hung in a
    later import).  This script crashed 3 times out of 3 before the fix."""
    script = textwrap.dedent("""
        import numpy as np, scipy.sparse as sp
        from solvers.kernels import ImplicitEulerHeatKernel
        lap = sp.csr_matrix(np.array([[1, -1, 0, 0, 0], [-1, 2, -1, 0, 0], [0, -1, 1, 0, 0],
                                      [0, 0, 0, 1, -1], [0, 0, 0, -1, 1.0]]))
        kernel = ImplicitEulerHeatKernel(np.ones(5), lap, 1.0)
        kernel.apply(np.eye(5))
        junk = [np.zeros(i % 50 + 1) for i in range(20000)]  # reuse the small-block heap
        del junk, kernel
        print("done")
    """)
    proc = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "done"


def test_invalid_arguments():
    with pytest.raises(ValueError, match="square"):
        factorize_spd(sp.csc_matrix(np.ones((2, 3))))
    with pytest.raises(ValueError, match="backend"):
        factorize_spd(sp.identity(3, format="csc"), backend="magic")


@pytest.mark.skipif(not have_pardiso(), reason="the mkl wheel (pardiso extra) is not installed")
def test_pardiso_backend_solves_and_refuses_indefinite():
    a = _random_spd(400, 5)
    before = (a.indptr.copy(), a.indices.copy(), a.data.copy())
    f = factorize_spd(a, backend="pardiso")
    assert f.backend == "pardiso" and f.n == 400 and f.factor_nnz >= 400 and f.nbytes > 0
    rng = np.random.default_rng(6)
    for rhs in (rng.normal(size=400), rng.normal(size=(400, 9)),
                np.asfortranarray(rng.normal(size=(400, 12)))[:, ::3]):
        x = f.solve(rhs)
        assert x.shape == rhs.shape
        np.testing.assert_allclose(a @ x, rhs, atol=1e-10 * np.abs(rhs).max())
    for arr, ref in zip((a.indptr, a.indices, a.data), before, strict=True):
        np.testing.assert_array_equal(arr, ref)
    with pytest.raises(ValueError, match="positive definite"):
        factorize_spd(sp.csr_matrix(np.array([[1.0, 2.0], [2.0, 1.0]])), backend="pardiso")
    assert factorize_spd(a).backend == "cholespy"  # "auto" is unchanged for other callers


@pytest.mark.skipif(not have_pardiso(), reason="the mkl wheel (pardiso extra) is not installed")
def test_pardiso_refactor_keeps_the_analysis_and_refuses_a_new_pattern():
    a = _random_spd(300, 7)
    f = factorize_spd(a, backend="pardiso")
    b = (a + sp.diags(np.linspace(1.0, 5.0, 300))).tocsr()  # same pattern, new values
    f.refactor(b)
    rhs = np.random.default_rng(1).normal(size=300)
    np.testing.assert_allclose(b @ f.solve(rhs), rhs, atol=1e-10 * np.abs(rhs).max())
    with pytest.raises(ValueError, match="pattern"):
        f.refactor(sp.identity(300, format="csr"))


@pytest.mark.skipif(not have_pardiso(), reason="the mkl wheel (pardiso extra) is not installed")
def test_pardiso_ldlt_takes_over_where_cholesky_meets_a_zero_pivot():
    """``pivoting=True`` (symmetric-indefinite L D Lᵀ) factors what the Cholesky refuses,
    solves it to rounding, and refactors in place with the kept analysis."""
    from scipy.sparse.linalg import eigsh

    from solvers.linalg import PardisoFactor

    a = _random_spd(300, 7).tocsr()
    shift = float(eigsh(a, k=1, sigma=0, which="LM", return_eigenvectors=False)[0])
    indefinite = (a - sp.identity(300) * 1.5 * shift).tocsr()  # a negative eigenvalue
    with pytest.raises(ValueError, match="positive definite"):
        PardisoFactor(indefinite)
    f = PardisoFactor(indefinite, pivoting=True)
    assert f.backend == "pardiso-ldlt" and f.mtype == -2
    rng = np.random.default_rng(8)
    rhs = rng.normal(size=(300, 3))
    np.testing.assert_allclose(indefinite @ f.solve(rhs), rhs, atol=1e-9 * np.abs(rhs).max())
    f.refactor(a)  # same pattern, now SPD
    x = f.solve(rhs[:, 0])
    np.testing.assert_allclose(a @ x, rhs[:, 0], atol=1e-10 * np.abs(rhs).max())
    f.release()  # memory freed now; the factor refuses further use
    with pytest.raises(ValueError, match="released"):
        f.solve(rhs[:, 0])


@pytest.mark.skipif(not have_pardiso(), reason="the mkl wheel (pardiso extra) is not installed")
def test_pardiso_reuses_a_given_ordering_and_refactors_from_data():
    """A factor reports its fill-reducing permutation; another factor of the same pattern
    given it (here the L D Lᵀ) skips the ordering and factors the same way (same factor
    size, same solves to rounding); ``refactor_data`` takes new values on the analysed
    upper-triangular pattern and refuses values of another length."""
    from solvers.linalg import PardisoFactor

    a = _random_spd(300, 9).tocsr()
    cholesky = PardisoFactor(a)
    perm = cholesky.permutation
    assert np.array_equal(np.sort(perm), np.arange(300))
    own = PardisoFactor(a, pivoting=True)
    given = PardisoFactor(a, ordering=perm, pivoting=True)
    assert np.array_equal(own.permutation, perm) and given.factor_nnz == own.factor_nnz
    rhs = np.random.default_rng(10).normal(size=300)
    np.testing.assert_allclose(given.solve(rhs), own.solve(rhs), rtol=0, atol=1e-12)
    b = (a + sp.identity(300)).tocsr()
    upper = sp.triu(b, format="csr")
    cholesky.refactor_data(upper.data)
    np.testing.assert_allclose(b @ cholesky.solve(rhs), rhs, atol=1e-10 * np.abs(rhs).max())
    with pytest.raises(ValueError, match="pattern"):
        cholesky.refactor_data(upper.data[:-1])
    with pytest.raises(ValueError, match="permutation"):
        PardisoFactor(a, ordering=perm[:-1])


@pytest.mark.skipif(not have_pardiso(), reason="the mkl wheel (pardiso extra) is not installed")
@pytest.mark.parametrize("pivoting", [False, True])
def test_pardiso_analysis_effort_solves_the_same_system(pivoting):
    """``effort`` changes how PARDISO's analysis lays out the factor (MKL 2026 on: ``iparm[1]
    = 10 effort + 2``), not what it solves: the Cholesky (or, with a given ordering, the
    L D Lᵀ) solves and refactors to rounding; efforts outside 0..10 are refused."""
    from solvers import linalg
    from solvers.linalg import PardisoFactor

    a = _random_spd(300, 11).tocsr()
    ordering = PardisoFactor(a).permutation if pivoting else "metis"
    f = PardisoFactor(a, ordering=ordering, pivoting=pivoting, effort=1)
    if linalg._mkl_major_version(linalg._pardiso_lib()) >= linalg._ANALYSIS_EFFORT_MKL:
        assert f._iparm[1] == 12
    rhs = np.random.default_rng(12).normal(size=(300, 2))
    np.testing.assert_allclose(a @ f.solve(rhs), rhs, atol=1e-10 * np.abs(rhs).max())
    b = (a + sp.identity(300)).tocsr()
    f.refactor(b)
    np.testing.assert_allclose(b @ f.solve(rhs), rhs, atol=1e-10 * np.abs(rhs).max())
    with pytest.raises(ValueError, match="effort"):
        PardisoFactor(a, effort=11)


@pytest.mark.skipif(not have_pardiso(), reason="the mkl wheel (pardiso extra) is not installed")
def test_factorize_spd_passes_the_pardiso_effort():
    """``factorize_spd(..., pardiso_effort=e)`` is PARDISO's factor with that analysis effort
    (MKL 2026 on), and the other backends ignore it."""
    from solvers import linalg

    a = _random_spd(200, 5).tocsr()
    f = linalg.factorize_spd(a, "pardiso", pardiso_effort=1)
    plain = linalg.factorize_spd(a, "pardiso")
    if linalg._mkl_major_version(linalg._pardiso_lib()) >= linalg._ANALYSIS_EFFORT_MKL:
        assert (f._iparm[1], plain._iparm[1]) == (12, 2)
    rhs = np.random.default_rng(6).normal(size=200)
    np.testing.assert_allclose(a @ f.solve(rhs), rhs, atol=1e-10 * np.abs(rhs).max())
    np.testing.assert_allclose(linalg.factorize_spd(a, "splu", pardiso_effort=1).solve(rhs),
                               f.solve(rhs), rtol=1e-9)


def test_eigenpairs_are_the_same_bits_on_every_call():
    """The spectral bases start ARPACK from a fixed vector: two fresh meshes (no shared cache)
    give the same bits, so a request's result does not vary from run to run."""
    import trimesh

    from solvers import TriangleMesh
    from solvers.emd.operators import EMDOperators
    from solvers.softmaps.descriptors import eigenpairs

    def fresh():
        s = trimesh.creation.icosphere(subdivisions=2)
        return TriangleMesh(s.vertices * [1.3, 1.0, 0.8], s.faces)

    first, second = eigenpairs(fresh(), 12), eigenpairs(fresh(), 12)
    assert all(np.array_equal(a, b) for a, b in zip(first, second, strict=True))
    first, second = (EMDOperators(fresh()).stream_eigenbasis(8) for _ in range(2))
    assert all(np.array_equal(a, b) for a, b in zip(first, second, strict=True))


def test_pardiso_runs_sequential_mkl_whatever_ran_before():
    """PARDISO's bits must not depend on the process's history: in a process that started
    numba's OpenMP pool first (as a colour transfer does), MKL still runs sequentially."""
    if not have_pardiso():  # the mkl wheel is a dev dependency: present wherever tests run
        raise AssertionError("MKL PARDISO did not load")
    script = (
        "import numba, numpy as np\n"
        "@numba.njit(parallel=True)\n"
        "def total(x):\n"
        "    s = 0.0\n"
        "    for i in numba.prange(x.size):\n"
        "        s += x[i]\n"
        "    return s\n"
        "total(np.ones(4096))\n"
        "from solvers.linalg import _pardiso_lib\n"
        "print(_pardiso_lib().MKL_Get_Max_Threads())\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True, env={**os.environ, "MKL_NUM_THREADS": "2"})
    assert out.stdout.strip() == "1", out.stdout + out.stderr
