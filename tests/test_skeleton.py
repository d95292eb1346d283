"""Skeleton layout by Wasserstein propagation (§3.7): a capsule's axis, spot's legs."""

import numpy as np
import pytest
import trimesh
from shared_meshes import load_shared_mesh

from solvers import TriangleMesh
from solvers.convolutional.skeleton import (
    linear_layout,
    position_distributions,
    segment_inside_fraction,
    skeleton_layout,
)
from solvers.errors import InputError


@pytest.fixture(scope="module")
def capsule():
    c = trimesh.creation.capsule(height=2.0, radius=0.35, count=[24, 24])
    return TriangleMesh(c.vertices, c.faces)


def test_capsule_chain_lies_on_the_axis_in_order(capsule):
    z = capsule.vertices[:, 2]
    n = 7
    edges = [(i, i + 1) for i in range(n - 1)]
    ends = {0: [0.0, 0.0, 0.8 * z.min()], n - 1: [0.0, 0.0, 0.8 * z.max()]}
    r = skeleton_layout(capsule, n, edges, ends)
    assert r.converged and r.residual <= 1e-5
    assert np.all(r.winding > 0.99)  # inside the volume
    radius = np.linalg.norm(capsule.vertices[:, :2], axis=1).max()
    assert np.all(np.linalg.norm(r.positions[:, :2], axis=1) < 0.05 * radius)  # near the axis
    assert np.all(np.diff(r.positions[:, 2]) > 0)  # in order along it
    np.testing.assert_allclose(r.positions[[0, -1]], np.array(list(ends.values())))
    # the linear layout of a chain: evenly spaced on the segment
    np.testing.assert_allclose(np.diff(r.linear[:, 2]), (0.8 * (z.max() - z.min())) / 6)
    # symmetric problem, symmetric layout
    np.testing.assert_allclose(r.positions[:, 2], -r.positions[::-1, 2], atol=1e-3)


def test_position_distributions_are_clipped_mvc(capsule):
    x = np.array([[0.0, 0.1, 0.2], [0.05, 0.0, -0.3]])
    M, clipped, err = position_distributions(capsule, x)
    assert np.all(M >= 0) and np.allclose(M.sum(axis=0), 1.0)
    # capsule is convex: MVC are positive, nothing clipped, linear precision exact
    assert np.all(clipped == 0) and np.all(err < 1e-10)


# Hooves of spot (welded, unit-area frame), picked by hand from the lowest vertices.
HOOVES = np.array([[0.09, -0.272, 0.009], [-0.09, -0.272, 0.009],
                   [0.083, -0.271, 0.314], [-0.083, -0.271, 0.314]])


def _loop_skeleton(inner=5):
    """The four hooves (fixed, nodes 0-3) joined front, back and along both sides by
    chains of ``inner`` free nodes: each chain must go up a leg, along the body, down."""
    edges, n = [], 4
    for a, b in ((0, 1), (2, 3), (0, 2), (1, 3)):
        prev = a
        for _ in range(inner):
            edges.append((prev, n))
            prev, n = n, n + 1
        edges.append((prev, b))
    return n, edges


def test_spot_layout_follows_the_legs_where_lines_leave_the_volume():
    mesh = load_shared_mesh("spot.obj", weld=True)
    n, edges = _loop_skeleton()
    fixed = {i: HOOVES[i] for i in range(4)}
    r = skeleton_layout(mesh, n, edges, fixed)  # the default gamma, (4h)^2
    assert r.converged
    free = r.free_nodes
    assert np.all(r.winding > 0.5), r.winding  # every embedded node is inside
    outside_linear = np.mean(r.linear_winding[free] < 0.5)
    assert outside_linear >= 0.5, outside_linear  # straight lines cut under the belly
    inside_bones = segment_inside_fraction(mesh, r.positions, edges)
    linear_bones = segment_inside_fraction(mesh, r.linear, edges)
    assert inside_bones >= 0.9 and linear_bones <= 0.6, (inside_bones, linear_bones)
    np.testing.assert_allclose(r.linear, linear_layout(n, edges, fixed))
    assert np.all(r.clipped[:4] < 0.2) and np.all(r.clipped[4:] == 0)


def test_bad_skeletons_name_the_field(capsule):
    with pytest.raises(InputError) as err:
        skeleton_layout(capsule, 3, [(0, 1), (1, 2)], {0: [0, 0, 5.0]})
    assert err.value.field == "fixed"  # outside the surface
    with pytest.raises(InputError) as err:
        skeleton_layout(capsule, 3, [(0, 1), (1, 2)], {0: [0, 0]})
    assert err.value.field == "fixed[0]"
    with pytest.raises(InputError) as err:
        skeleton_layout(capsule, 3, [(0, 1), (1, 5)], {0: [0, 0, 0]})
    assert err.value.field == "edges"
    with pytest.raises(InputError) as err:  # node 3, 4 not connected to a fixed node
        skeleton_layout(capsule, 5, [(0, 1), (1, 2), (3, 4)], {0: [0, 0, 0]})
    assert err.value.field == "edges"
