"""Soft-map outputs: bijectivity density b(y) (eq. 4.5), Dirichlet density per source vertex,
and the Sinkhorn-projected refinement (doubly-stochastic w.r.t. source/target areas)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from solvers import InputError, TriangleMesh
from solvers.softmaps import farthest_point_samples, soft_map
from solvers.softmaps.energies import (
    bijectivity_density,
    bijectivity_density_top_k,
    bijectivity_energy,
    dirichlet_energy,
    soft_map_energies,
)
from solvers.softmaps.extraction import extract_correspondence, mode, sinkhorn_projection


@pytest.fixture(scope="module")
def sphere():
    s = trimesh.creation.icosphere(subdivisions=2)
    return TriangleMesh(s.vertices, s.faces)


def _blurred_map(mesh, points, t):
    """Rows of target masses: heat-blurred deltas at the vertices nearest to ``points``."""
    from scipy.spatial import cKDTree

    _, y = cKDTree(mesh.vertices).query(points)
    deltas = np.zeros((mesh.n, len(points)))
    deltas[y, np.arange(len(points))] = 1.0 / mesh.areas[y]
    rows = (mesh.heat_kernel(t, 1).apply(deltas) * mesh.areas[:, None]).T
    return rows / rows.sum(axis=1, keepdims=True)


def _stretched(mesh):
    """The sphere squeezed towards its poles: a map that piles mass up (Fig. 4.6)."""
    c = mesh.vertices - mesh.vertices.mean(0)
    s = c * np.array([1.0, 1.0, 4.0])
    return s / np.linalg.norm(s, axis=1, keepdims=True) * np.linalg.norm(c, axis=1).mean()


def test_sinkhorn_projection_reaches_both_marginals_by_diagonal_scaling():
    rng = np.random.default_rng(3)
    rows = rng.random((30, 80)) ** 4 + 1e-3
    rows /= rows.sum(axis=1, keepdims=True)
    c = rng.random(30) + 0.5
    a = rng.random(80) + 0.5
    proj = sinkhorn_projection(rows, c, a, max_iter=500, tol=1e-10)
    assert proj.converged and proj.residual <= 1e-10 and proj.iterations > 1
    assert proj.initial_residual > 0.1  # the random map was far from doubly stochastic
    plan = proj.rows * (c / c.sum())[:, None]
    np.testing.assert_allclose(proj.rows.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(plan.sum(axis=0), a / a.sum(), atol=1e-10)
    # KL projection = diagonal scaling: log(pi / pi0) is u_i + v_j (double-centering is 0).
    g = np.log(proj.rows / rows)
    g = g - g.mean(axis=0) - g.mean(axis=1, keepdims=True) + g.mean()
    assert np.abs(g).max() < 1e-8
    # Already doubly stochastic: no scaling needed, unchanged.
    again = sinkhorn_projection(proj.rows, c, a, tol=1e-9)
    assert again.iterations == 0 and np.allclose(again.rows, proj.rows, atol=1e-12)


def test_sinkhorn_projection_keeps_fixed_delta_rows(sphere):
    rows = _blurred_map(sphere, sphere.vertices[:40], 4 * sphere.mean_edge_length**2)
    rows[0] = 0.0
    rows[0, 7] = 1.0  # a landmark delta carrying a whole cell (1/40 of the area)
    c = np.full(40, 1.0 / 40)
    stuck = sinkhorn_projection(rows, c, sphere.areas, max_iter=50, tol=1e-4)
    # A cell of area 1/40 cannot fit into one vertex of area ~1/162: infeasible, column 7
    # keeps at least the excess c_0 - a_7 and the other columns miss as much.
    assert not stuck.converged
    assert stuck.residual >= 2 * (c[0] - sphere.areas[7]) - 1e-12
    ok = sinkhorn_projection(rows, c, sphere.areas, fixed=[0], max_iter=200, tol=1e-6)
    assert ok.converged
    assert np.array_equal(ok.rows[0], rows[0])
    free = ok.rows[1:] * c[1:, None]
    np.testing.assert_allclose(free.sum(axis=0), sphere.areas * c[1:].sum(), atol=1e-6)
    with pytest.raises(InputError) as err:
        sinkhorn_projection(rows, c, sphere.areas, fixed=[40])
    assert err.value.field == "fixed"


def test_sinkhorn_spreads_a_piling_map_to_bijectivity_one(sphere):
    """The stretched map piles mass at the poles (E_B > 1, Proposition 11); projecting it
    makes b = 1 (E_B = 1, the minimum at unit area)."""
    rows = _blurred_map(sphere, _stretched(sphere), sphere.mean_edge_length**2)
    cells = sphere.areas
    before = bijectivity_energy(sphere, rows, cells)
    b0 = bijectivity_density(sphere, rows, cells)
    assert before > 1.3 and b0.max() > 2.0
    proj = sinkhorn_projection(rows, cells, sphere.areas, max_iter=2000, tol=1e-8)
    assert proj.converged
    b = bijectivity_density(sphere, proj.rows, cells)
    np.testing.assert_allclose(b, 1.0, atol=1e-5)
    assert bijectivity_energy(sphere, proj.rows, cells) == pytest.approx(1.0, abs=1e-8)


def test_bijectivity_density_integrates_to_one_and_top_k_agrees(sphere):
    g = farthest_point_samples(sphere, 30)
    cells = np.bincount(g.labels, weights=sphere.areas, minlength=g.n)
    rows = _blurred_map(sphere, sphere.vertices[g.indices], 2 * sphere.mean_edge_length**2)
    b = bijectivity_density(sphere, rows, cells)
    assert sphere.areas @ b == pytest.approx(1.0, abs=1e-12)
    everything = np.tile(np.arange(sphere.n), (g.n, 1))
    np.testing.assert_allclose(bijectivity_density_top_k(sphere, everything, rows, cells), b,
                               atol=1e-12)
    k = 12
    idx = np.argsort(-rows, axis=1)[:, :k]
    kept = np.take_along_axis(rows, idx, axis=1)
    dropped = 1.0 - kept.sum(axis=1)
    bk = bijectivity_density_top_k(sphere, idx, kept, cells)
    assert sphere.areas @ bk == pytest.approx(1.0 - cells @ dropped, abs=1e-12)
    assert np.all(bk <= b + 1e-12)
    with pytest.raises(InputError):
        bijectivity_density_top_k(sphere, idx + sphere.n, kept, cells)


def test_dirichlet_density_per_source_vertex_integrates_to_the_energy(sphere):
    g = farthest_point_samples(sphere, 20)
    cells = np.bincount(g.labels, weights=sphere.areas, minlength=g.n)
    rows = _blurred_map(sphere, sphere.vertices[g.indices], 4 * sphere.mean_edge_length**2)
    e = dirichlet_energy(sphere, rows, g.edges, g.weights, cell_areas=cells, debiased=False)
    per_vertex = e.vertex_density(g.labels)
    assert per_vertex.shape == (sphere.n,) and e.total > 0
    assert sphere.areas @ per_vertex == pytest.approx(e.total, rel=1e-10)
    # Each cell carries half of its edges' weighted energies.
    u = 3
    mine = np.any(g.edges == u, axis=1)
    assert e.density[u] * cells[u] == pytest.approx(0.5 * g.weights[mine] @ e.per_edge[mine])


def test_soft_map_sinkhorn_refinement_and_energies(sphere):
    pairs = [[0, 0], [100, 100]]
    res = soft_map(sphere, sphere, pairs, samples=40, k=20, max_iter=15, refine="sinkhorn")
    proj = res.sinkhorn
    rows = res.target_rows()  # prolonged from the coarse target the propagation solved on
    assert res.target_points is not None and rows.shape == (40, sphere.n)
    assert proj is not None and proj.rows is None  # the projected copy is not kept
    assert np.isfinite(proj.residual) and proj.residual < proj.initial_residual
    # The extraction is the mode of the projected rows (landmark rows fixed) ...
    again = sinkhorn_projection(rows, res.cell_areas, sphere.areas, fixed=[0, 1])
    assert again.residual == pytest.approx(proj.residual, rel=1e-6)
    assert np.array_equal(res.sample_correspondence, mode(again.rows, sphere.areas))
    assert np.array_equal(res.correspondence[res.samples], res.sample_correspondence)
    # ... and refine="none" extracts from the soft map itself, same rows.
    plain = extract_correspondence(sphere, sphere, rows, labels=res.labels,
                                   samples=res.samples, cell_areas=res.cell_areas,
                                   edges=res.edges, refine="none")
    assert plain.sinkhorn is None
    assert np.array_equal(plain.sample_correspondence, mode(rows, sphere.areas))
    energies = soft_map_energies(sphere, res)
    b = bijectivity_density(sphere, rows, res.cell_areas)
    np.testing.assert_allclose(energies.bijectivity_density, b, rtol=1e-5)  # float32 rows
    assert energies.bijectivity == pytest.approx(float(sphere.areas @ b**2), rel=1e-6)
    assert energies.bijectivity >= 1.0 - 1e-6  # Cauchy-Schwarz at unit area
    assert sphere.areas @ energies.dirichlet_vertex_density == \
        pytest.approx(res.dirichlet.total, rel=1e-6)
    # Top-k result: b from the kept masses, never above the dense one.
    k = 30
    idx = np.argsort(-rows, axis=1)[:, :k]
    top = dataclasses.replace(res, soft_map=None, prolongation=None, top_indices=idx,
                              top_masses=np.take_along_axis(rows, idx, axis=1))
    bt = soft_map_energies(sphere, top).bijectivity_density
    assert np.all(bt <= b + 1e-6) and sphere.areas @ bt < 1.0
    with pytest.raises(InputError) as err:
        extract_correspondence(sphere, sphere, rows, labels=res.labels,
                               samples=res.samples, cell_areas=res.cell_areas,
                               edges=res.edges, refine="icp")
    assert err.value.field == "refine"
