"""Graph: combinatorial Laplacian, (I + tL)^-1 in closed form, connectivity, validation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from solvers.domains import Graph, domain_from_arrays
from solvers.errors import DomainError


def test_path_laplacian():
    g = Graph(4, [[0, 1], [1, 2], [2, 3]], weights=[1.0, 2.0, 3.0])
    expected = np.array([
        [1.0, -1.0, 0.0, 0.0],
        [-1.0, 3.0, -2.0, 0.0],
        [0.0, -2.0, 5.0, -3.0],
        [0.0, 0.0, -3.0, 3.0],
    ])
    np.testing.assert_allclose(g.laplacian.toarray(), expected)
    np.testing.assert_allclose(g.areas, 0.25)
    assert g.is_connected and g.n_components == 1
    json.dumps(g.summary())


def test_parallel_edges_are_summed():
    g = Graph(2, [[0, 1], [1, 0]], weights=[1.0, 2.5])
    np.testing.assert_allclose(g.laplacian.toarray(), [[3.5, -3.5], [-3.5, 3.5]])


@pytest.mark.parametrize(("w", "t"), [(1.0, 0.5), (3.0, 0.1), (0.2, 7.0)])
def test_two_node_heat_kernel_closed_form(w, t):
    """(I + tL)^-1 with L = w [[1, -1], [-1, 1]] is [[1 + tw, tw], [tw, 1 + tw]] / (1 + 2tw)."""
    g = Graph(2, [[0, 1]], weights=[w])
    expected = np.array([[1 + t * w, t * w], [t * w, 1 + t * w]]) / (1 + 2 * t * w)
    np.testing.assert_allclose(g.heat_kernel(t).apply(np.eye(2)), expected, rtol=1e-12)
    # Substeps: (I + (t/s) L)^-s.
    step = np.linalg.inv(np.eye(2) + (t / 4) * g.laplacian.toarray())
    np.testing.assert_allclose(g.heat_kernel(t, substeps=4).apply(np.eye(2)),
                               np.linalg.matrix_power(step, 4), rtol=1e-12)


def test_heat_kernel_conserves_mass_and_is_positive():
    rng = np.random.default_rng(0)
    n = 40
    edges = np.array([[i, (i + 1) % n] for i in range(n)] + [[0, 20], [5, 33]])
    g = Graph(n, edges, weights=rng.random(len(edges)) + 0.1)
    k = g.heat_kernel(2.0).apply(np.eye(n))
    assert k.min() > 0  # connected graph: (I + tL)^-1 is an M-matrix inverse, all positive
    np.testing.assert_allclose(g.areas @ k, g.areas, rtol=1e-12)
    np.testing.assert_allclose(k, k.T, atol=1e-14)


def test_connectivity():
    g = Graph(5, [[0, 1], [1, 2], [3, 4]])
    assert not g.is_connected and g.n_components == 2
    labels = g.component_labels
    assert labels[0] == labels[1] == labels[2] != labels[3] == labels[4]
    np.testing.assert_allclose(g.component_masses(g.areas), [0.6, 0.4])
    # Heat never crosses components.
    k = g.heat_kernel(1.0).apply(np.eye(5))
    assert np.all(k[:3, 3:] == 0) and np.all(k[3:, :3] == 0)
    isolated = Graph(3, np.zeros((0, 2), dtype=int))
    assert isolated.n_components == 3
    assert Graph(1, []).is_connected


@pytest.mark.parametrize(
    ("args", "kwargs", "field"),
    [
        ((0, [[0, 1]]), {}, "n_nodes"),
        (("x", [[0, 1]]), {}, "n_nodes"),
        ((3, [[0, 3]]), {}, "edges"),
        ((3, [[-1, 2]]), {}, "edges"),
        ((3, [[1, 1]]), {}, "edges"),
        ((3, [[0, 1, 2]]), {}, "edges"),
        ((3, [[0, 1.5]]), {}, "edges"),
        ((3, [[0, 1]]), {"weights": [-1.0]}, "weights"),
        ((3, [[0, 1]]), {"weights": [np.nan]}, "weights"),
        ((3, [[0, 1]]), {"weights": [1.0, 2.0]}, "weights"),
        ((3, [[0, 1]]), {"positions": np.zeros((2, 2))}, "positions"),
        ((3, [[0, 1]]), {"positions": np.full((3, 2), np.inf)}, "positions"),
    ],
)
def test_invalid_graphs_raise_typed_errors(args, kwargs, field):
    with pytest.raises(DomainError) as info:
        Graph(*args, **kwargs)
    assert info.value.field == field


@pytest.mark.parametrize("positions", [None, np.arange(8.0).reshape(4, 2)])
def test_round_trip_through_arrays_keeps_hash(positions):
    g = Graph(4, [[0, 1], [1, 2], [2, 3]], weights=[1.0, 2.0, 0.5], positions=positions)
    rebuilt = domain_from_arrays("graph", g.to_arrays(), g.parameters())
    assert rebuilt.content_hash() == g.content_hash()
    other = Graph(4, [[0, 1], [1, 2], [2, 3]], weights=[1.0, 2.0, 0.6], positions=positions)
    assert other.content_hash() != g.content_hash()
