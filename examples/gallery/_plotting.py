"""Small offscreen pictures of meshes with matplotlib, shared by the gallery examples.

``mesh_axes`` draws a shaded surface colored by per-vertex or per-face values (painter's
algorithm over a 2-D projection: quick and clear for meshes of a few 10k faces), and
``flow_arrows`` adds per-face vectors seen from the same view.  ``shared_mesh`` finds the
real test meshes beside the repository (``../shared/meshes``; ``OTGEO_MESHES`` overrides).
"""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection

ROOT = Path(__file__).resolve().parents[2]
MESHES = Path(os.environ.get("OTGEO_MESHES", ROOT.parent / "shared" / "meshes"))


def shared_mesh(name: str, **kwargs):
    """Load ``name`` from the shared meshes (``spot.obj``, ``pairs/cat-00.off``, ...)."""
    from solvers import load_mesh

    return load_mesh(MESHES / name, **kwargs)


class View:
    """An orthographic camera turned ``azim`` degrees about the mesh's ``up`` axis and
    raised ``elev`` degrees above the horizon; maps points to (screen x, screen y, depth)."""

    def __init__(self, vertices: np.ndarray, elev: float = 20.0, azim: float = 30.0,
                 up: int = 1):
        self.axes = [(up + 1) % 3, (up + 2) % 3, up]  # a right-handed frame with up last
        self.center = np.asarray(vertices).mean(axis=0)
        a, e = np.radians(azim), np.radians(elev)
        turn = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0],
                         [0.0, 0.0, 1.0]])
        tilt = np.array([[1.0, 0.0, 0.0], [0.0, np.sin(e), np.cos(e)],
                         [0.0, np.cos(e), -np.sin(e)]])  # rows: screen x, screen y, depth
        self.matrix = tilt @ turn

    def vectors(self, vecs: np.ndarray) -> np.ndarray:
        return np.asarray(vecs)[:, self.axes] @ self.matrix.T

    def __call__(self, points: np.ndarray) -> np.ndarray:
        return self.vectors(np.asarray(points) - self.center)

    @property
    def forward(self) -> np.ndarray:
        """The viewing direction (increasing depth) in mesh coordinates."""
        world = np.zeros(3)
        world[self.axes] = self.matrix[2]
        return world


def mesh_axes(ax, mesh, values=None, *, view: View | None = None, cmap="viridis",
              vmin=None, vmax=None, color=(0.8, 0.8, 0.82), title: str | None = None,
              alpha: float = 1.0, colors=None):
    """Draw ``mesh`` on ``ax`` colored by ``values`` (``(V,)`` or ``(F,)``), or by RGB
    ``colors`` ``(V, 3)`` in [0, 1]; returns the view and the color mapping (for a
    colorbar)."""
    verts, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    view = view or View(verts)
    p = view(verts)
    tri = p[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # screen frame
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-30
    light = np.array([-0.4, 0.6, -0.7]) / np.linalg.norm([-0.4, 0.6, -0.7])
    shade = 0.3 + 0.7 * np.abs(normal @ light)
    mapper = None
    if colors is not None:
        rgb = np.asarray(colors, float)[faces].mean(axis=1)
    elif values is None:
        rgb = np.tile(np.asarray(color, float), (len(faces), 1))
    else:
        values = np.asarray(values, float)
        face_values = values[faces].mean(axis=1) if len(values) == len(verts) else values
        lo = np.nanmin(face_values) if vmin is None else vmin
        hi = np.nanmax(face_values) if vmax is None else vmax
        mapper = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(lo, hi))
        rgb = mapper.to_rgba(face_values)[:, :3]
    rgb = np.clip(rgb * shade[:, None], 0, 1)
    order = np.argsort(tri[:, :, 2].mean(axis=1))[::-1]  # far faces first
    edges = rgb[order] if alpha == 1.0 else "none"
    ax.add_collection(PolyCollection(tri[order, :, :2], facecolors=rgb[order],
                                     edgecolors=edges, linewidths=0.2, alpha=alpha))
    ax.set_xlim(p[:, 0].min(), p[:, 0].max())
    ax.set_ylim(p[:, 1].min(), p[:, 1].max())
    ax.set_aspect("equal")
    ax.axis("off")
    if title:
        ax.set_title(title, fontsize=10)
    return view, mapper


def visible_faces(mesh, view: View) -> np.ndarray:
    """Faces whose normal points towards the viewer (for arrows and markers)."""
    tri = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return normal @ view.forward < 0


def flow_arrows(ax, mesh, flow: np.ndarray, view: View, *, count: int = 400,
                length: float = 0.04, color="k"):
    """Per-face vectors ``flow`` ``(F, 3)`` as arrows from the centroids of about ``count``
    visible faces (the strongest first), the longest ``length`` units long."""
    faces = np.asarray(mesh.faces)
    centroid = np.asarray(mesh.vertices)[faces].mean(axis=1)
    norm = np.linalg.norm(flow, axis=1)
    strong = np.percentile(norm, 98)  # a few faces beside the sources carry far more
    visible = np.flatnonzero(visible_faces(mesh, view) & (norm > 0.1 * strong))
    rng = np.random.default_rng(0)  # an even spread of the faces that carry flow
    keep = np.sort(rng.choice(visible, size=min(count, len(visible)), replace=False))
    flow = flow * (length / strong) / np.maximum(1.0, norm / strong)[:, None]
    c, v = view(centroid[keep]), view.vectors(flow[keep])
    ax.quiver(c[:, 0], c[:, 1], v[:, 0], v[:, 1], color=color, angles="xy",
              scale_units="xy", scale=1.0, width=0.003, headwidth=3.5, zorder=3)


def face_to_vertex(mesh, face_values: np.ndarray) -> np.ndarray:
    """Area-weighted mean of per-face values around each vertex (for smooth shading)."""
    faces = np.asarray(mesh.faces)
    tri = np.asarray(mesh.vertices)[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = np.zeros(len(mesh.vertices))
    weight = np.zeros(len(mesh.vertices))
    for corner in range(3):
        np.add.at(total, faces[:, corner], area * face_values)
        np.add.at(weight, faces[:, corner], area)
    return total / np.maximum(weight, 1e-30)


def mark_vertices(ax, mesh, vertices, view: View, color="red", size=30):
    p = view(np.asarray(mesh.vertices)[np.atleast_1d(vertices)])
    ax.scatter(p[:, 0], p[:, 1], s=size, c=color, zorder=4, edgecolors="white")
