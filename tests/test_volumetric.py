"""Volumetric distances (thesis §2.6): mean value coordinates, KR distances, descent paths."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from solvers.domains import TriangleMesh
from solvers.emd.volumetric import (
    mean_value_coordinates,
    volumetric_distance,
    volumetric_distances,
    volumetric_path,
    winding_number,
)
from solvers.errors import CancelledError, InputError, UnsupportedDomainError


@pytest.fixture(scope="module")
def sphere():
    s = trimesh.creation.icosphere(subdivisions=2)
    return TriangleMesh(s.vertices, s.faces)


@pytest.fixture(scope="module")
def torus():
    t = trimesh.creation.torus(major_radius=1.0, minor_radius=0.4, major_sections=16,
                               minor_sections=8)
    return TriangleMesh(t.vertices, t.faces)


def _random_points(mesh, count, seed):
    rng = np.random.default_rng(seed)
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    return lo + (hi - lo) * rng.random((count, 3))


@pytest.mark.parametrize("name", ["spot.obj", "cow.obj"])
def test_mvc_linear_precision_on_real_closed_meshes(name, shared_mesh):
    mesh = shared_mesh(name)
    assert mesh.is_closed
    P = _random_points(mesh, 150, 0)
    wn = winding_number(mesh, P)
    # winding numbers of a closed surface are integers: 0 outside, 1 inside
    assert np.abs(wn - np.round(wn)).max() < 1e-6
    inside, outside = P[wn > 0.5][:40], P[wn < 0.5][:10]
    assert len(inside) >= 15
    for pts in (inside, outside):
        W = mean_value_coordinates(mesh, pts)
        assert np.abs(W.sum(axis=1) - 1).max() < 1e-10
        assert np.abs(W @ mesh.vertices - pts).max() < 1e-9  # measured <= 3e-11
    # real models are not convex: some interior coordinates are negative
    assert mean_value_coordinates(mesh, inside).min() < 0


def test_mvc_positive_inside_convex_and_surface_cases(sphere):
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(60, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    radius = np.linalg.norm(sphere.vertices, axis=1).min()
    P = dirs * radius * rng.uniform(0.0, 0.9, (60, 1))
    W = mean_value_coordinates(sphere, P)
    assert W.min() > 0
    assert np.abs(W @ sphere.vertices - P).max() < 1e-12
    assert np.allclose(winding_number(sphere, P), 1.0)
    # on a face: barycentric coordinates; at a vertex: a Dirac
    f = sphere.faces[3]
    q = sphere.vertices[f].T @ np.array([0.2, 0.3, 0.5])
    W = mean_value_coordinates(sphere, np.vstack([q, sphere.vertices[7]]))
    assert np.allclose(W[0, f], [0.2, 0.3, 0.5])
    assert np.abs(W[0]).sum() == pytest.approx(1.0)
    assert W[1, 7] == 1.0 and np.abs(W[1]).sum() == 1.0
    # units="input" takes coordinates of the loaded file
    Win = mean_value_coordinates(sphere, P[:5] * sphere.length_scale, units="input")
    assert np.allclose(Win, mean_value_coordinates(sphere, P[:5]))


def test_distance_metric_properties(sphere):
    rng = np.random.default_rng(2)
    radius = np.linalg.norm(sphere.vertices, axis=1).min()
    dirs = rng.normal(size=(4, 3))
    P = dirs / np.linalg.norm(dirs, axis=1)[:, None] * radius * rng.uniform(0.1, 0.9, (4, 1))
    D = np.zeros((4, 4))
    for i in range(4):
        for j in range(4):
            if i != j:
                r = volumetric_distance(sphere, P[i], P[j])
                assert r.converged
                assert r.potential @ (r.weights_y - r.weights_x) == pytest.approx(r.value,
                                                                                 rel=1e-6)
                D[i, j] = r.value
    assert np.abs(D - D.T).max() < 1e-7 * D.max()
    for i in range(4):
        for j in range(4):
            for k in range(4):
                assert D[i, j] <= D[i, k] + D[k, j] + 1e-8
    # linear functions are feasible potentials: d(x, y) >= |x - y|
    E = np.linalg.norm(P[:, None] - P[None], axis=2)
    off = ~np.eye(4, dtype=bool)
    assert np.all(D[off] >= E[off] * (1 - 1e-6))
    assert volumetric_distance(sphere, P[0], P[0]).value < 1e-8
    # one-to-many agrees with the pairwise distances
    field = volumetric_distances(sphere, P[0], P)
    assert field.converged
    assert np.allclose(field.distances, D[0], rtol=1e-6, atol=1e-8)
    with pytest.raises(CancelledError):
        volumetric_distances(sphere, P[0], P, should_cancel=lambda: True)


def test_distance_with_negative_weights_on_a_torus(torus):
    P = _random_points(torus, 200, 5)
    inside = P[winding_number(torus, P) > 0.5]
    W = mean_value_coordinates(torus, inside)
    assert W.min() < 0  # the solid torus is not convex
    x, y = inside[np.argmin(W.min(axis=1))], inside[0]
    r = volumetric_distance(torus, x, y)
    assert r.converged and r.weights_x.min() < 0
    assert r.value >= np.linalg.norm(x - y) * (1 - 1e-6)
    assert r.value == pytest.approx(volumetric_distance(torus, y, x).value, rel=1e-6)


def test_descent_path_on_sphere_reaches_target(sphere):
    radius = np.linalg.norm(sphere.vertices, axis=1).min()
    start = np.array([0.8, 0.0, 0.0]) * radius
    target = np.array([0.0, 0.5, 0.3]) * radius
    calls = []
    path = volumetric_path(sphere, start, target, step=0.05 * radius,
                           progress=lambda k, d: calls.append(d))
    assert path.converged
    assert np.allclose(path.points[0], start) and np.allclose(path.points[-1], target)
    assert np.all(np.diff(path.distances) < 0)  # distance to the target decreases
    assert len(calls) == path.iterations
    steps = np.linalg.norm(np.diff(path.points[:-1], axis=0), axis=1)
    assert np.allclose(steps, 0.05 * radius)


def test_descent_path_on_torus(torus):
    """Descent on a non-convex solid: reaches the target; along the way (inside or outside
    the solid) the W1 distance to the target never drops below the straight-line one."""
    a, c = np.array([1.0, 0, 0]), np.array([-0.2, 0.98, 0])
    path = volumetric_path(torus, a, c, units="input", step=0.15, max_iter=40)
    assert path.converged
    assert np.linalg.norm(path.points[-1] * torus.length_scale - c) < 1e-9
    gap = np.linalg.norm(path.points - c / torus.length_scale, axis=1)
    assert np.all(path.distances >= gap * (1 - 1e-6))
    assert path.distances[-2] < 0.25 * path.distances[0]


def test_validation(sphere):
    with pytest.raises(InputError):
        mean_value_coordinates(sphere, np.zeros((3, 2)))
    with pytest.raises(InputError):
        mean_value_coordinates(sphere, [np.nan, 0, 0])
    with pytest.raises(InputError):
        volumetric_distance(sphere, np.zeros(3), np.zeros(3), method="nope")
    open_mesh = TriangleMesh(sphere.vertices, sphere.faces[1:])
    with pytest.raises(UnsupportedDomainError):
        mean_value_coordinates(open_mesh, np.zeros(3))


def test_admm_option_runs_admm(torus, monkeypatch):
    """``method="admm"`` reaches the ADMM of solvers.emd (not the interior point)."""
    from solvers.emd import beckmann
    seen = []
    real = beckmann._admm
    monkeypatch.setattr(beckmann, "_admm", lambda *a, **k: seen.append(1) or real(*a, **k))
    monkeypatch.setattr(beckmann, "_ipm", lambda *a, **k: pytest.fail("ran the interior point"))
    volumetric_distance(torus, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), units="input",
                        method="admm", tol=1e-3)
    assert seen


def test_admm_agrees_with_exact_solver(torus):
    """solvers.emd's ADMM over all piecewise-constant flows solves the same discrete
    problem as the interior-point SOCP (measured relative gap 6e-6 at tol 1e-5)."""
    a, c = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    exact = volumetric_distance(torus, a, c, units="input")
    admm = volumetric_distance(torus, a, c, units="input", method="admm", tol=1e-5)
    assert (exact.method, admm.method) == ("exact", "admm")
    assert admm.converged
    assert admm.value == pytest.approx(exact.value, rel=1e-3)
