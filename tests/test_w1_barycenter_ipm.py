"""W1 barycenters (eq. 2.7) by the vertex-sized interior point (``method="ipm"``, the
default) against Clarabel on the whole cone program (``"socp"``) on small meshes.

The interior point certifies its objective: ``lower_bound <= optimum <= value`` with
``(value - lower_bound) / value = gap <= tol``; Clarabel's optimum (tolerance 1e-10) must fall
in that bracket, which is the check below (up to Clarabel's own tolerance).  The ground-truth
tests with Dirac inputs (brute force over vertices, exact geodesics) are in
``test_emd_exact.py`` and run on this default route."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import solvers.emd.interior_point_barycenter as ipb
from solvers.domains import TriangleMesh
from solvers.emd.beckmann import earth_movers_distance
from solvers.emd.exact import w1_barycenter
from solvers.emd.interior_point_barycenter import estimated_cost
from solvers.errors import InputError
from solvers.linalg import have_pardiso


def _sphere(subdivisions=2):
    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    return TriangleMesh(s.vertices, s.faces)


@pytest.fixture(scope="module")
def sphere():
    return _sphere()  # 162 vertices


def _bump(mesh, center, width=0.3):
    d = np.linalg.norm(mesh.vertices - mesh.vertices[center], axis=1)
    x = np.exp(-((d / width) ** 2))
    return x / x.sum()


def _check_bracket(ipm, ref, tol):
    assert ipm.method == "ipm" and ipm.converged and ipm.gap <= tol
    assert ipm.lower_bound <= ipm.value
    slack = 1e-8 * ref.value + 1e-12  # Clarabel's tolerance
    assert ipm.lower_bound - slack <= ref.value <= ipm.value + slack
    assert ipm.value == pytest.approx(ref.value, rel=2 * tol)
    assert ipm.residual < 1e-9


@pytest.mark.parametrize("case", ["bumps", "diracs", "two-inputs"])
def test_interior_point_matches_clarabel(sphere, case):
    if case == "bumps":
        mus = np.stack([_bump(sphere, c) for c in (0, 50, 100)], axis=1)
        alpha = [0.2, 0.3, 0.5]
    elif case == "diracs":
        mus = np.zeros((sphere.n, 4))
        mus[[3, 40, 90, 150], np.arange(4)] = 1.0
        alpha = None
    else:
        mus = np.stack([_bump(sphere, 7, 0.2), _bump(sphere, 120, 0.5)], axis=1)
        alpha = [0.7, 0.3]
    tol = 1e-6  # the default; the loop stops near 1e-7 on these small meshes (rounding)
    ipm = w1_barycenter(sphere, mus, alpha, tol=tol)
    ref = w1_barycenter(sphere, mus, alpha, method="socp", tol=1e-10)
    _check_bracket(ipm, ref, tol)
    # the reported distances are the W1 distances of the returned barycenter
    for i in range(mus.shape[1]):
        w1 = earth_movers_distance(sphere, ipm.masses, mus[:, i], method="ipm", tol=1e-9)
        assert ipm.distances[i] == pytest.approx(w1.value, rel=1e-4, abs=1e-9)
    # the flows carry the barycenter to each input
    for i in range(mus.shape[1]):
        div = sphere.divergence @ ipm.flows[i].ravel()
        assert np.abs(div - (ipm.masses - mus[:, i])).max() < 1e-9
    assert ipm.masses.min() > 0 and ipm.masses.sum() == pytest.approx(1.0, abs=1e-9)


def test_face_weights_and_two_components():
    """Finite face weights (cheaper travel on half the faces), and a mesh of two spheres
    whose inputs carry the same mass on each component."""
    s = trimesh.creation.icosphere(subdivisions=1)
    two = TriangleMesh(np.vstack([s.vertices, s.vertices + 3.0]),
                       np.vstack([s.faces, s.faces + len(s.vertices)]))
    n = len(s.vertices)
    mus = np.zeros((two.n, 3))
    mus[[0, 7, 20], [0, 1, 2]] = 0.5
    mus[[n + 3, n + 30, n + 11], [0, 1, 2]] = 0.5
    fw = np.where(np.arange(two.n_faces) % 2 == 0, 1.0, 2.5)
    alpha = [0.5, 0.25, 0.25]
    ipm = w1_barycenter(two, mus, alpha, face_weights=fw, tol=1e-6)
    ref = w1_barycenter(two, mus, alpha, face_weights=fw, method="socp", tol=1e-10)
    _check_bracket(ipm, ref, 1e-6)
    assert ipm.masses[:n].sum() == pytest.approx(0.5, abs=1e-9)


def test_zero_weights(sphere):
    a, b, c = _bump(sphere, 0), _bump(sphere, 60), _bump(sphere, 110)
    # all weight on one input: that input, exactly, and W1 to the others
    one = w1_barycenter(sphere, np.stack([a, b], axis=1), [1.0, 0.0])
    assert one.converged and one.value == 0.0 and np.allclose(one.masses, a, rtol=1e-12, atol=0)
    w_ab = earth_movers_distance(sphere, a, b, method="ipm", tol=1e-6).value
    assert one.distances[0] == 0.0
    assert one.distances[1] == pytest.approx(w_ab, rel=1e-5)
    # a zero weight leaves the optimum of the others unchanged
    mus = np.stack([a, b, c], axis=1)
    with_zero = w1_barycenter(sphere, mus, [0.5, 0.0, 0.5])
    without = w1_barycenter(sphere, mus[:, [0, 2]], [0.5, 0.5])
    assert with_zero.converged
    assert with_zero.value == pytest.approx(without.value, rel=1e-7)
    assert with_zero.distances[1] == pytest.approx(earth_movers_distance(
        sphere, with_zero.masses, b, method="ipm", tol=1e-6).value, rel=1e-6)


def test_walls_need_the_conic_route(sphere):
    a, b = _bump(sphere, 0), _bump(sphere, 60)
    fw = np.ones(sphere.n_faces)
    fw[:5] = np.inf
    res = w1_barycenter(sphere, np.stack([a, b], axis=1), face_weights=fw)  # auto: socp
    assert res.method == "socp" and res.converged
    with pytest.raises(InputError) as err:
        w1_barycenter(sphere, np.stack([a, b], axis=1), face_weights=fw, method="ipm")
    assert err.value.field == "method"
    with pytest.raises(InputError) as err:
        w1_barycenter(sphere, np.stack([a, b], axis=1), method="lp")
    assert err.value.field == "method"


def test_no_vertex_cap_on_the_interior_point():
    """The conic route refuses a 10k-vertex mesh; the interior point solves it."""
    mesh = _sphere(5)  # 10242 vertices
    mus = np.zeros((mesh.n, 2))
    mus[[0, 5000], [0, 1]] = 1.0
    with pytest.raises(InputError):
        w1_barycenter(mesh, mus, method="socp")
    res = w1_barycenter(mesh, mus)
    assert res.converged and res.gap <= 1e-6 and res.residual < 1e-6


def test_cost_model_grows_with_size_and_inputs():
    small, more, bigger = (estimated_cost(10_000, 20_000, 3), estimated_cost(10_000, 20_000, 6),
                           estimated_cost(50_000, 100_000, 3))
    assert small.seconds < more.seconds and small.seconds < bigger.seconds
    assert small.bytes < more.bytes and small.bytes < bigger.bytes


@pytest.mark.skipif(not have_pardiso(), reason="the mkl wheel (pardiso extra) is not installed")
@pytest.mark.parametrize("from_iteration", [1, 6])
def test_zero_pivot_hands_over_to_ldlt(sphere, monkeypatch, from_iteration):
    """A zero pivot in the Cholesky (forced here from a given factorization on) hands the
    normal matrix to PARDISO's L D Lᵀ, which factors the remaining iterations; the optimum
    is Clarabel's, within the certified bracket, and the constraints hold to rounding."""
    calls, used = [0], []
    first, refactor = ipb._first_factor, ipb.PardisoFactor.refactor_data

    def zero_pivot(mtype):
        calls[0] += 1
        return mtype == 2 and calls[0] >= from_iteration

    def first_factor(normal, backend):
        if zero_pivot(2):
            raise ValueError("PARDISO phase 22 failed (-4: zero pivot)")
        return first(normal, backend)

    def refactor_data(self, data):  # the later iterations refactor in place
        if self.mtype == -2:
            used.append(self.backend)
        if zero_pivot(self.mtype):
            raise ValueError("PARDISO phase 22 failed (-4: zero pivot)")
        return refactor(self, data)

    monkeypatch.setattr(ipb, "_first_factor", first_factor)
    monkeypatch.setattr(ipb.PardisoFactor, "refactor_data", refactor_data)
    mus = np.stack([_bump(sphere, c) for c in (0, 50, 100)], axis=1)
    alpha = [0.2, 0.3, 0.5]
    ipm = w1_barycenter(sphere, mus, alpha, tol=1e-6)
    ref = w1_barycenter(sphere, mus, alpha, method="socp", tol=1e-10)
    _check_bracket(ipm, ref, 1e-6)
    assert ipm.iterations > from_iteration and used and set(used) == {"pardiso-ldlt"}


@pytest.mark.parametrize("iterations", [1, 8])
def test_bordered_solve_is_the_normal_equations(sphere, monkeypatch, iterations):
    """The bordered matrix ``[[A, V], [Vᵀ, C⁻¹]]`` one factorization per iteration solves:
    its border holds ``v_i`` on block ``i``'s rows and ``1 / c_i``, its solve's first rows
    solve the normal equations ``(A - V C Vᵀ) Δy = r`` (dense check), and the directions
    built on them satisfy the Newton system's divergence constraints
    (``D du_i - dρ = -e_i``)."""
    seen = []

    class Recording(ipb._Newton):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            seen.append(self)

    monkeypatch.setattr(ipb, "_Newton", Recording)
    mus = np.stack([_bump(sphere, c) for c in (0, 50, 100)], axis=1)
    w1_barycenter(sphere, mus, [0.2, 0.3, 0.5], tol=1e-12, max_iter=iterations)
    newton = seen[-1]
    prog, layout = newton.prog, newton.layout
    size, k = layout.size, prog.k
    data = layout.data(ipb.ip.face_blocks(newton.scaling, prog.products), newton.d, newton.v,
                       newton.c)
    bordered = layout.matrix(data, full=True).toarray()
    a, border = bordered[:size, :size], bordered[:size, size:]
    for i in range(k):
        expected = np.zeros(size)
        expected[layout.offsets[i]:layout.offsets[i + 1]] = newton.v[i, layout.rows_of[i]]
        np.testing.assert_array_equal(border[:, i], expected)
    np.testing.assert_allclose(np.diag(bordered[size:, size:]), 1.0 / newton.c, rtol=1e-15)
    normal = a - border @ np.diag(newton.c) @ border.T
    r = np.random.default_rng(1).normal(size=(k, prog.n))
    dy = newton._solve(r)
    np.testing.assert_allclose(normal @ dy, layout.scatter(r), rtol=0,
                               atol=1e-8 * np.abs(layout.scatter(r)).max())
    lam = newton.scaling.lam
    dx, drho = newton(-ipb.ip._jordan(lam, lam), -newton.lam_rho**2)[:2]
    change = prog.div(dx.reshape(k, -1, 3)) - drho[None]
    np.testing.assert_allclose(change, -newton.residual, atol=1e-9)


def _interior_cones(rng, k):
    v = rng.normal(size=(k, 3))
    v[:, 0] = np.linalg.norm(v[:, 1:], axis=1) + rng.uniform(0.1, 1.0, k)
    return v


def _nt_apply(w, beta, y, power):
    """``W y = β (2 v vᵀ − J) y`` (``power`` 1, ``w = v``) or ``W⁻¹ y = (2 p pᵀ − J) y / β``
    (``power`` -1, ``w = p``), written out in numpy."""
    c = 2.0 * np.sum(w * y, axis=1, keepdims=True)
    return (c * w - np.array([1.0, -1.0, -1.0]) * y) * beta[:, None] ** power


def test_centrality_correction_moves_spectral_values_into_the_band():
    """Gondzio's target per Lorentz cone, as the correctors' right-hand side adds it to
    ``rc`` (``_gondzio_rhs_kernel``): after the change, the scaled product ``p = W (x +
    trial Δx) ∘ W⁻¹ (z + trial Δz)`` has its spectral values ``p_0 ± ‖p̄‖`` in the band
    (where the decrease cap does not bind), and products already inside are left alone."""
    ip = ipb.ip
    rng = np.random.default_rng(3)
    x, z = _interior_cones(rng, 500), _interior_cones(rng, 500)
    dx, dz, rc = rng.normal(size=(3, 500, 3))
    trial = 0.3
    sc = ip._nt_scaling(x, z)
    p = ip._jordan(_nt_apply(sc.v, sc.beta, x + trial * dx, 1),
                   _nt_apply(sc.p, sc.beta, z + trial * dz, -1))

    def spectra(a):
        norm = np.linalg.norm(a[:, 1:], axis=1)
        return a[:, 0] - norm, a[:, 0] + norm

    low, high = spectra(p)
    hi = 0.6 * high.max()  # every decrease is below hi: the cap does not bind
    lo = float(np.median(low))
    inside = (low >= lo) & (high <= hi)
    assert 0 < lo < hi and inside.any() and (low < lo).any() and (high > hi).any()
    out = ip._gondzio_rhs_kernel(x, dx, z, dz, trial, sc.v, sc.p, sc.beta, rc, lo, hi)
    q = p + (out - rc)
    tol = 1e-12 * np.abs(p).max()
    for s in spectra(q):
        assert np.all((s >= lo - tol) & (s <= hi + tol))
    np.testing.assert_allclose(q[inside], p[inside], rtol=0, atol=tol)


@pytest.mark.parametrize("correctors", [0, 1, 4])
def test_correctors_keep_the_optimum(sphere, monkeypatch, correctors):
    """With any number of Gondzio's correctors (the default is ``CORRECTORS``) the certified
    bracket holds Clarabel's optimum."""
    step = ipb.ip.mehrotra_step
    monkeypatch.setattr(ipb.ip, "mehrotra_step", lambda *args: step(*args[:5], correctors))
    mus = np.stack([_bump(sphere, c) for c in (0, 50, 100)], axis=1)
    alpha = [0.2, 0.3, 0.5]
    ipm = w1_barycenter(sphere, mus, alpha, tol=1e-6)
    ref = w1_barycenter(sphere, mus, alpha, method="socp", tol=1e-10)
    _check_bracket(ipm, ref, 1e-6)
