"""Ch. 5 propagation of histograms on Prob(R): Fig. 5.1, Props. 13-16, Fig. 5.3-5.4."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import Delaunay

from solvers import Graph, TriangleMesh
from solvers.errors import InputError
from solvers.histograms import (
    cdf_from_inverse_cdf,
    diffuse_histograms,
    harmonic_means,
    histograms_from_inverse_cdf,
    inverse_cdf_from_density,
    inverse_cdf_from_histograms,
    inverse_cdf_from_samples,
    knn_graph,
    make_bins,
    propagate_histograms,
    quantile_levels,
)
from solvers.histograms import dirichlet as dirichlet_module
from solvers.histograms import summaries as S
from solvers.histograms.dirichlet import dirichlet_system, harmonic_extension
from solvers.histograms.quantiles import sort_rows
from solvers.linalg import have_pardiso


def gauss(bins, mu, sigma):
    h = np.exp(-0.5 * ((bins.centers - mu) / sigma) ** 2)
    return h / h.sum()


def path(n):
    return Graph(n, np.c_[np.arange(n - 1), np.arange(1, n)])


def qmoments(q):
    m = q.mean(axis=1)
    return m, np.sqrt(np.maximum((q**2).mean(axis=1) - m**2, 0.0))


def random_graph(rng, n, p):
    while True:
        a = np.triu(rng.random((n, n)) < p, 1)
        e = np.argwhere(a)
        g = Graph(n, e, rng.uniform(0.2, 2.0, len(e)))
        if g.n_components == 1:
            return g


# -- quantiles ------------------------------------------------------------------
def test_inverse_cdf_of_uniform_histogram_is_linear_and_round_trips():
    b = make_bins(lo=-1.0, hi=3.0, count=8)
    lev = quantile_levels(64)
    q = inverse_cdf_from_histograms(np.ones(8), b, lev)
    assert np.allclose(q[0], -1.0 + 4.0 * lev)
    back = histograms_from_inverse_cdf(q, lev, b)
    assert np.allclose(back, 1 / 8, atol=1e-12)
    # histogram with empty bins: the inverse CDF skips them; the CDF is exact at edges
    h = np.array([[0.5, 0, 0, 0.5, 0, 0, 0, 0]])
    q = inverse_cdf_from_histograms(h, b, lev)
    assert np.all((q < 0.0) | ((q >= 0.5) & (q <= 1.0)))
    F = cdf_from_inverse_cdf(q, lev, b.edges)
    assert np.allclose(F[0, [0, 1, 3, 4, 8]], [0, 0.5, 0.5, 1.0, 1.0], atol=1 / 64)


def test_samples_and_piecewise_linear_density():
    lev = quantile_levels(10)
    q = inverse_cdf_from_samples([3.0, 1.0, 2.0, 4.0], lev)
    assert np.allclose(q, np.repeat([1.0, 2.0, 3.0, 4.0], [3, 2, 3, 2]))
    # triangle density on [0, 1] rising: F(x) = x^2, F^-1(s) = sqrt(s)
    q = inverse_cdf_from_density([0.0, 1.0], [0.0, 2.0], lev)
    assert np.allclose(q, np.sqrt(lev), atol=1e-12)


# -- Fig. 5.1 ---------------------------------------------------------------------
def test_path_graph_peak_slides_linearly_pdf_is_bimodal():
    n = 21
    b = make_bins(lo=0.0, hi=1.0, count=100)
    labels = np.stack([gauss(b, 0.2, 0.03), gauss(b, 0.8, 0.03)])
    res = propagate_histograms(path(n), [0, n - 1], labels, bins=b, levels=200)
    assert res.residual < 1e-10 and res.converged
    m, s = qmoments(res.quantiles)
    assert np.allclose(m, np.linspace(m[0], m[-1], n), atol=1e-12)  # slides linearly
    assert np.allclose(s, s[0], atol=1e-12)  # no added variance
    hm = S.mean(res.histograms, b)
    assert np.allclose(hm, np.linspace(0.2, 0.8, n), atol=2e-3)
    assert np.all(S.std(res.histograms, b) < 0.035)
    mid = res.histograms[n // 2]
    assert b.centers[np.argmax(mid)] == pytest.approx(0.5, abs=0.011)
    pdf = propagate_histograms(path(n), [0, n - 1], labels, bins=b, method="pdf")
    pm = pdf.histograms[n // 2]
    assert np.allclose(pm, 0.5 * labels[0] + 0.5 * labels[1], atol=1e-12)  # a mixture
    near = np.abs(b.centers - 0.5) < 0.05
    assert pm[near].sum() < 1e-6 and S.std(pdf.histograms, b)[n // 2] > 0.25  # bimodal


# -- Props. 14 and 15 ---------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_prop14_random_graphs_means_harmonic_sigma_bounded(seed):
    rng = np.random.default_rng(seed)
    n = 60
    g = random_graph(rng, n, 0.08)
    b = make_bins(lo=0.0, hi=10.0, count=80)
    labeled = rng.choice(n, 8, replace=False)
    hist = rng.random((8, 80)) ** 4 * (rng.random((8, 80)) < 0.3)
    hist[:, 40] += 1e-3
    res = propagate_histograms(g, labeled, hist, bins=b, levels=128)
    m, s = qmoments(res.quantiles)
    lm, ls = m[labeled], s[labeled]
    assert np.allclose(m, harmonic_means(g, labeled, lm), atol=1e-10)
    assert np.all(m >= lm.min() - 1e-12) and np.all(m <= lm.max() + 1e-12)
    assert np.all(s <= ls.max() + 1e-10)
    # the same statements on the returned histograms, up to the level discretization
    hmean, hstd = S.mean(res.histograms, b), S.std(res.histograms, b)
    assert np.allclose(hmean, harmonic_means(g, labeled, hmean[labeled]), atol=0.05)
    assert np.all(hstd <= hstd[labeled].max() + 0.05)
    assert np.allclose(res.histograms.sum(axis=1), 1.0)


def test_prop15_dirac_labels_give_classical_harmonic_interpolation():
    rng = np.random.default_rng(3)
    g = random_graph(rng, 80, 0.06)
    labeled = rng.choice(80, 10, replace=False)
    x = rng.uniform(-5, 5, 10)
    res = propagate_histograms(g, labeled, samples=[[v] for v in x], levels=50)
    expected = harmonic_means(g, labeled, x)
    assert np.abs(res.quantiles - expected[:, None]).max() < 1e-12
    # the same harmonic interpolation computed independently (dense solve)
    L = g.laplacian.toarray()
    free = np.setdiff1d(np.arange(80), labeled)
    xf = np.linalg.solve(L[np.ix_(free, free)], -L[np.ix_(free, labeled)] @ x)
    assert np.allclose(res.quantiles[free, 0], xf, atol=1e-10)


def test_amg_solver_matches_direct():
    rng = np.random.default_rng(4)
    g = random_graph(rng, 200, 0.03)
    b = make_bins(lo=0, hi=1, count=20)
    lab = rng.choice(200, 10, replace=False)
    h = rng.random((10, 20))
    d = propagate_histograms(g, lab, h, bins=b, linear_method="direct")
    a = propagate_histograms(g, lab, h, bins=b, linear_method="amg", tol=1e-12)
    assert a.linear_method == "amg" and a.iterations > 1
    assert np.abs(a.quantiles - d.quantiles).max() < 1e-8



@pytest.mark.skipif(not have_pardiso(), reason="the mkl wheel (pardiso extra) is not installed")
def test_pardiso_and_cholespy_direct_routes_agree(monkeypatch):
    # many columns in several blocks (the block width is forced down to 7 columns), on
    # Fortran-ordered right-hand sides for PARDISO and C-ordered ones for cholespy
    monkeypatch.setattr(dirichlet_module, "_block_columns", lambda r, n: 7)
    rng = np.random.default_rng(8)
    g = random_graph(rng, 300, 0.02)
    lab = np.sort(rng.choice(300, 40, replace=False))
    values = np.sort(rng.random((40, 30)), axis=1)
    runs = {}
    for name in ("pardiso", "cholespy"):
        system = dirichlet_system(g, lab, factorization=name)
        assert system.factor.backend == name
        runs[name] = harmonic_extension(system, values)
        assert runs[name].rank == 30 and runs[name].residual < 1e-12
    np.testing.assert_allclose(runs["pardiso"].values, runs["cholespy"].values, atol=1e-11)
    assert dirichlet_system(g, lab).factor.backend == "pardiso"  # "auto" picks it


def test_back_conversion_matches_the_cdf_at_the_edges():
    # the compiled merge pass against the vectorized CDF reader, with values beyond the
    # edges, plateaus (atoms) and values exactly on edges
    rng = np.random.default_rng(9)
    b = make_bins(edges=np.r_[0.0, np.sort(rng.uniform(0.05, 0.95, 10)), 1.0])
    lev = quantile_levels(40)
    q = np.sort(rng.uniform(-0.1, 1.1, (60, 40)), axis=1)
    q[:5, 10:20] = b.edges[3]
    q[5:10] = b.edges[rng.integers(0, 12, (5, 40))]
    q.sort(axis=1)
    h = histograms_from_inverse_cdf(q, lev, b, sorted_rows=True)
    F = cdf_from_inverse_cdf(q, lev, b.edges)
    F[:, 0], F[:, -1] = 0.0, 1.0
    np.testing.assert_allclose(h, np.clip(np.diff(F, axis=1), 0, None), atol=1e-14)
    np.testing.assert_allclose(histograms_from_inverse_cdf(q[:, ::-1], lev, b), h, atol=1e-14)
    shuffled = q[:, rng.permutation(40)]
    np.testing.assert_array_equal(sort_rows(shuffled.copy()), q)

# -- Fig. 5.3: disk with multimodal boundary labels ---------------------------------------
def disk_mesh(rings=12):
    pts = [[0.0, 0.0]]
    for r in range(1, rings + 1):
        k = 6 * r
        th = 2 * np.pi * np.arange(k) / k
        pts += list(np.c_[r / rings * np.cos(th), r / rings * np.sin(th)])
    p = np.asarray(pts)
    tri = Delaunay(p).simplices
    mesh = TriangleMesh(np.c_[p, np.zeros(len(p))], tri)
    boundary = np.flatnonzero(np.isclose(np.linalg.norm(p, axis=1), 1.0))
    return mesh, p, boundary


def test_disk_mesh_multimodal_boundary_wasserstein_keeps_spread():
    mesh, p, boundary = disk_mesh()
    b = make_bins(lo=0.0, hi=1.0, count=60)
    th = np.arctan2(p[boundary, 1], p[boundary, 0])
    labels = np.stack([0.5 * gauss(b, 0.3 + 0.1 * np.cos(t), 0.04)
                       + 0.5 * gauss(b, 0.7 + 0.1 * np.sin(t), 0.04) for t in th])
    interior = np.setdiff1d(np.arange(mesh.n), boundary)
    for lap in ("robust", "cotan"):
        w = propagate_histograms(mesh, boundary, labels, bins=b, laplacian=lap)
        pdf = propagate_histograms(mesh, boundary, labels, bins=b, method="pdf", laplacian=lap)
        _, s = qmoments(w.quantiles)
        assert np.all(s[interior] <= s[boundary].max() + 1e-10)  # Prop. 14 on a mesh
        hw, hp = S.entropy(w.histograms, b), S.entropy(pdf.histograms, b)
        # PDF propagation mixes the shifting modes (flatter); Wasserstein keeps them sharp
        assert hp[interior].mean() > hw[interior].mean() + 0.2
        # both routes agree on the means (both harmonic in the labeled means)
        assert np.allclose(S.mean(w.histograms, b), S.mean(pdf.histograms, b), atol=0.01)
        # Wasserstein histograms stay bimodal in the interior: the mass near 0.5 stays low
        centre = w.histograms[0]
        assert centre[np.abs(b.centers - 0.5) < 0.05].sum() < 0.05


# -- Fig. 5.4: diffusion on a circle graph ---------------------------------------------------
def test_diffusion_on_circle_graph_keeps_spread_pdf_flattens():
    n = 64
    g = Graph(n, np.c_[np.arange(n), (np.arange(n) + 1) % n])
    b = make_bins(lo=0.0, hi=1.0, count=100)
    rng = np.random.default_rng(5)
    mus = 0.5 + 0.25 * np.sin(2 * np.pi * np.arange(n) / n) + rng.normal(0, 0.05, n)
    h0 = np.stack([gauss(b, m, 0.03) for m in mus])
    times = [0.0, 2.0, 20.0]
    w = diffuse_histograms(g, h0, times, bins=b)
    pdf = diffuse_histograms(g, h0, times, bins=b, method="pdf")
    s0 = S.std(h0, b)
    sw = S.std(w.histograms[-1], b)
    sp_ = S.std(pdf.histograms[-1], b)
    assert np.allclose(w.histograms[0], h0, atol=0.01)
    assert np.all(np.abs(sw - s0.mean()) < 0.15 * s0.mean())  # spread kept
    assert sp_.mean() > 2.0 * s0.mean()  # PDF diffusion flattens
    # means diffuse identically in both routes (heat equation on the means)
    assert np.allclose(S.mean(w.histograms[-1], b), S.mean(pdf.histograms[-1], b), atol=5e-3)
    # noise is smoothed: neighbouring means get closer
    dm0 = np.abs(np.diff(S.mean(h0, b))).mean()
    dm = np.abs(np.diff(S.mean(w.histograms[-1], b))).mean()
    assert dm < 0.5 * dm0
    assert w.residual < 1e-8


# -- graph sources ---------------------------------------------------------------------
def test_weight_matrix_and_knn_graph():
    rng = np.random.default_rng(6)
    pts = rng.random((300, 2))
    g = knn_graph(pts, 6, weights="gaussian")
    assert g.n_components == 1 and np.all(g.weights > 0)
    b = make_bins(lo=0, hi=1, count=10)
    lab = np.argsort(pts[:, 0])[[0, -1]]
    h = np.stack([gauss(b, 0.1, 0.05), gauss(b, 0.9, 0.05)])
    r1 = propagate_histograms(g, lab, h, bins=b)
    r2 = propagate_histograms(g.adjacency, lab, h, bins=b)  # a sparse weight matrix
    assert np.allclose(r1.quantiles, r2.quantiles, atol=1e-12)
    m = S.mean(r1.histograms, b)
    assert np.corrcoef(m, pts[:, 0])[0, 1] > 0.8  # means follow x


# -- validation ---------------------------------------------------------------------------
def test_validation_names_the_problem():
    b = make_bins(lo=0, hi=1, count=4)
    g = Graph(6, [[0, 1], [1, 2], [3, 4], [4, 5]])
    h = np.ones((1, 4))
    with pytest.raises(InputError, match="component 1") as exc:
        propagate_histograms(g, [0], h, bins=b)
    assert exc.value.field == "labeled"
    with pytest.raises(InputError) as exc:
        propagate_histograms(g, [0, 3], [[1, -1, 0, 0], [1, 1, 1, 1]], bins=b)
    assert exc.value.field == "histograms[0]"
    with pytest.raises(InputError) as exc:
        propagate_histograms(g, [0, 3], [[0, 0, 0, 0], [1, 1, 1, 1]], bins=b)
    assert exc.value.field == "histograms[0]"
    with pytest.raises(InputError) as exc:
        propagate_histograms(g, [0, 3], [[np.nan, 0, 0, 1], [1, 1, 1, 1]], bins=b)
    assert exc.value.field == "histograms[0]"
    with pytest.raises(InputError) as exc:
        make_bins([0, 1, 1, 2])
    assert exc.value.field == "bins.edges"
    with pytest.raises(InputError) as exc:
        make_bins(lo=1, hi=0, count=3)
    assert exc.value.field == "bins.hi"
    with pytest.raises(InputError) as exc:
        propagate_histograms(g, [0, 3, 3], np.ones((3, 4)), bins=b)
    assert exc.value.field == "labeled"
    with pytest.raises(InputError) as exc:
        propagate_histograms(g, [0, 3], np.ones((3, 4)), bins=b)
    assert exc.value.field == "histograms"
    with pytest.raises(InputError) as exc:
        propagate_histograms(g, [0, 3], samples=[[0.5], [2.0]], bins=b)
    assert exc.value.field == "samples[1]"
    with pytest.raises(InputError):
        propagate_histograms(sp.csr_matrix(np.array([[0, -1.0], [-1.0, 0]])), [0], h, bins=b)


def test_factorization_is_cached_per_labeled_set():
    g = path(50)
    b = make_bins(lo=0, hi=1, count=10)
    h = np.stack([gauss(b, 0.2, 0.1), gauss(b, 0.7, 0.1)])
    before = g.operators.builds
    propagate_histograms(g, [0, 49], h, bins=b)
    propagate_histograms(g, [49, 0], h[::-1], bins=b, method="pdf")
    assert g.operators.builds == before + 1


def test_guide_snippet_runs_and_prints_linear_means():
    import re
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    text = (root / "docs" / "guide" / "details.md").read_text()
    section = text.split("## Propagating histograms", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, cwd=root)
    assert out.returncode == 0, out.stderr
    means = np.array(out.stdout.replace("[", " ").replace("]", " ").split(), dtype=float)
    assert np.allclose(means, np.linspace(0.2, 0.8, 21), atol=1e-3)


def test_point_cloud_laplacian_weights():
    from solvers import PointCloud

    rng = np.random.default_rng(8)
    p = rng.normal(size=(400, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    cloud = PointCloud(p, n_neighbors=10)
    b = make_bins(lo=0, hi=1, count=20)
    lab = np.r_[np.argsort(p[:, 2])[:5], np.argsort(p[:, 2])[-5:]]
    h = np.stack([gauss(b, 0.2, 0.05)] * 5 + [gauss(b, 0.8, 0.05)] * 5)
    res = propagate_histograms(cloud, lab, h, bins=b)
    m = S.mean(res.histograms, b)
    assert np.corrcoef(m, p[:, 2])[0, 1] > 0.9 and res.converged
    assert np.all(S.std(res.histograms, b) < 0.06)  # no added variance (equal label shapes)


def test_block_residual_kernel_equals_the_dense_product():
    """The compiled residual pass of the direct route: (Σ (A X − B)², Σ B²) as numpy
    computes it, for C- and Fortran-ordered blocks (PARDISO returns the latter)."""
    import scipy.sparse as sp

    from solvers.histograms._kernels import block_residual_parts

    rng = np.random.default_rng(0)
    A = (sp.random(300, 300, density=0.03, random_state=2, format="csr")
         + sp.identity(300, format="csr")).tocsr()
    X = rng.normal(size=(300, 5))
    B = rng.normal(size=(300, 5))
    want = (float(((A @ X - B) ** 2).sum()), float((B**2).sum()))
    for x, b in ((X, B), (np.asfortranarray(X), np.asfortranarray(B))):
        got = block_residual_parts(A.indptr, A.indices, A.data, x, b)
        np.testing.assert_allclose(got, want, rtol=1e-12)
