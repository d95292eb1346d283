"""Welding merges coincident vertices but keeps the file's vertex order, so indices that
refer to the file (landmarks, ground-truth maps, picks) still refer to the same points."""

from __future__ import annotations

import numpy as np
import trimesh

from solvers import load_mesh


def test_off_without_duplicates_keeps_every_index(meshes_dir):
    path = meshes_dir / "pairs" / "cat-00.off"
    raw = trimesh.load(path, process=False)
    welded = load_mesh(path)  # PLY/OFF are welded by position by default
    assert welded.diagnostics.welded_vertices == 0 and welded.n == len(raw.vertices)
    np.testing.assert_array_equal(welded.faces, raw.faces)
    scale = np.linalg.norm(welded.vertices[1] - welded.vertices[0]) / np.linalg.norm(
        raw.vertices[1] - raw.vertices[0])
    np.testing.assert_allclose((welded.vertices - welded.vertices[0]) / scale,
                               raw.vertices - raw.vertices[0], atol=1e-9)


def test_duplicates_merge_into_their_first_occurrence(tmp_path):
    # two triangles of a square written with the shared edge duplicated, vertex 0 last
    v = np.array([[1, 1, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0]], float)
    f = np.array([[5, 1, 2], [0, 4, 3]])
    path = tmp_path / "square.ply"
    trimesh.Trimesh(v, f, process=False).export(path)
    mesh = load_mesh(path)
    assert mesh.diagnostics.welded_vertices == 2 and mesh.n == 4
    # order of first appearance in the file: (1,1,0), (1,0,0), (0,1,0), (0,0,0)
    expected = np.array([[1, 1, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0]], float)
    got = (mesh.vertices - mesh.vertices.min(axis=0)) / np.ptp(mesh.vertices, axis=0).max()
    np.testing.assert_allclose(got, expected, atol=1e-12)
    np.testing.assert_array_equal(mesh.faces, [[3, 1, 2], [0, 2, 1]])
