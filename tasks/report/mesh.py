"""Pictures of the model's mesh: segments, sensors and excitation; updated factors as colours.

Only the outer surface is drawn (:func:`fe_core.surface.boundary_faces`: faces of one
cell, tet10 by its corners), in an orthographic 3-D view, and of it only the faces that
look towards the viewer, as one vectorised ``Poly3DCollection`` shaded by the angle to the
light. Sensors are arrows along their measured direction with their names; the excitation's
DOFs are red stars with arrows along the force. Matplotlib with the Agg backend (no display).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib import colormaps  # noqa: E402
from matplotlib.cm import ScalarMappable  # noqa: E402
from matplotlib.colors import Normalize, to_rgba  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from fe_core.surface import boundary_faces, dof_arrows, face_normals  # noqa: E402
from tasks.report.html import Section  # noqa: E402

__all__ = ["MeshView", "plot_mesh_segments", "plot_mesh_factors", "mesh_section",
           "SEGMENTS_PNG", "FACTORS_PNG"]

REPO = Path(__file__).resolve().parents[2]
SEGMENTS_PNG = "mesh_segments.png"
FACTORS_PNG = "mesh_factors.png"
DPI = 110
#: Viewing angles (degrees) and the light's direction (from the viewer's upper left).
ELEVATION, AZIMUTH = 24.0, -58.0
REMAINDER_COLOR = "0.78"
EXCITATION_STYLE = dict(marker="*", s=170, c="C3", edgecolors="k", linewidths=0.6)


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


def _segment_colors(n: int) -> list:
    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def _sensors_and_excitation(ax, model, view: MeshView) -> list:
    """Sensor arrows with names, excitation stars and arrows; returns the legend handles."""
    length = 0.12 * view.size
    handles = []
    outputs = model.outputs.tocsc()
    for j, name in enumerate(model.sensor_names):
        arrows = dof_arrows(model, outputs[:, j])
        p, d = arrows.positions, arrows.directions
        ax.quiver(p[:, 0], p[:, 1], p[:, 2], d[:, 0], d[:, 1], d[:, 2], length=length, color="k", lw=1.4,
                  arrow_length_ratio=0.3, zorder=5)
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=14, c="k", depthshade=False, zorder=6)
        tip = p[0] + 1.15 * length * d[0]
        ax.text(tip[0], tip[1], tip[2], name, fontsize=7, zorder=7,
                bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.7))
    handles.append(Line2D([], [], color="k", marker=r"$\rightarrow$", ms=10, ls="none",
                          label=f"sensor ({model.n_sensors}): measured direction"))
    exc = dof_arrows(model, model.load)
    p, d = exc.positions, exc.directions
    ax.quiver(p[:, 0], p[:, 1], p[:, 2], d[:, 0], d[:, 1], d[:, 2], length=0.8 * length, color="C3", lw=1.6,
              arrow_length_ratio=0.35, zorder=5)
    ax.scatter(p[:, 0], p[:, 1], p[:, 2], depthshade=False, zorder=8, **EXCITATION_STYLE)
    plural = "s" if len(exc.nodes) > 1 else ""
    handles.append(Line2D([], [], ls="none", marker="*", ms=12, mfc="C3", mec="k",
                          label=f"excitation {model.excitation_name!r} ({len(exc.nodes)} node{plural})"))
    return handles


def plot_mesh_segments(model, path: Path, view: MeshView | None = None, title: str | None = None) -> Path:
    """The outer surface coloured by segment, the remainder grey, with sensors and excitation."""
    view = view or MeshView(model)
    fig = Figure(figsize=(9.0, 6.2))
    ax = view.axes(fig, 111, title or f"Segments, sensors and excitation ({model.mesh.n_cells} cells)")
    colors = _segment_colors(model.n_segments)
    seg = np.asarray(model.cell_segment)[view.cell]
    rgba = np.array([to_rgba(colors[s]) if s >= 0 else to_rgba(REMAINDER_COLOR) for s in range(-1, model.n_segments)])
    view.draw(ax, rgba[seg + 1])
    handles = [Patch(color=colors[i], label=f"{i + 1}: {name}") for i, name in enumerate(model.segment_names)]
    if np.any(np.asarray(model.cell_segment) < 0):
        handles.append(Patch(color=REMAINDER_COLOR, label="remainder (fixed)"))
    handles += _sensors_and_excitation(ax, model, view)
    fig.legend(handles=handles, loc="center right", fontsize=8, frameon=False)
    fig.subplots_adjust(left=0.0, right=0.72, bottom=0.02, top=0.95)
    return _save(fig, path)


def plot_mesh_factors(model, alpha, path: Path, gamma=None, view: MeshView | None = None,
                      title: str | None = None) -> Path:
    """The updated stiffness factors (and mass factors) as colours on the surface, with a colour bar.

    alpha, gamma : array_like, shape (n_segments,); the fixed remainder is grey. ``title``: above the panels.
    """
    view = view or MeshView(model)
    factors = {"alpha (stiffness factor)": np.asarray(alpha, float)}
    if gamma is not None:
        factors["gamma (mass factor)"] = np.asarray(gamma, float)
    fig = Figure(figsize=(7.6 * len(factors), 5.6))
    seg = np.asarray(model.cell_segment)[view.cell]
    for k, (label, values) in enumerate(factors.items()):
        symbol = label.split(" ")[0]
        ax = view.axes(fig, (1, len(factors), k + 1), f"Updated {label}: " +
                       ("K_i (1 + alpha_i)" if symbol == "alpha" else "M_i (1 + gamma_i)"))
        top = max(float(np.max(np.abs(values))), 1e-3)
        norm = Normalize(-top, top)
        cmap = colormaps["coolwarm"]
        rgba = np.vstack([to_rgba(REMAINDER_COLOR), cmap(norm(values))])
        view.draw(ax, rgba[seg + 1])
        bar = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.65, pad=0.08)
        remainder = "; grey: fixed remainder" if np.any(seg < 0) else ""
        bar.set_label(f"{symbol} (on the mesh: segment number: value){remainder}", fontsize=8)
        bar.ax.tick_params(labelsize=7)
        for v in values:
            bar.ax.axhline(v, color="k", lw=0.8)
        _segment_labels(ax, view, seg, [f"{s + 1}: {v:+.3f}" for s, v in enumerate(values)])
    if title:
        fig.suptitle(title, fontsize=9)
    fig.subplots_adjust(left=0.0, right=0.97, bottom=0.03, top=0.9 if title else 0.93, wspace=0.05)
    return _save(fig, path)


def _segment_labels(ax, view: MeshView, seg: np.ndarray, labels: list[str]) -> None:
    """Each label at the centre of its segment's visible faces (none for a segment out of sight)."""
    centres = view.polygons.mean(axis=1)
    for s, text in enumerate(labels):
        mine = seg == s
        if mine.any():
            c = centres[mine].mean(axis=0)
            ax.text(c[0], c[1], c[2], text, fontsize=7, ha="center", va="center", zorder=7,
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.75))


def _save(fig: Figure, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, bbox_inches="tight", pad_inches=0.15)  # flat structures leave empty bands
    return path


def mesh_section(data, out: Path) -> Section:
    """The mesh pictures of a run (or one line saying why there are none)."""
    from tasks.model_vtu import VTU_NAME, factors_from_parameters

    title = "Mesh, segments, sensors and updated factors"
    name = data.config.get("model", "three_plate")
    model = data.model
    if model.mesh is None:
        return Section(title=title, notes=[f"No mesh pictures: the model {name} is given as matrices (no node "
                                           "coordinates or cells to draw), and no model.vtu is written for it."])
    _, theta, _ = data.best()
    alpha, gamma = factors_from_parameters(dict(zip(data.names, theta)), model)
    view = MeshView(model)
    fig1 = plot_mesh_segments(model, out / SEGMENTS_PNG, view)
    fig2 = plot_mesh_factors(model, alpha, out / FACTORS_PNG, gamma, view)
    cells = np.bincount(np.asarray(model.cell_segment) + 1, minlength=model.n_segments + 1)
    table = pd.DataFrame({"segment": [f"{i + 1}: {s}" for i, s in enumerate(model.segment_names)],
                          "cells": cells[1:], "alpha (updated)": alpha})
    if gamma is not None:
        table["gamma (updated)"] = gamma
    vtu = data.root / VTU_NAME
    paragraphs = [f"{model.mesh.n_cells} cells, {model.mesh.n_nodes} nodes, {model.n_dofs} free DOFs; "
                  f"{int(cells[0])} cells in the fixed remainder. The pictures show the outer surface "
                  f"({view.n_boundary} boundary faces, those facing the viewer drawn)."]
    paragraphs.append(f"{VTU_NAME} in the run folder holds the mesh with the cell data segment, alpha"
                      f"{' and gamma' if gamma is not None else ''} and the first modes of the updated model as "
                      "point data, for ParaView." if vtu.exists() else
                      f"No {VTU_NAME} in the run folder (it is written when a run finishes).")
    return Section(title=title, paragraphs=paragraphs, tables=[("Segments", table)],
                   figures=[(fig1, "Outer surface by segment; sensors (arrows along the measured direction) and "
                                   "the excitation (red stars)"),
                            (fig2, "Updated factors per segment; the colour bar marks each segment's value")])
