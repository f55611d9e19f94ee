"""The 3-D view the mesh pictures share (:mod:`tasks.report.mesh`, :mod:`tasks.report.deck_mesh`): the
visible outer surface of a mesh in an orthographic view, shaded by the angle to the light, its axes at equal
scale, and the pictures' file writer. Matplotlib with the Agg backend (no display).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from fe_core.surface import boundary_faces, dof_arrows, face_normals  # noqa: E402

__all__ = ["MeshView", "ELEVATION", "AZIMUTH", "DPI"]

DPI = 110
#: Viewing angles (degrees) and the light's direction (from the viewer's upper left).
ELEVATION, AZIMUTH = 24.0, -58.0


class MeshView:
    """The visible outer surface of a model's mesh, computed once for several pictures.

    Attributes
    ----------
    polygons : ndarray, shape (n_visible, 3 or 4, 3), m
        Corner coordinates of the faces that look towards the viewer.
    cell : ndarray, shape (n_visible,), int
        The cell of each face.
    shade : ndarray, shape (n_visible,)
        Brightness factor in [0.45, 1] from the angle between the face and the light.
    n_boundary : int
        Boundary faces before back-face culling.
    """

    def __init__(self, model, elevation: float = ELEVATION, azimuth: float = AZIMUTH):
        nodes = model.mesh.nodes
        faces, owner = boundary_faces(nodes, model.mesh.cells)
        normals = face_normals(nodes, faces)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        e, a = np.radians(elevation), np.radians(azimuth)
        eye = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        visible = normals @ eye > 0.0
        light = eye + np.array([-np.sin(a), np.cos(a), 0.0]) * 0.4 + np.array([0.0, 0.0, 0.5])
        light /= np.linalg.norm(light)
        self.elevation, self.azimuth = elevation, azimuth
        self.n_boundary = faces.shape[0]
        self.polygons = nodes[faces[visible]]
        self.cell = owner[visible]
        self.shade = 0.45 + 0.55 * np.clip(normals[visible] @ light, 0.0, 1.0)
        self.lo, self.hi = nodes.min(axis=0), nodes.max(axis=0)
        self.segment = np.asarray(model.cell_segment)[self.cell]     # of each visible face (-1: remainder)
        self.cell_segments = np.asarray(model.cell_segment)
        self.n_cells = model.mesh.n_cells
        self.lines = np.zeros((0, 2, 3))                             # beams (a deck's: tasks/report/deck_mesh.py)
        self.line_segment = np.zeros(0, dtype=np.int64)

    def arrows(self, model, vector):
        """Where a free-DOF vector acts (:func:`fe_core.surface.dof_arrows`)."""
        return dof_arrows(model, vector)

    @property
    def size(self) -> float:
        """Largest extent of the model, m."""
        return float(np.max(self.hi - self.lo))

    def axes(self, fig: Figure, position, title: str):
        ax = fig.add_subplot(*np.atleast_1d(position), projection="3d")
        ax.set_proj_type("ortho")
        ax.view_init(elev=self.elevation, azim=self.azimuth)
        ax.computed_zorder = False  # markers stay above the surface (the painter would hide them)
        span = np.maximum(self.hi - self.lo, 1e-3 * self.size)
        pad = 0.08 * self.size
        for setter, lo, hi in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), self.lo - pad, self.hi + pad):
            setter(lo, hi)
        ax.set_box_aspect(span + 2 * pad)  # equal scale on all three axes
        ax.set_xlabel("x (m)", fontsize=8, labelpad=6)
        ax.set_ylabel("y (m)", fontsize=8, labelpad=6)
        ax.set_zlabel("z (m)", fontsize=8, labelpad=2)
        ax.tick_params(labelsize=7)
        ax.set_title(title, fontsize=10)
        return ax

    def draw(self, ax, rgba: np.ndarray) -> None:
        """The visible faces in colours ``rgba`` (n_visible, 4), shaded."""
        shaded = rgba.copy()
        shaded[:, :3] *= self.shade[:, None]
        poly = Poly3DCollection(self.polygons, facecolors=shaded, edgecolors=(0, 0, 0, 0.25), linewidths=0.15,
                                zorder=1)
        ax.add_collection3d(poly)

    def paint(self, ax, table: np.ndarray) -> None:
        """Faces and lines in the colours ``table`` (n_segments + 1, 4) of their segment (row 0: remainder)."""
        self.draw(ax, table[self.segment + 1])
        if len(self.lines):
            from mpl_toolkits.mplot3d.art3d import Line3DCollection

            ax.add_collection3d(Line3DCollection(self.lines, colors=table[self.line_segment + 1], linewidths=2.5,
                                                 zorder=2))


def _save(fig: Figure, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, bbox_inches="tight", pad_inches=0.15)  # flat structures leave empty bands
    return path
