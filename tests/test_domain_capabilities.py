"""Domains own their kind: capabilities, coordinates and what differs by kind are answered
by the domain (and by its light representations alike), never by branching on ``kind``."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from solvers.domains import (
    CAPABILITIES,
    DOMAIN_CLASSES,
    Graph,
    Grid,
    PointCloud,
    TriangleMesh,
    domain_class,
    domain_from_arrays,
    kind_supports,
    kinds_supporting,
    supports,
)
from solvers.domains.sketch import DomainSketch
from solvers.errors import DomainError, InputError, UnsupportedDomainError
from solvers.histograms.graphs import as_graph, graph_laplacian

TETRA = ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def _domains():
    rng = np.random.default_rng(0)
    return {
        "mesh": TriangleMesh(*TETRA),
        "grid": Grid([4, 5]),
        "graph": Graph(4, [[0, 1], [1, 2], [2, 3]], positions=rng.random((4, 2))),
        "pointcloud": PointCloud(rng.random((30, 3)), n_neighbors=5),
    }


def test_every_class_lists_known_capabilities_and_kinds_follow():
    for cls in DOMAIN_CLASSES.values():
        assert cls.capabilities <= set(CAPABILITIES), cls
    assert kinds_supporting("faces") == ("mesh",)
    assert kinds_supporting("exact_transport") == ("mesh", "grid", "pointcloud")
    assert kinds_supporting("hop_metric") == ("graph",)
    assert domain_class("grid") is Grid
    with pytest.raises(DomainError):
        domain_class("torus")
    assert not kind_supports("torus", "faces")


def test_light_representations_answer_as_the_domain():
    """A sketch (what decisions read) and the stored kind give the built domain's answer for
    every capability."""
    for kind, domain in _domains().items():
        sketch = DomainSketch.of(domain)
        for capability in CAPABILITIES:
            want = domain.supports(capability)
            assert sketch.supports(capability) == want, (kind, capability)
            assert kind_supports(kind, capability) == want, (kind, capability)
            assert supports(domain, capability) == want


def test_objects_that_are_not_domains_support_nothing():
    assert not supports(sp.eye(3), "faces")
    assert not supports(None, "exact_transport")
    assert not supports(TETRA, "faces")


def test_coordinates_by_kind():
    d = _domains()
    assert d["mesh"].coordinates is d["mesh"].vertices
    assert d["grid"].coordinates.shape == (20, 2)
    assert d["pointcloud"].coordinates is d["pointcloud"].points
    assert d["graph"].coordinates is d["graph"].positions
    assert Graph(3, [[0, 1], [1, 2]]).coordinates is None
    # the extent reads the coordinates: unchanged by a rebuild from the stored arrays
    for domain in d.values():
        again = domain_from_arrays(domain.kind, domain.to_arrays(), domain.parameters())
        assert again.extent == domain.extent


def test_laplacian_variants_and_graphs():
    d = _domains()
    mesh = d["mesh"]
    assert graph_laplacian(mesh, "cotan") is mesh.cotan_laplacian
    assert graph_laplacian(mesh, "robust") is mesh.robust_laplacian
    with pytest.raises(InputError, match="applies to triangle meshes only"):
        graph_laplacian(d["grid"], "cotan")
    with pytest.raises(InputError, match="must be 'auto', 'robust' or 'cotan'"):
        graph_laplacian(d["grid"], "nope")
    assert as_graph(d["graph"], "cotan") is d["graph"]  # a graph is its own graph
    g = as_graph(mesh)
    assert isinstance(g, Graph) and g.positions is mesh.vertices and g.n == mesh.n
    assert np.allclose(g.laplacian.toarray(), mesh.laplacian.toarray())
    assert np.array_equal(d["graph"].heat_mass, np.ones(4))
    assert np.array_equal(mesh.heat_mass, mesh.areas)


def test_export_geometry_by_kind():
    d = _domains()
    mesh = d["mesh"].export_geometry()
    assert np.array_equal(mesh.faces, d["mesh"].faces) and mesh.edges is None
    grid = d["grid"].export_geometry()
    assert grid.positions.shape == (20, 3) and len(grid.faces) == 2 * 3 * 4
    assert d["graph"].export_geometry().edges is d["graph"].edges
    with pytest.raises(UnsupportedDomainError, match="no node positions"):
        Graph(3, [[0, 1], [1, 2]]).export_geometry()
    cloud = d["pointcloud"].export_geometry()
    assert cloud.faces is None and cloud.edges is None
    assert np.array_equal(cloud.positions, d["pointcloud"].to_arrays()["points"])


def test_service_views_and_operations_ask_the_capability():
    from service.operations.base import Operation, OperationRequest, view_of_domain

    for kind, domain in _domains().items():
        view = view_of_domain(domain)
        for capability in CAPABILITIES:
            assert view.supports(capability) == domain.supports(capability), (kind, capability)
        assert (view.load_faces is not None) == domain.supports("faces")
    op = Operation("x", "x", "x", OperationRequest, print, print, "faces")
    assert op.kinds == ("mesh",)
    assert Operation("y", "y", "y", OperationRequest, print, print).kinds == tuple(DOMAIN_CLASSES)
    with pytest.raises(ValueError, match="not a domain capability"):
        Operation("z", "z", "z", OperationRequest, print, print, ("mesh",))
