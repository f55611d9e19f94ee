"""Pictures of a solver deck's mesh (``solver = "calculix"``): shells as their mid-surface polygons, beams as
lines, solids by their outer faces, coloured like our own meshes (:mod:`tasks.report.mesh`), and the updated
model's mode shapes drawn on the deformed deck.

The deck's nodes, cells and segments are those of ``model.vtu`` (:class:`fe_core.io.calculix.vtu.DeckView`,
set on the model by the deck's reader); a shell node's displacement is the mean of the rows ccx expands it
into, as ccx reports it. Shells have two sides: every polygon is drawn, shaded by the angle between its
normal and the light whichever side faces the viewer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from fe_core.surface import DofArrows, boundary_faces
from tasks.report.view3d import AZIMUTH, ELEVATION, MeshView, _save

__all__ = ["DeckMeshView", "plot_mode_shapes", "MODES_PNG"]

MODES_PNG = "mesh_modes.png"
#: Outline of each surface cell type (meshio node order): corners and mid-side nodes around the edge.
OUTLINES = {"triangle": [0, 1, 2], "triangle6": [0, 3, 1, 4, 2, 5], "quad": [0, 1, 2, 3],
            "quad8": [0, 4, 1, 5, 2, 6, 3, 7], "quad9": [0, 4, 1, 5, 2, 6, 3, 7]}
#: Line cell types as chains of nodes (meshio's line3: end, end, middle).
CHAINS = {"line": [0, 1], "line3": [0, 2, 1]}
#: Solid cell types by their corner cells (boundary faces of :func:`fe_core.surface.boundary_faces`).
SOLIDS = {"hexahedron": ("hexahedron", 8), "hexahedron20": ("hexahedron", 8), "tetra": ("tetra", 4),
          "tetra10": ("tetra10", 10)}


def _pad(polys: list[np.ndarray]) -> np.ndarray:
    """Node index polygons of different lengths as one array, short ones ending in their last node again."""
    width = max(len(p) for p in polys)
    return np.array([np.concatenate([p, np.repeat(p[-1:], width - len(p))]) for p in polys], dtype=np.int64)


class DeckMeshView(MeshView):
    """:class:`~tasks.report.mesh.MeshView` of a deck model: the same drawing, from ``model.deck_view``.

    Attributes besides MeshView's: ``faces`` (n_faces, k) node indices of the drawn polygons, ``line_nodes``
    (n_lines, 2) of the beam segments, ``segment`` / ``line_segment`` per face / line (-1: in no segment),
    ``cell_segments`` (every drawn cell's segment), ``skipped`` (element type: count not drawn).
    """

    def __init__(self, model, elevation: float = ELEVATION, azimuth: float = AZIMUTH):
        dv = model.deck_view
        self.points = np.asarray(dv.points, float)
        faces, seg, lines, lseg, cells = [], [], [], [], []
        skipped = dict(dv.skipped)
        for (ctype, conn), segs in zip(dv.blocks, dv.segments):
            conn, segs = np.asarray(conn), np.asarray(segs)
            if ctype in OUTLINES:
                faces += list(conn[:, OUTLINES[ctype]])
                seg += list(segs)
            elif ctype in CHAINS:
                chain = CHAINS[ctype]
                for a, b in zip(chain[:-1], chain[1:]):
                    lines += list(conn[:, [a, b]])
                    lseg += list(segs)
            elif ctype in SOLIDS:
                kind, width = SOLIDS[ctype]
                f, owner = boundary_faces(self.points, conn[:, :width], kind)
                faces += list(f)
                seg += list(segs[owner])
            else:
                skipped[ctype] = skipped.get(ctype, 0) + len(conn)
                continue
            cells += list(segs)
        self.faces = _pad(faces) if faces else np.zeros((0, 3), np.int64)
        self.segment = np.asarray(seg, np.int64)
        self.line_nodes = np.asarray(lines, np.int64).reshape(-1, 2)
        self.line_segment = np.asarray(lseg, np.int64)
        self.cell_segments = np.asarray(cells, np.int64)
        self.n_cells = int(self.cell_segments.size)
        self.skipped = skipped
        self.rows_to_nodes = dv.rows_to_nodes
        self.elevation, self.azimuth = elevation, azimuth
        self.n_boundary = int(self.faces.shape[0])
        self.cell = np.arange(self.n_boundary)
        used = np.unique(np.concatenate([self.faces.ravel(), self.line_nodes.ravel()]))
        pts = self.points[used] if used.size else self.points
        self.lo, self.hi = pts.min(axis=0), pts.max(axis=0)
        self._light = self._light_direction(elevation, azimuth)
        self._place(self.points)

    @staticmethod
    def _light_direction(elevation: float, azimuth: float) -> np.ndarray:
        e, a = np.radians(elevation), np.radians(azimuth)
        eye = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        light = eye + np.array([-np.sin(a), np.cos(a), 0.0]) * 0.4 + np.array([0.0, 0.0, 0.5])
        return light / np.linalg.norm(light)

    def _place(self, points: np.ndarray) -> None:
        """Polygons, lines and shading at node positions ``points`` (the deck's, or a deformed shape)."""
        self.polygons = points[self.faces]
        self.lines = points[self.line_nodes]
        p = self.polygons
        normal = np.cross(p - p.mean(axis=1, keepdims=True), np.roll(p, -1, axis=1) - p.mean(axis=1, keepdims=True)
                          ).sum(axis=1)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        self.shade = 0.45 + 0.55 * np.abs(normal @ self._light)     # both sides of a shell are seen

    def arrows(self, model, vector) -> DofArrows:
        """Where a row vector of ccx's matrices acts (a sensor, the load): one arrow per deck node."""
        v = vector.toarray().ravel() if hasattr(vector, "toarray") else np.asarray(vector, dtype=float).ravel()
        full = (self.rows_to_nodes @ v).reshape(-1, 3)
        nodes = np.flatnonzero(np.linalg.norm(full, axis=1) > 0)
        vec = full[nodes]
        weights = np.linalg.norm(vec, axis=1)
        return DofArrows(nodes, self.points[nodes], vec / weights[:, None], weights)

    def nodal(self, shape: np.ndarray) -> np.ndarray:
        """A mode shape over ccx's rows as displacements of the deck's nodes, shape (n_nodes, 3)."""
        return (self.rows_to_nodes @ shape).reshape(-1, 3)


def plot_mode_shapes(model, view: DeckMeshView, alpha, path: Path, gamma=None, lowest_hz: float = 0.0,
                     n_modes: int = 4) -> tuple[Path, list[float]]:
    """The updated model's first ``n_modes`` modes at or above ``lowest_hz`` on the deformed deck, coloured by
    the displacement's magnitude (the undeformed deck as grey lines). Returns the picture and their frequencies.
    """
    freqs, shapes, _ = model.modes(alpha, min(n_modes + 8, model.n_dofs - 1), gamma)   # rigid-body modes below
    pick = [k for k, f in enumerate(freqs) if f >= lowest_hz][:n_modes] or list(range(min(n_modes, len(freqs))))
    cols = min(len(pick), 2)
    rows = int(np.ceil(len(pick) / cols))
    fig = Figure(figsize=(6.4 * cols, 4.8 * rows))
    cmap = colormaps["viridis"]
    undeformed = view.polygons
    for i, k in enumerate(pick):
        u = view.nodal(shapes[k])
        scale = 0.12 * view.size / max(float(np.max(np.linalg.norm(u, axis=1))), 1e-300)
        view._place(view.points + scale * u)
        mag = np.linalg.norm(u, axis=1)
        face_mag = mag[view.faces].mean(axis=1) / max(mag.max(), 1e-300)
        ax = view.axes(fig, (rows, cols, i + 1), f"mode {k + 1}: {freqs[k]:.2f} Hz")
        ax.add_collection3d(Poly3DCollection(undeformed, facecolors=(0, 0, 0, 0), edgecolors=(0, 0, 0, 0.12),
                                             linewidths=0.2, zorder=0))
        rgba = cmap(face_mag)
        view.draw(ax, rgba)
        if len(view.lines):
            from mpl_toolkits.mplot3d.art3d import Line3DCollection

            ax.add_collection3d(Line3DCollection(view.lines, colors="C1", linewidths=2.0, zorder=2))
    view._place(view.points)
    bar = fig.colorbar(ScalarMappable(norm=Normalize(0, 1), cmap=cmap), ax=fig.axes, shrink=0.6, pad=0.04)
    bar.set_label("|displacement| / its largest value", fontsize=8)
    fig.suptitle("Mode shapes of the updated model (deformation exaggerated)", fontsize=10)
    return _save(fig, path), [float(freqs[k]) for k in pick]
