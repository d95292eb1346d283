"""Anisotropic W1 (thesis §2.7, Fig. 2.15): closed forms on a plane, curvature weights.

On a flat square, moving a Dirac along a straight line under a constant metric ``M`` costs
``|M (p - q)|`` exactly; a cost that depends on x only makes the straight path optimal for a
horizontal move, so its cost is the integral of the weight along it.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from solvers import InputError, TriangleMesh
from solvers.emd import earth_movers_distance
from solvers.emd.anisotropy import anisotropic_w1, mean_curvature_weights


@pytest.fixture(scope="module")
def square():
    n = 21
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), \
        idx[1:, :-1].ravel()
    faces = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    return TriangleMesh(np.c_[x.ravel(), y.ravel(), np.zeros(n * n)], faces)


def dirac(mesh, fraction):
    """Unit mass at the vertex nearest to ``lo + fraction * (hi - lo)`` in the plane."""
    v = mesh.vertices[:, :2]
    target = v.min(0) + np.asarray(fraction) * np.ptp(v, axis=0)
    i = int(np.argmin(np.linalg.norm(v - target, axis=1)))
    e = np.zeros(mesh.n)
    e[i] = 1.0
    return e, mesh.vertices[i]


def rotation_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("start, end", [((0.2, 0.5), (0.8, 0.5)), ((0.5, 0.2), (0.5, 0.8)),
                                        ((0.2, 0.3), (0.7, 0.8))])
@pytest.mark.parametrize("angle", [0.0, np.pi / 5])
def test_constant_matrix_metric_gives_the_closed_form(square, start, end, angle):
    R = rotation_z(angle)
    M = R @ np.diag([3.0, 1.0, 1.0]) @ R.T
    mu0, p = dirac(square, start)
    mu1, q = dirac(square, end)
    res = anisotropic_w1(square, mu0, mu1, np.tile(M, (square.n_faces, 1, 1)))
    exact = float(np.linalg.norm(M @ (p - q)))
    assert res.converged and res.method == "ipm"
    assert res.value == pytest.approx(exact, rel=2e-3)
    assert res.lower_bound <= res.value and res.lower_bound == pytest.approx(exact, rel=2e-3)
    # the flow moves the mass: its divergence is the difference of the marginals
    np.testing.assert_allclose(square.divergence @ res.flow.ravel(), mu0 - mu1, atol=1e-8)


def test_curl_basis_overestimates_matrix_weights(square):
    """The thesis' curl basis is a subspace of all flows: far above the closed form."""
    M = np.tile(np.diag([3.0, 1.0, 1.0]), (square.n_faces, 1, 1))
    mu0, p = dirac(square, (0.5, 0.2))
    mu1, q = dirac(square, (0.5, 0.8))
    exact = float(np.linalg.norm(p - q))
    full = anisotropic_w1(square, mu0, mu1, M, method="admm", basis="full")
    assert full.value > 1.2 * exact
    assert anisotropic_w1(square, mu0, mu1, M).value < 1.002 * exact


def test_scalar_weights_integrate_along_the_straight_path(square):
    mu0, p = dirac(square, (0.2, 0.5))
    mu1, q = dirac(square, (0.8, 0.5))
    middle = 0.5 * (square.vertices[:, 0].min() + square.vertices[:, 0].max())
    centroids = square.vertices[square.faces].mean(axis=1)
    w = np.where(centroids[:, 0] > middle, 3.0, 1.0)
    res = anisotropic_w1(square, mu0, mu1, w)
    exact = (middle - p[0]) + 3.0 * (q[0] - middle)
    assert res.value == pytest.approx(exact, rel=2e-3)


def test_mean_curvature_weights_on_a_sphere_are_constant():
    s = trimesh.creation.icosphere(subdivisions=3)
    sphere = TriangleMesh(s.vertices, s.faces)
    w = mean_curvature_weights(sphere, 2.0)
    assert w.shape == (sphere.n_faces,)
    np.testing.assert_allclose(w, 3.0, rtol=0.035)  # measured: 3.1 % at the 12 valence-5 vertices
    e = np.eye(sphere.n)
    iso = earth_movers_distance(sphere, e[0], e[100])
    np.testing.assert_allclose(anisotropic_w1(sphere, e[0], e[100], w).value, 3 * iso.value,
                               rtol=0.03)


def test_mean_curvature_weights_grow_on_creases(shared_mesh):
    """fandisk (CAD): its sharp edges carry the largest weights; flat faces weigh 1."""
    mesh = shared_mesh("fandisk.obj")
    w = mean_curvature_weights(mesh, 1.0)
    a = mesh.face_areas
    assert float(a @ (w - 1.0) / a.sum()) == pytest.approx(1.0, rel=1e-9)  # mean |H| -> 1
    normals = mesh.face_normals
    e = mesh.edges
    # faces on a crease: a neighbour across an edge turns by more than 30 degrees
    from scipy.sparse import coo_matrix

    vf = coo_matrix((np.ones(3 * mesh.n_faces), (mesh.faces.ravel(),
                    np.repeat(np.arange(mesh.n_faces), 3))), shape=(mesh.n, mesh.n_faces))
    vf = vf.tocsr()
    crease = np.zeros(mesh.n_faces, bool)
    for i, j in e[::7]:  # a sample of the edges
        shared = np.intersect1d(vf[i].indices, vf[j].indices)
        if len(shared) == 2 and normals[shared[0]] @ normals[shared[1]] < np.cos(np.pi / 6):
            crease[shared] = True
    assert crease.any()
    assert np.median(w[crease]) > 2.0 * np.median(w[~crease])
    assert np.median(w[~crease]) < 1.5


def test_refuses_degenerate_matrices_and_missing_weights(square):
    mu0, _ = dirac(square, (0.2, 0.5))
    mu1, _ = dirac(square, (0.8, 0.5))
    M = np.tile(np.diag([1.0, 0.0, 1.0]), (square.n_faces, 1, 1))  # kills y on the plane
    with pytest.raises(InputError) as err:
        anisotropic_w1(square, mu0, mu1, M)
    assert err.value.field == "face_weights"
    with pytest.raises(InputError) as err:
        anisotropic_w1(square, mu0, mu1, None)
    assert err.value.field == "face_weights"
    with pytest.raises(InputError) as err:
        mean_curvature_weights(square, -1.0)
    assert err.value.field == "strength"
