"""TriangleMesh: loading, topology, operators and heat kernels, checked on every shared mesh.

Ground truth: the topology stated in ../shared/meshes/README.md, closed forms on a
single triangle and on linear functions, an independent vertex-link computation of
non-manifold vertices, and algebraic identities of the operators.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import trimesh
from scipy.sparse.csgraph import connected_components
from shared_meshes import MESH_FILES, MESHES_DIR, load_shared_mesh

from solvers.domains import TriangleMesh, domain_from_arrays, load_mesh
from solvers.errors import DomainError, InputError, MeshFormatError
from solvers.kernels import ImplicitEulerHeatKernel

ALL_MESHES = (
    "alligator.obj", "beetle.obj", "cheburashka.obj", "cow.obj", "fandisk.obj", "homer.obj",
    "nefertiti.obj", "rocker-arm.obj", "spot.obj", "stanford-bunny.obj", "suzanne.obj",
    "teapot.obj", "woody.obj",
)
MULTI_COMPONENT = ("beetle.obj", "suzanne.obj", "teapot.obj")
# Closed surfaces per the meshes' README; cow has one pinched (non-manifold) vertex.
CLOSED_GENUS = {
    "spot.obj": 0, "cheburashka.obj": 0, "fandisk.obj": 0, "homer.obj": 0,
    "nefertiti.obj": 0, "rocker-arm.obj": 1,
}
OPEN_GENUS0 = ("woody.obj", "alligator.obj", "stanford-bunny.obj")
BIG = ("stanford-bunny.obj", "nefertiti.obj")


def test_all_shared_meshes_are_present(meshes_dir):
    # Guards against silently empty parametrizations when ../shared is missing.
    assert tuple(MESH_FILES) == ALL_MESHES


# --------------------------------------------------------------------------- loading


@pytest.mark.parametrize("name", MESH_FILES)
def test_load_unit_area_and_lumped_areas(name):
    m = load_shared_mesh(name)
    assert m.n > 0 and m.faces.shape[1] == 3
    assert np.all(m.face_areas > 0)
    assert m.face_areas.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.all(m.areas > 0)
    assert m.areas.sum() == pytest.approx(1.0, abs=1e-12)
    # Rescaling is a pure similarity: input lengths = stored lengths * length_scale.
    np.testing.assert_allclose(m.vertices * m.length_scale, m.to_arrays()["vertices"],
                               rtol=0, atol=1e-12 * np.abs(m.to_arrays()["vertices"]).max())
    # Lumped areas: a third of the incident face areas, also per connected component.
    comp_faces = np.bincount(m.component_labels[m.faces[:, 0]], weights=m.face_areas,
                             minlength=m.n_components)
    np.testing.assert_allclose(m.component_masses(m.areas), comp_faces, rtol=1e-12)
    # Every vertex line of the OBJ survives (OBJ positions are already welded) unless
    # the loader reports it as unreferenced.
    with open(MESHES_DIR / name, "rb") as fh:
        n_v_lines = sum(1 for line in fh if line.startswith(b"v "))
    assert m.n == n_v_lines - m.diagnostics.removed_unreferenced_vertices
    json.dumps(m.summary())  # JSON-serializable


@pytest.mark.parametrize("name", MESH_FILES)
def test_euler_characteristic_and_genus(name):
    m = load_shared_mesh(name)
    corners = m.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    n_edges = len(np.unique(np.sort(corners, axis=1), axis=0))
    chi = m.n - n_edges + m.n_faces
    assert m.euler_characteristic == chi
    if m.is_manifold:
        # chi = sum over components of 2 - 2 g - b
        b = len(m.boundary_loops)
        assert chi == 2 * m.n_components - 2 * m.genus - b
        assert m.genus >= 0
    if name in CLOSED_GENUS:
        assert m.is_closed and m.is_manifold and m.n_components == 1
        assert m.genus == CLOSED_GENUS[name]
        assert chi == 2 - 2 * CLOSED_GENUS[name]
        assert m.boundary_loops == []
    if name in OPEN_GENUS0:
        assert not m.is_closed and m.n_components == 1 and m.genus == 0
        assert len(m.boundary_loops) >= 1
        assert chi == 2 - len(m.boundary_loops)
        loop_vertices = np.concatenate(m.boundary_loops)
        assert len(loop_vertices) == m.diagnostics.boundary_edges  # each loop is a cycle


def test_spot_welds_to_one_closed_genus0_surface():
    m = load_shared_mesh("spot.obj")
    assert (m.n, m.n_faces) == (2930, 5856)
    assert m.euler_characteristic == 2 and m.genus == 0
    assert m.is_closed and m.is_manifold and m.n_components == 1


def test_rocker_arm_is_genus_one():
    m = load_shared_mesh("rocker-arm.obj")
    assert m.euler_characteristic == 0 and m.genus == 1 and m.is_closed


def _link_nonmanifold_vertices(faces: np.ndarray, n: int) -> int:
    """Vertices whose link (the edges opposite them in incident faces) is disconnected.

    Link nodes are the pairs (vertex, neighbour); each face corner (v; b, c) joins
    (v, b) to (v, c); one global connected-components pass labels every link piece.
    """
    center = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
    b = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    c = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    pairs = np.concatenate([np.stack([center, b], 1), np.stack([center, c], 1)])
    keys, node = np.unique(pairs, axis=0, return_inverse=True)
    node = node.reshape(-1)
    k = len(center)
    graph = sp.coo_matrix((np.ones(k), (node[:k], node[k:])), shape=(len(keys), len(keys)))
    _, piece = connected_components(graph, directed=False)
    pieces_per_vertex = np.bincount(np.unique(np.stack([keys[:, 0], piece], 1), axis=0)[:, 0],
                                    minlength=n)
    return int((pieces_per_vertex > 1).sum())


@pytest.mark.parametrize("name", ["cow.obj", "teapot.obj", "spot.obj", "woody.obj"])
def test_nonmanifold_vertices_match_link_computation(name):
    m = load_shared_mesh(name)
    assert m.diagnostics.nonmanifold_edges == 0  # the link criterion needs manifold edges
    expected = _link_nonmanifold_vertices(m.faces, m.n)
    assert m.diagnostics.nonmanifold_vertices == expected
    if expected:
        assert m.genus is None and not m.is_manifold
        assert any("non-manifold vertices" in w for w in m.diagnostics.warnings)


def test_cow_pinched_vertex_is_reported():
    m = load_shared_mesh("cow.obj")
    # A closed surface with chi = 1 cannot be a manifold: the loader must notice.
    assert m.is_closed and m.euler_characteristic == 1
    assert m.diagnostics.nonmanifold_vertices == 1 and m.genus is None


@pytest.mark.parametrize("name", MULTI_COMPONENT)
def test_multi_component_meshes_are_reported(name):
    m = load_shared_mesh(name)
    assert m.n_components > 1
    assert any("connected components" in w for w in m.diagnostics.warnings)
    assert m.summary()["components"] == m.n_components
    labels = m.component_labels
    assert labels.shape == (m.n,) and set(np.unique(labels)) == set(range(m.n_components))
    # No edge crosses components, and every component carries positive area.
    assert np.all(labels[m.edges[:, 0]] == labels[m.edges[:, 1]])
    per_comp = m.component_masses(m.areas)
    assert np.all(per_comp > 0) and per_comp.sum() == pytest.approx(1.0)
    # The Laplacian's connectivity agrees: its null space has one constant per component.
    n_lap, _ = connected_components(m.laplacian, directed=False)
    assert n_lap == m.n_components


# --------------------------------------------------------------------------- operators


@pytest.mark.parametrize("name", MESH_FILES)
def test_laplacians_symmetric_annihilate_constants(name):
    m = load_shared_mesh(name)
    ones = np.ones(m.n)
    for lap in (m.cotan_laplacian, m.robust_laplacian):
        scale = abs(lap).max()
        assert abs(lap - lap.T).max() <= 1e-12 * scale
        assert np.abs(lap @ ones).max() <= 1e-12 * scale * 20
        assert np.all(lap.diagonal() > 0)
    assert m.laplacian is m.robust_laplacian  # robust by default


@pytest.mark.parametrize("name", MESH_FILES)
def test_robust_laplacian_is_an_m_matrix(name):
    """Intrinsic-Delaunay weights are non-negative, so off-diagonals are <= 0.

    robust-laplacian's mollification leaves round-off sized positive entries
    (measured <= 1e-6 of the median weight); anything larger is a real violation.
    """
    lap = load_shared_mesh(name).robust_laplacian.tocoo()
    off = lap.row != lap.col
    typical = np.median(np.abs(lap.data[off]))
    assert lap.data[off].max() <= 1e-5 * typical


@pytest.mark.parametrize("name", MESH_FILES)
def test_cotan_laplacian_is_gradient_gram_and_div_grad(name):
    m = load_shared_mesh(name)
    lap = m.cotan_laplacian
    gram = m.gradient.T @ sp.diags(np.repeat(m.face_areas, 3)) @ m.gradient
    scale = abs(lap).max()
    assert abs(gram - lap).max() <= 1e-10 * scale
    assert abs(m.divergence @ m.gradient + lap).max() <= 1e-10 * scale
    assert m.gradient.shape == (3 * m.n_faces, m.n)
    assert m.divergence.shape == (m.n, 3 * m.n_faces)


@pytest.mark.parametrize("name", MESH_FILES)
def test_laplacians_positive_semidefinite(name):
    """PSD, three ways.

    cotan: L = G^T diag(A_f) G with A_f > 0 (tested above) is a Gram matrix.
    robust: Gershgorin, since row sums are 0, lambda_min >= -2 max_i sum_j max(L_ij, 0).
    Both, on meshes up to 15k vertices: the smallest generalized eigenvalue of
    L x = lambda D_a x is 0 to round-off (shift-invert Lanczos around -1).
    """
    m = load_shared_mesh(name)
    robust = m.robust_laplacian.tocoo()
    positive_off = np.where(robust.row != robust.col, np.maximum(robust.data, 0), 0)
    gershgorin = -2 * np.bincount(robust.row, weights=positive_off, minlength=m.n).max()
    assert gershgorin >= -1e-5 * np.median(m.robust_laplacian.diagonal())
    if name in BIG:
        return
    mass = sp.diags(m.areas)
    for lap in (m.robust_laplacian, m.cotan_laplacian):
        smallest = spla.eigsh(lap.tocsc(), k=1, M=mass, sigma=-1.0, which="LM",
                              return_eigenvectors=False)[0]
        assert -1e-9 <= smallest <= 1e-9  # >= 0, and constants are in the kernel


def test_single_right_triangle_closed_form():
    m = TriangleMesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    # Input area 1/2 -> rescaled to 1 by lengths * sqrt(2).
    assert m.length_scale == pytest.approx(np.sqrt(0.5))
    np.testing.assert_allclose(m.face_areas, [1.0])
    np.testing.assert_allclose(m.areas, [1 / 3] * 3)
    # Angles: 90 deg at vertex 0 (cot 0), 45 deg at 1 and 2 (cot 1); L_ij = -cot/2.
    expected = np.array([[1.0, -0.5, -0.5], [-0.5, 0.5, 0.0], [-0.5, 0.0, 0.5]])
    np.testing.assert_allclose(m.cotan_laplacian.toarray(), expected, atol=1e-14)
    np.testing.assert_allclose(m.robust_laplacian.toarray(), expected, atol=1e-9)
    np.testing.assert_allclose(m.face_normals, [[0, 0, 1]], atol=1e-15)
    # The gradient of a linear function is exact: f = 2x - 3y + 5 (stored coordinates).
    f = 2 * m.vertices[:, 0] - 3 * m.vertices[:, 1] + 5
    np.testing.assert_allclose(m.gradient @ f, [2, -3, 0], atol=1e-13)
    assert m.euler_characteristic == 1 and m.genus == 0 and not m.is_closed
    assert len(m.boundary_loops) == 1 and sorted(m.boundary_loops[0]) == [0, 1, 2]


def test_linear_function_gradient_is_tangential_projection_on_real_mesh():
    m = load_shared_mesh("spot.obj")
    c = np.array([0.3, -1.2, 2.0])
    grad = (m.gradient @ (m.vertices @ c)).reshape(-1, 3)
    n = m.face_normals
    expected = c[None, :] - (n @ c)[:, None] * n
    np.testing.assert_allclose(grad, expected, atol=1e-9 * np.linalg.norm(c))
    # Weak form: -div grad f = L f for the same linear function.
    np.testing.assert_allclose(-(m.divergence @ grad.ravel()),
                               m.cotan_laplacian @ (m.vertices @ c), atol=1e-9)


# --------------------------------------------------------------------------- heat kernels


def _delta_columns(m: TriangleMesh, n_random: int = 4, n_obtuse: int = 4,
                   seed: int = 0) -> np.ndarray:
    """Unit-mass densities at random vertices and at the ends of the ``n_obtuse`` most
    positive cotan off-diagonals (obtuse angle pairs, where negativity appears)."""
    lap = m.cotan_laplacian.tocoo()
    off = np.where(lap.row != lap.col, lap.data, -np.inf)
    worst = np.argsort(-off)[:n_obtuse]
    rng = np.random.default_rng(seed)
    idx = np.unique(np.concatenate([lap.row[worst], lap.col[worst],
                                    rng.choice(m.n, n_random, replace=False)]))
    x = np.zeros((m.n, len(idx)))
    x[idx, np.arange(len(idx))] = 1.0 / m.areas[idx]
    return x


@pytest.mark.parametrize("name", MESH_FILES)
def test_robust_heat_kernel_positive_conservative_symmetric(name):
    m = load_shared_mesh(name)
    t = m.mean_edge_length**2
    kernel = m.heat_kernel(t)
    assert m.heat_kernel(t) is kernel  # factored once, cached
    deltas = _delta_columns(m)
    y = kernel.apply(deltas)
    assert y.min() >= -1e-12 * y.max()
    rng = np.random.default_rng(1)
    x = rng.random((m.n, 3))
    hx = kernel.apply(x)
    # Mass conservation a^T H x = a^T x (implicit Euler: exact up to the solve).
    np.testing.assert_allclose(m.areas @ hx, m.areas @ x, rtol=1e-10)
    np.testing.assert_allclose(m.areas @ y, m.areas @ deltas, rtol=1e-10)
    # Symmetry in the a-weighted inner product: y^T D_a H x = x^T D_a H y.
    lhs = x[:, 1] @ (m.areas * hx[:, 0])
    rhs = x[:, 0] @ (m.areas * hx[:, 1])
    assert lhs == pytest.approx(rhs, rel=1e-10)
    # A vector input gives the corresponding column.
    np.testing.assert_allclose(kernel.apply(x[:, 2]), hx[:, 2], rtol=1e-12, atol=0)


@pytest.mark.parametrize(
    ("name", "edge_factor"),
    [("rocker-arm.obj", 0.1), ("stanford-bunny.obj", 1.0), ("nefertiti.obj", 1.0)],
)
def test_cotan_kernel_goes_negative_where_robust_does_not(name, edge_factor):
    """The issue's measurement: (D_a + tL)^-1 D_a has negative entries with the plain
    cotan L on rocker-arm, bunny and nefertiti, none with the intrinsic-Delaunay L.

    Measured minima (relative to the max over deltas at the 16 most obtuse spots) at
    t = edge_factor * h^2, h the mean edge length: rocker-arm (t = 0.1 h^2) -1.6e-3,
    bunny (t = h^2) -4.5e-2, nefertiti (t = h^2) -4.7e-3.  At t = h^2 rocker-arm's
    cotan kernel is only -3.5e-15 (round-off), hence 0.1 h^2 there.  The robust
    minima are positive (>= 1e-93 relative) in all three cases.
    """
    m = load_shared_mesh(name)
    t = edge_factor * m.mean_edge_length**2
    deltas = _delta_columns(m, n_random=0, n_obtuse=16)
    cotan = ImplicitEulerHeatKernel(m.areas, m.cotan_laplacian, t).apply(deltas)
    robust = m.heat_kernel(t).apply(deltas)
    assert cotan.min() < -1e-3 * cotan.max()
    assert robust.min() >= -1e-12 * robust.max()


def test_heat_kernel_substeps_and_cotan_option():
    m = load_shared_mesh("woody.obj")
    t = 4 * m.mean_edge_length**2
    one = m.heat_kernel(t, substeps=1)
    four = m.heat_kernel(t, substeps=4)
    assert one is not four
    x = _delta_columns(m)
    # Four steps of tau = t/4 equal four applications of the tau-kernel.
    quarter = m.heat_kernel(t / 4)
    y = x
    for _ in range(4):
        y = quarter.apply(y)
    np.testing.assert_allclose(four.apply(x), y, rtol=1e-9, atol=1e-12 * np.abs(y).max())
    cot = TriangleMesh(m.to_arrays()["vertices"], m.faces, laplacian="cotan")
    assert cot.laplacian is cot.cotan_laplacian
    assert cot.content_hash() != m.content_hash()


# --------------------------------------------------------------------------- files and hashing


def test_same_mesh_loaded_twice_same_hash(meshes_dir):
    a = load_mesh(meshes_dir / "spot.obj")
    with open(meshes_dir / "spot.obj", "rb") as fh:
        data = fh.read()
    b = load_mesh(data, file_type="obj")
    c = load_mesh(io.BytesIO(data), file_type="obj")
    assert a.content_hash() == b.content_hash() == c.content_hash()
    assert a.content_hash() != load_shared_mesh("woody.obj").content_hash()
    rebuilt = domain_from_arrays("mesh", a.to_arrays(), a.parameters())
    assert rebuilt.content_hash() == a.content_hash()
    np.testing.assert_array_equal(rebuilt.faces, a.faces)


@pytest.mark.parametrize("fmt", ["stl", "ply", "off", "glb"])
def test_other_formats_round_trip(fmt):
    spot = load_shared_mesh("spot.obj")
    exported = trimesh.Trimesh(spot.to_arrays()["vertices"], spot.faces,
                               process=False).export(file_type=fmt)
    data = exported.encode() if isinstance(exported, str) else exported
    m = load_mesh(data, file_type=fmt)
    # STL stores three corners per triangle; welding by position restores the surface.
    assert (m.n, m.n_faces) == (spot.n, spot.n_faces)
    assert m.is_closed and m.genus == 0 and m.euler_characteristic == 2
    assert m.length_scale == pytest.approx(spot.length_scale, rel=1e-6)


def test_stl_cube_is_welded():
    data = trimesh.creation.box(extents=(1.0, 2.0, 3.0)).export(file_type="stl")
    m = load_mesh(data, file_type="stl")
    assert (m.n, m.n_faces) == (8, 12)
    assert m.diagnostics.welded_vertices == 36 - 8
    assert m.is_closed and m.genus == 0 and m.euler_characteristic == 2
    assert m.length_scale**2 == pytest.approx(2 * (1 * 2 + 2 * 3 + 1 * 3))
    unwelded = load_mesh(data, file_type="stl", weld=False)
    assert unwelded.n == 36 and unwelded.n_components == 12


_TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


@pytest.mark.parametrize(
    ("data", "file_type", "error", "field", "words"),
    [
        (b"", "obj", MeshFormatError, "file", "empty"),
        (b"\x00\x9f\x01garbage\xff" * 200, "obj", MeshFormatError, "file", "not text"),
        (b"\x00\x9f\x01garbage\xff" * 200, "stl", MeshFormatError, "file", "binary"),
        (b"\x00\x9f\x01garbage\xff" * 200, "ply", MeshFormatError, "file", "PLY"),
        (b"\x00\x9f\x01garbage\xff" * 200, "off", MeshFormatError, "file", "not text"),
        (b"\x00\x9f\x01garbage\xff" * 200, "glb", MeshFormatError, "file", "GLB"),
        (b"hello\nthis is not a mesh\n", "obj", MeshFormatError, "file", "no triangles"),
        (_TRI.encode(), "obj", MeshFormatError, "file", "no triangles"),
        (_TRI.encode(), "xyz", MeshFormatError, "file", "unsupported"),
        ((_TRI + "f 1 2 9\n").encode(), "obj", MeshFormatError, "file", "out of bounds"),
        (b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "obj", DomainError, "vertices", "NaN"),
        (b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "obj", DomainError, "faces", "degenerate"),
    ],
)
def test_broken_files_raise_typed_errors(data, file_type, error, field, words):
    with pytest.raises(error) as info:
        load_mesh(data, file_type=file_type)
    assert info.value.field == field
    assert words.lower() in str(info.value).lower()
    assert isinstance(info.value, InputError)  # the service maps these to 4xx


def test_missing_file_and_extension(tmp_path):
    with pytest.raises(MeshFormatError, match="no such file") as info:
        load_mesh(tmp_path / "missing.obj")
    assert info.value.field == "file"
    path = tmp_path / "mesh.txt"
    path.write_text(_TRI + "f 1 2 3\n")
    with pytest.raises(MeshFormatError, match="unsupported mesh format 'txt'"):
        load_mesh(path)
    assert load_mesh(path, file_type="obj").n == 3


def test_text_file_objects_and_bad_sources():
    assert load_mesh(io.StringIO(_TRI + "f 1 2 3\n"), file_type="obj").n_faces == 1
    with pytest.raises(MeshFormatError) as info:
        load_mesh(12345, file_type="obj")
    assert info.value.field == "file"


def test_latin1_obj_comment_is_read():
    data = ("# caf\u00e9 mod\u00e8le\n" + _TRI + "f 1 2 3\n").encode("latin-1")
    assert load_mesh(data, file_type="obj").n_faces == 1


@pytest.mark.parametrize(
    ("vertices", "faces", "field", "words"),
    [
        ([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], "vertices", "NaN"),
        ([[0, 0, 0], [1, np.inf, 0], [0, 1, 0]], [[0, 1, 2]], "vertices", "vertex 1"),
        ([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]], "vertices", "shape"),
        (np.zeros((0, 3)), [[0, 1, 2]], "vertices", "shape"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]], "faces", "[0, 2]"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[-1, 1, 2]], "faces", "[0, 2]"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 3, 2]], "faces", "triangles"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2.5]], "faces", "integers"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.zeros((0, 3), int), "faces", "triangles"),
        ([["a", 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], "vertices", "numeric"),
    ],
)
def test_broken_arrays_raise_typed_errors(vertices, faces, field, words):
    with pytest.raises(DomainError) as info:
        TriangleMesh(vertices, faces)
    assert info.value.field == field
    assert words.lower() in str(info.value).lower()


def test_ragged_faces_and_bad_laplacian_kind():
    verts = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]
    with pytest.raises(DomainError) as info:
        TriangleMesh(verts, [[0, 1, 2], [1, 3]])
    assert info.value.field == "faces"
    with pytest.raises(DomainError) as info:
        TriangleMesh(verts, [[0, 1, 2]], laplacian="fem")
    assert info.value.field == "laplacian"


def test_degenerate_and_duplicate_faces_are_removed_and_reported():
    verts = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [5, 5, 5]]
    faces = [[0, 1, 2], [2, 1, 0], [0, 1, 3], [1, 1, 2]]
    m = TriangleMesh(verts, faces)
    d = m.diagnostics
    assert (d.removed_degenerate_faces, d.removed_duplicate_faces) == (2, 1)
    assert d.removed_unreferenced_vertices == 2 and m.n == 3 and m.n_faces == 1
    assert any("degenerate" in w for w in d.warnings)
