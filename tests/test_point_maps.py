"""Soft maps of point maps (ch. 4) and their bases (§4.6.1 SVD, §4.6.2 collections).

Closed forms on a sphere: the blurred identity map's weighted kernel is
``(I + tau A^{-1/2} L A^{-1/2})^{-1}``, so its singular values are ``1 / (1 + tau lambda_i)``
with the Laplace-Beltrami eigenvalues, its bases the eigenfunctions, and its bijectivity
density is 1 everywhere.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
import trimesh

from solvers import InputError, TriangleMesh
from solvers.kernels import heat_time
from solvers.softmaps import low_rank_approximation
from solvers.softmaps.point_maps import (
    analyze_point_map,
    captured_energy,
    point_map_soft_map,
    point_maps_collection_basis,
)


@pytest.fixture(scope="module")
def sphere():
    s = trimesh.creation.icosphere(subdivisions=2)
    return TriangleMesh(s.vertices, s.faces)


def rotation_map(mesh, angle=0.9):
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    p = (mesh.vertices - mesh.vertices.mean(0)) @ R.T + mesh.vertices.mean(0)
    from scipy.spatial import cKDTree

    return cKDTree(mesh.vertices).query(p)[1]


def laplace_eigenvalues(mesh):
    L = mesh.laplacian.toarray()
    return sla.eigh(L, np.diag(mesh.areas), eigvals_only=True)


def subspace_cosines(A, B, areas):
    """Cosines of the principal angles between the area-weighted column spans."""
    qa = np.linalg.qr(np.sqrt(areas)[:, None] * A)[0]
    qb = np.linalg.qr(np.sqrt(areas)[:, None] * B)[0]
    return np.linalg.svd(qa.T @ qb, compute_uv=False)


def test_identity_map_singular_values_are_the_heat_spectrum(sphere):
    gamma = 4 * sphere.mean_edge_length**2
    res = analyze_point_map(sphere, sphere, np.arange(sphere.n), samples=sphere.n, gamma=gamma,
                            rank=10, dirichlet_method=None, descriptor_k=None)
    tau = heat_time(gamma)
    lam = laplace_eigenvalues(sphere)
    # all pairs of the remainder: the last one is the constant direction again (0)
    np.testing.assert_allclose(res.singular_values[:-1], 1.0 / (1.0 + tau * lam),
                               rtol=1e-8, atol=1e-12)
    assert abs(res.singular_values[-1]) < 1e-9
    # bases: the constant, then the degree-1 harmonics (linear functions) span 3 columns
    t = res.basis.target_basis
    np.testing.assert_allclose(t[:, 0], 1.0, rtol=1e-9)
    cos = subspace_cosines(t[:, 1:4], sphere.vertices - sphere.vertices.mean(0), sphere.areas)
    assert cos.min() > 0.999
    np.testing.assert_allclose(res.bijectivity_density, 1.0, rtol=1e-9)
    assert res.bijectivity == pytest.approx(1.0, rel=1e-9) and res.dirichlet is None
    _, err = low_rank_approximation(res.soft_map.rows, res.soft_map.cell_areas, sphere.areas,
                                    10)
    assert res.low_rank_error == pytest.approx(err, rel=1e-9)


def test_energies_tell_a_rotation_from_a_scramble(sphere):
    opts = {"samples": 60, "rank": 5, "descriptor_k": None}
    ident = analyze_point_map(sphere, sphere, np.arange(sphere.n), **opts)
    rot = analyze_point_map(sphere, sphere, rotation_map(sphere), **opts)
    scramble = analyze_point_map(sphere, sphere,
                                 np.random.default_rng(0).permutation(sphere.n), **opts)
    # an isometry keeps the Dirichlet energy; a scramble tears the map apart
    assert rot.dirichlet.total == pytest.approx(ident.dirichlet.total, rel=0.15)
    assert scramble.dirichlet.total > 5 * ident.dirichlet.total
    assert ident.soft_map.rows.shape == (60, sphere.n) and ident.descriptor is None
    assert 0.9 < ident.bijectivity < 1.5


def test_descriptor_energy_is_low_for_the_identity(shared_mesh):
    """eq. 4.6 with WKS: the identity of a real shape matches descriptors, a scramble not."""
    mesh = shared_mesh("woody.obj")
    opts = {"samples": 40, "rank": 3, "descriptor_k": 20, "n_energies": 30,
            "dirichlet_method": None, "gamma": 4 * mesh.mean_edge_length**2}
    ident = analyze_point_map(mesh, mesh, np.arange(mesh.n), **opts)
    scramble = analyze_point_map(mesh, mesh, np.random.default_rng(1).permutation(mesh.n),
                                 **opts)
    assert ident.descriptor < 0.5 * scramble.descriptor  # measured ratio 0.27


def test_collection_basis_of_isometries_spans_the_low_harmonics(sphere):
    """§4.6.2: identity and rotation share the spherical-harmonic bands: a rank-4 collection
    basis spans {1, x, y, z}; it also captures the stacked maps at least as well as either
    map's own rank-4 basis (Eckart-Young)."""
    gamma = 4 * sphere.mean_edge_length**2
    opts = {"samples": sphere.n, "gamma": gamma, "rank": 4, "dirichlet_method": None,
            "descriptor_k": None}
    maps = [analyze_point_map(sphere, sphere, np.arange(sphere.n), **opts),
            analyze_point_map(sphere, sphere, rotation_map(sphere), **opts)]
    basis = point_maps_collection_basis(sphere, maps, 4)
    assert basis.shape == (sphere.n, 4)
    np.testing.assert_allclose(basis.T @ (sphere.areas[:, None] * basis), np.eye(4),
                               atol=1e-9)
    linear = np.c_[np.ones(sphere.n), sphere.vertices]
    # measured 0.9973: the rotation is snapped to the nearest vertices
    assert subspace_cosines(basis, linear, sphere.areas).min() > 0.995
    # Eckart-Young on the stacked, de-meaned weighted kernels
    def captured(B):
        return sum(captured_energy(m.soft_map, sphere.areas, B) for m in maps)

    third = analyze_point_map(sphere, sphere, rotation_map(sphere, 2.0), **opts)
    for other in (maps[0].basis.target_basis, third.basis.target_basis):
        assert captured(basis) >= captured(other) - 1e-12
    # a map's own SVD basis captures the most of it
    own = captured_energy(maps[0].soft_map, sphere.areas, maps[0].basis.target_basis)
    assert own >= captured_energy(maps[0].soft_map, sphere.areas, basis) - 1e-12
    assert captured_energy(maps[0].soft_map, sphere.areas, np.ones((sphere.n, 1))) == 0.0


def test_point_maps_are_validated(sphere):
    with pytest.raises(InputError) as err:
        point_map_soft_map(sphere, sphere, np.arange(sphere.n - 1))
    assert err.value.field == "correspondence"
    with pytest.raises(InputError) as err:
        point_map_soft_map(sphere, sphere, np.full(sphere.n, sphere.n))
    assert err.value.field == "correspondence"
    with pytest.raises(InputError) as err:
        analyze_point_map(sphere, sphere, np.arange(sphere.n), samples=20, rank=100)
    assert err.value.field == "rank"
