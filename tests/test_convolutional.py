"""Convolutional Wasserstein toolkit (thesis ch. 3) against closed forms, POT and the exact LP."""

from __future__ import annotations

import numpy as np
import ot
import potpourri3d as pp3d
import pytest
from shared_meshes import load_shared_mesh

from solvers import Grid
from solvers.convolutional import (
    barycenter,
    displacement_interpolation,
    wasserstein_distance,
    wasserstein_propagation,
)
from solvers.convolutional.common import LogKernel, entropy
from solvers.errors import CancelledError, InputError, UnsupportedDomainError


def _blobs(n, specs):
    x = np.linspace(0, 1, n)
    X, Y = np.meshgrid(x, x, indexing="ij")
    out = []
    for cx, cy, s in specs:
        b = np.exp(-((X - cx) ** 2 + (Y - cy) ** 2) / s)
        out.append(b / b.sum())
    return np.stack(out)


@pytest.fixture(scope="module")
def woody():
    mesh = load_shared_mesh("woody.obj")
    solver = pp3d.MeshHeatMethodDistanceSolver(mesh.vertices, mesh.faces)
    D = np.stack([solver.compute_distance(i) for i in range(mesh.n)])
    return mesh, 0.5 * (D + D.T)


def _bumps(mesh, D, i, j, width=0.02):
    m0 = mesh.areas * np.exp(-D[i] ** 2 / width)
    m1 = mesh.areas * np.exp(-D[j] ** 2 / width)
    return m0 / m0.sum(), m1 / m1.sum()


# -- barycenters on grids vs POT ------------------------------------------------------
@pytest.mark.parametrize("weights", [None, [0.5, 0.3, 0.2], [0.1, 0.1, 0.8]])
def test_grid_barycenter_matches_pot(weights):
    """Same kernel exp(-d^2/reg) on linspace(0,1,n); POT's stabThr=0 (its default 1e-30
    floor inside log(KU) shifts the fixed point by ~1e-4 at this reg)."""
    n, reg = 32, 0.004
    A = _blobs(n, [(0.25, 0.25, 0.01), (0.75, 0.7, 0.02), (0.3, 0.8, 0.005)])
    w = None if weights is None else np.asarray(weights)
    ref = ot.bregman.convolutional_barycenter2d(A, reg, w, stopThr=0, numItermax=1500,
                                                stabThr=0, warn=False)
    ours = barycenter(Grid((n, n)), A.reshape(3, -1).T, w, gamma=reg, tol=1e-12)
    assert ours.converged
    assert np.abs(ours.masses - ref.ravel() / ref.sum()).max() < 1e-9


def test_grid_debiased_barycenter_matches_pot():
    n, reg = 24, 0.004
    A = _blobs(n, [(0.3, 0.3, 0.01), (0.7, 0.6, 0.01)])
    w = np.array([0.7, 0.3])
    ref = ot.bregman.convolutional_barycenter2d_debiased(A, reg, w, stopThr=0, numItermax=600,
                                                         stabThr=0, warn=False)
    ours = barycenter(Grid((n, n)), A.reshape(2, -1).T, w, gamma=reg, tol=1e-12,
                      debiased=True, max_iter=600)
    assert np.abs(ours.masses - ref.ravel() / ref.sum()).max() < 1e-8
    plain = barycenter(Grid((n, n)), A.reshape(2, -1).T, w, gamma=reg, tol=1e-10)
    assert entropy(ours.masses, np.full(n * n, 1 / n**2)) < plain.entropy  # less blur


# -- distances ------------------------------------------------------------------------
def test_1d_gaussians_approach_closed_form():
    """W2^2(N(m0,s0^2), N(m1,s1^2)) = (m0-m1)^2 + (s0-s1)^2; error shrinks with gamma."""
    grid = Grid((400,))
    x = grid.points[:, 0]
    m0, s0, m1, s1 = 0.35, 0.05, 0.6, 0.08
    p = np.exp(-((x - m0) ** 2) / (2 * s0**2))
    q = np.exp(-((x - m1) ** 2) / (2 * s1**2))
    exact = (m0 - m1) ** 2 + (s0 - s1) ** 2
    errors = []
    for gamma in (1e-2, 3e-3, 1e-3):
        res = wasserstein_distance(grid, p, q, gamma=gamma, debiased=True, tol=1e-8)
        assert res.converged
        errors.append(abs(res.value - exact) / exact)
    assert errors[0] > errors[1] > errors[2]
    assert errors[-1] < 0.01


def test_woody_tracks_exact_lp(woody):
    """Debiased W2^2 vs ot.emd2 with squared geodesic costs, with the documented rule.

    Rule: gamma = 2.5 * h * d (h mean edge length, d transport distance estimated by a
    first pass at gamma = 0.05), substeps = 64.  Measured errors: +2.4 %, 0.0 %, -2.7 % on
    these three pairs (d = 0.46, 0.80, 1.04 at unit area; gamma = 0.046, 0.072, 0.095)."""
    mesh, D = woody
    h = mesh.mean_edge_length
    for i, j in [(100, 500), (20, 650), (300, 50)]:
        p, q = _bumps(mesh, D, i, j)
        lp = ot.emd2(p, q, D**2, numItermax=10**7)
        first = wasserstein_distance(mesh, p, q, gamma=0.05, substeps=16, debiased=True)
        gamma = 2.5 * h * np.sqrt(first.value)
        res = wasserstein_distance(mesh, p, q, gamma=gamma, substeps=64, debiased=True)
        assert res.converged
        assert abs(res.value / lp - 1) < 0.10, (res.value, lp)


def test_debiased_self_distance_is_zero_and_symmetric(woody):
    mesh, D = woody
    p, q = _bumps(mesh, D, 100, 500)
    assert abs(wasserstein_distance(mesh, p, p, gamma=0.02, debiased=True).value) < 1e-6
    biased = wasserstein_distance(mesh, p, p, gamma=0.02)
    assert abs(biased.value) > 1e-3  # the thesis' W_{2,H_t}(p, p) is not zero
    pq = wasserstein_distance(mesh, p, q, gamma=0.02, tol=1e-8)
    qp = wasserstein_distance(mesh, q, p, gamma=0.02, tol=1e-8)
    assert abs(pq.value - qp.value) < 1e-6 * abs(pq.value)


def test_plan_marginals_from_scalings(woody):
    """The returned scalings reproduce both marginals: a v H(a w) = m0, a w H(a v) = m1."""
    mesh, _ = woody
    rng = np.random.default_rng(1)
    p, q = rng.random(mesh.n), rng.random(mesh.n)
    p, q = p / p.sum(), q / q.sum()
    res = wasserstein_distance(mesh, p, q, gamma=0.01, tol=1e-9)
    kernel = mesh.heat_kernel(res.t)
    lk = LogKernel(kernel)
    m0 = mesh.areas * np.exp(res.log_v + lk(res.log_w))
    m1 = mesh.areas * np.exp(res.log_w + lk(res.log_v))
    assert np.abs(m0 - p).sum() < 1e-8 and np.abs(m1 - q).sum() < 1e-8
    assert abs(m0.sum() - 1) < 1e-9


@pytest.mark.parametrize("support", ["full", "sparse"])
def test_accelerations_same_answer_fewer_iterations(woody, support):
    """Over-relaxation and Anderson reach plain Alg. 1's fixed point in far fewer steps."""
    mesh, _ = woody
    rng = np.random.default_rng(2)
    p, q = rng.random(mesh.n), rng.random(mesh.n)
    if support == "sparse":  # zero mass on ~90 % of the vertices (-inf potentials)
        p *= rng.random(mesh.n) < 0.1
        q *= rng.random(mesh.n) < 0.1
    gamma = 4 * mesh.mean_edge_length**2
    plain = wasserstein_distance(mesh, p, q, gamma=gamma, acceleration="none", tol=1e-7)
    sor = wasserstein_distance(mesh, p, q, gamma=gamma, acceleration="over-relaxation",
                               tol=1e-7)
    anderson = wasserstein_distance(mesh, p, q, gamma=gamma, tol=1e-7)  # the default
    assert plain.converged and sor.converged and anderson.converged
    assert sor.iterations < plain.iterations / 3
    assert anderson.iterations < sor.iterations
    for fast in (sor, anderson):
        assert abs(fast.value - plain.value) < 1e-6 * abs(plain.value)
        assert fast.residual <= 1e-7


def test_unknown_acceleration_names_the_field(woody):
    mesh, _ = woody
    with pytest.raises(InputError) as err:
        wasserstein_distance(mesh, np.ones(mesh.n), np.ones(mesh.n), gamma=0.01,
                             acceleration="nesterov")
    assert err.value.field == "acceleration"
    with pytest.raises(InputError):
        barycenter(mesh, np.ones((mesh.n, 2)), gamma=0.01, acceleration="anderson")


def test_small_gamma_no_nan_and_honest_nonconvergence(woody):
    mesh, D = woody
    p, q = _bumps(mesh, D, 100, 500)
    for gamma in (1e-6, 1e-4):
        res = wasserstein_distance(mesh, p, q, gamma=gamma, substeps=8)
        assert np.isfinite(res.value) and np.isfinite(res.residual)
        assert not np.any(np.isnan(res.log_v)) and not np.any(np.isnan(res.log_w))
    rng = np.random.default_rng(3)
    short = wasserstein_distance(mesh, rng.random(mesh.n), rng.random(mesh.n),
                                 gamma=4 * mesh.mean_edge_length**2, max_iter=5)
    assert not short.converged and short.residual > 1e-5 and short.iterations == 5
    assert np.isfinite(short.value)
    # Grid whose Gaussian kernel underflows in float64: exact log-domain path.
    grid = Grid((64,))
    x = grid.points[:, 0]
    r = wasserstein_distance(grid, np.exp(-((x - 0.2) ** 2) / 0.001),
                             np.exp(-((x - 0.8) ** 2) / 0.001), gamma=1e-4, tol=1e-6)
    assert np.isfinite(r.value) and r.converged
    assert abs(r.value - 0.36) < 0.01


def test_progress_and_cancellation(woody):
    mesh, D = woody
    p, q = _bumps(mesh, D, 100, 500)
    seen = []
    wasserstein_distance(mesh, p, q, gamma=0.01, progress=lambda i, r: seen.append((i, r)))
    assert [i for i, _ in seen] == list(range(len(seen))) and len(seen) > 2
    with pytest.raises(CancelledError):
        wasserstein_distance(mesh, p, q, gamma=0.01, should_cancel=lambda: len(seen) > 0)
    with pytest.raises(CancelledError):
        barycenter(mesh, np.stack([p, q], 1), gamma=0.01, should_cancel=lambda: True)


def test_input_errors(woody):
    mesh, D = woody
    p, q = _bumps(mesh, D, 100, 500)
    with pytest.raises(InputError) as err:
        wasserstein_distance(mesh, p, q, gamma=-1.0)
    assert err.value.field == "gamma"
    with pytest.raises(InputError) as err:
        wasserstein_distance(mesh, p[:-1], q, gamma=0.01)
    assert err.value.field == "mu0"
    with pytest.raises(InputError) as err:
        barycenter(mesh, np.stack([p, q], 1), [1.0, -1.0], gamma=0.01)
    assert err.value.field == "weights"


def test_components_refused_or_solved():
    mesh = load_shared_mesh("suzanne.obj")
    assert mesh.n_components > 1
    labels = mesh.component_labels
    big = np.bincount(labels).argmax()
    p = np.where(labels == big, mesh.areas, 0.0)
    q = np.where(labels != big, mesh.areas, 0.0)
    with pytest.raises(UnsupportedDomainError):
        wasserstein_distance(mesh, p, q, gamma=0.01)
    rng = np.random.default_rng(0)
    r = rng.random(mesh.n) * (labels == big)
    res = wasserstein_distance(mesh, p, r, gamma=0.01)  # same component masses: per component
    assert res.converged and np.isfinite(res.value)


# -- barycenters on meshes ------------------------------------------------------------
def test_two_bump_barycenter_peaks_at_geodesic_midpoint(woody):
    mesh, D = woody
    i, j = 100, 500
    p, q = _bumps(mesh, D, i, j, width=0.005)
    # One implicit Euler step at this gamma has an almost linear effective cost, whose
    # barycenters do not move mass to the midpoint; 16 substeps restore d^2.
    res = barycenter(mesh, np.stack([p, q], 1), gamma=0.01, substeps=16, sharpen=True)
    assert res.converged and abs(res.masses.sum() - 1) < 1e-12
    k = int(np.argmax(res.masses))
    assert abs(D[i, k] - D[j, k]) < 0.15 * D[i, j]
    assert D[i, k] + D[k, j] < 1.1 * D[i, j]
    flipped = barycenter(mesh, np.stack([q, p], 1), gamma=0.01, substeps=16, sharpen=True)
    assert np.abs(flipped.masses - res.masses).sum() < 1e-5  # symmetry


def test_sharpening_lowers_entropy_to_bound(woody):
    mesh, D = woody
    p, q = _bumps(mesh, D, 100, 500, width=0.005)
    mus = np.stack([p, q], 1)
    bound = float(np.max(entropy(mus, mesh.areas)))
    blurred = barycenter(mesh, mus, gamma=0.01)
    sharp = barycenter(mesh, mus, gamma=0.01, sharpen=True)
    assert blurred.entropy > bound + 0.1
    assert sharp.entropy_bound == pytest.approx(bound)
    assert sharp.entropy <= bound + 1e-3 and sharp.entropy > bound - 0.05
    lower = barycenter(mesh, mus, gamma=0.01, entropy_bound=bound - 0.5)
    assert lower.entropy <= bound - 0.5 + 1e-3


def test_interpolation_and_propagation_agree(woody):
    """A path 0-1-2 with fixed ends propagates the midpoint barycenter (Alg. 4 = Alg. 2,
    with the default kernel of both: the geodesic one on this mesh)."""
    mesh, D = woody
    p, q = _bumps(mesh, D, 100, 500)
    interp = displacement_interpolation(mesh, p, q, [0.0, 0.5, 1.0], gamma=0.01)
    assert interp.converged and interp.masses.shape == (mesh.n, 3)
    assert np.allclose(interp.masses.sum(0), 1.0)
    prop = wasserstein_propagation(mesh, 3, [[0, 1], [1, 2]], {0: p, 2: q}, gamma=0.01)
    assert prop.converged and list(prop.free_nodes) == [1]
    assert prop.method == interp.method == "geodesic"
    assert np.abs(prop.masses[:, 1] - interp.masses[:, 1]).sum() < 1e-4
    # Unequal edge weights pull the free node toward the heavier edge's end.
    skew = wasserstein_propagation(mesh, 3, [[0, 1], [1, 2]], {0: p, 2: q},
                                   edge_weights=[3.0, 1.0], gamma=0.01)
    quarter = displacement_interpolation(mesh, p, q, [0.25], gamma=0.01)
    assert np.abs(skew.masses[:, 1] - quarter.masses[:, 0]).sum() < 1e-4
    # eq. 3.18: a per-edge diagonal rescaling of the kernel changes the coupling.
    phi = np.exp(-D[100] ** 2 / 0.01)
    scaled = wasserstein_propagation(mesh, 3, [[0, 1], [1, 2]], {0: p, 2: q},
                                     edge_kernels={0: (np.ones(mesh.n), phi)}, gamma=0.01)
    assert scaled.converged
    assert (scaled.masses[:, 1] @ D[100]) < (prop.masses[:, 1] @ D[100])


def _textbook_propagation(mesh, n_nodes, edges, fixed, weights, log_d, t, sweeps,
                          rtol=1e-14):
    """Alg. 4 as written: dense kernel, linear scalings, nodes one by one, plain
    (unnormalized) geometric means; the reference for the library's batched sweeps. Stops
    after ``sweeps``, or once a sweep changes no scaling by more than ``rtol`` (relative):
    machine precision, the fixed point reached (about 220 sweeps in the test below)."""
    import scipy.sparse as sp

    a = mesh.areas
    H = np.linalg.solve((sp.diags(a) + t * mesh.laplacian).toarray(), np.diag(a))
    d = np.exp(log_d)
    ends = [(k, s) for k in range(len(edges)) for s in (0, 1)]
    x = {(k, s): d[edges[k][s]].copy() for k, s in ends}  # scaling x rescaling, own side
    for _ in range(sweeps):
        before = {end: v.copy() for end, v in x.items()}
        for u in range(n_nodes):
            mine = [(k, s) for k, s in ends if edges[k][s] == u]
            hy = {end: H @ x[(end[0], 1 - end[1])] for end in mine}
            if u in fixed:
                for end in mine:
                    x[end] = fixed[u] / a / hy[end]
                continue
            w = np.array([weights[k] for k, _ in mine])
            logbar = sum(wi * np.log(x[end] * hy[end]) for wi, end in zip(w / w.sum(), mine,
                                                                       strict=True))
            for end in mine:
                x[end] = np.exp(logbar) / hy[end]
        if max(np.abs(x[end] / before[end] - 1).max() for end in ends) <= rtol:
            break
    out = np.zeros((mesh.n, n_nodes))
    for u in range(n_nodes):
        k, s = next((k, s) for k, s in ends if edges[k][s] == u)
        out[:, u] = fixed[u] if u in fixed else a * x[(k, s)] * (H @ x[(k, 1 - s)])
    return out


def test_propagation_matches_textbook_alg4_on_a_cycle(woody):
    """A 5-node graph with a cycle, two fixed nodes, unequal weights and node rescalings
    (eq. 3.18): the batched sweeps, whose barycenters are normalized to unit mass, reach the
    fixed point of the textbook node-by-node Alg. 4 (plain sweeps to machine precision)."""
    mesh, D = woody
    p, q = _bumps(mesh, D, 100, 500)
    edges = [[0, 1], [1, 2], [2, 3], [3, 1], [3, 4]]
    weights = [1.0, 2.0, 1.0, 0.5, 1.5]
    rng = np.random.default_rng(3)
    gamma = 0.01
    log_d = -0.3 * rng.random((5, mesh.n))
    fixed = {0: p, 4: q}
    ours = wasserstein_propagation(mesh, 5, edges, fixed, edge_weights=weights,
                                   node_scalings=log_d, gamma=gamma, tol=1e-10,
                                   method="convolutional")  # the textbook's heat kernel
    assert ours.converged and ours.iterations < 200
    ref = _textbook_propagation(mesh, 5, edges, fixed, weights, log_d, ours.t, 2000)
    assert np.allclose(ref.sum(axis=0), 1.0, atol=1e-8)  # the textbook run has converged
    assert np.abs(ours.masses - ref).sum(axis=0).max() < 1e-6


def test_propagation_active_nodes_and_threads_keep_the_fixed_point(woody):
    """A 24-node ring with chords and three fixed nodes: late sweeps skip the settled nodes
    (fewer kernel columns than every end in every sweep), convergence is certified by a full
    sweep, the result matches a run to 1e-11, and 1 or 2 threads give the same result."""
    mesh, D = woody
    p, q = _bumps(mesh, D, 100, 500)
    r = _bumps(mesh, D, 300, 600)[0]
    k = 24
    edges = [[i, (i + 1) % k] for i in range(k)] + [[i, (i + 7) % k] for i in range(0, k, 3)]
    fixed = {0: p, 8: q, 16: r}
    # the heat kernel: its threaded triangular solves are what the thread counts exercise
    opts = dict(gamma=0.01, acceleration="over-relaxation", method="convolutional")
    one = wasserstein_propagation(mesh, k, edges, fixed, tol=1e-6, threads=1, **opts)
    two = wasserstein_propagation(mesh, k, edges, fixed, tol=1e-6, threads=2, **opts)
    assert one.converged and one.residual <= 1e-6
    assert one.iterations == two.iterations and np.array_equal(one.masses, two.masses)
    assert one.kernel_columns < (one.iterations + 1) * 2 * len(edges)
    ref = wasserstein_propagation(mesh, k, edges, fixed, tol=1e-11, **opts)
    assert ref.converged
    assert np.abs(one.masses - ref.masses).sum(axis=0).max() < 1e-4


def test_propagation_warm_start_keeps_the_fixed_point(woody):
    """A warm start from a converged result is certified by its first sweep; one from a
    coarser gamma (epsilon-scaling, potentials carried over) reaches the cold start's fixed
    point; a start from another graph is refused."""
    mesh, D = woody
    p, q = _bumps(mesh, D, 100, 500)
    k = 12
    edges = [[i, (i + 1) % k] for i in range(k)] + [[0, 6]]
    fixed = {0: p, 6: q}
    opts = dict(acceleration="over-relaxation", tol=1e-8, method="convolutional")
    cold = wasserstein_propagation(mesh, k, edges, fixed, gamma=0.01, keep_scalings=True,
                                   **opts)
    assert cold.converged and cold.scalings.shape == (2 * len(edges), mesh.n)
    again = wasserstein_propagation(mesh, k, edges, fixed, gamma=0.01, initial=cold, **opts)
    assert again.converged and again.iterations == 0
    assert np.abs(again.masses - cold.masses).sum(axis=0).max() < 1e-7
    coarse = wasserstein_propagation(mesh, k, edges, fixed, gamma=0.04, keep_scalings=True,
                                     acceleration="over-relaxation", tol=1e-3)
    warm = wasserstein_propagation(mesh, k, edges, fixed, gamma=0.01, initial=coarse, **opts)
    assert warm.converged and warm.gamma == cold.gamma
    assert np.abs(warm.masses - cold.masses).sum(axis=0).max() < 1e-6
    with pytest.raises(InputError) as err:
        wasserstein_propagation(mesh, k, edges[:-1], fixed, gamma=0.01, initial=cold, **opts)
    assert err.value.field == "initial"


def test_log_kernel_bands_match_superposition(woody):
    """Inputs spanning e^-900: banded absorption equals the sum of separately shifted parts."""
    mesh, _ = woody
    lk = LogKernel(mesh.heat_kernel(0.01, 4))
    rng = np.random.default_rng(4)
    part_a = np.where(np.arange(mesh.n) < 300, rng.random(mesh.n), -np.inf)
    part_b = np.where(np.arange(mesh.n) >= 300, rng.random(mesh.n) - 900.0, -np.inf)
    banded = lk(np.maximum(part_a, part_b) + 5000.0)  # + 5000: would overflow unshifted
    assert lk.band < 900
    expected = np.logaddexp(lk(part_a), lk(part_b)) + 5000.0
    assert np.all(np.isfinite(banded))
    assert np.abs(banded - expected).max() < 1e-9 * np.abs(expected).max()
    two = lk(np.stack([part_a, part_b], axis=1))  # block of columns, one solve
    assert np.allclose(two[:, 0], lk(part_a)) and np.allclose(two[:, 1], lk(part_b))


def test_barycenter_over_relaxation_same_fixed_point_fewer_iterations():
    n, reg = 32, 0.004
    A = _blobs(n, [(0.25, 0.25, 0.01), (0.75, 0.7, 0.02)]).reshape(2, -1).T
    grid = Grid((n, n))
    plain = barycenter(grid, A, [0.3, 0.7], gamma=reg, tol=1e-10, acceleration="none")
    fast = barycenter(grid, A, [0.3, 0.7], gamma=reg, tol=1e-10)
    assert plain.converged and fast.converged
    assert fast.iterations < plain.iterations / 2
    assert np.abs(fast.masses - plain.masses).max() < 1e-9
