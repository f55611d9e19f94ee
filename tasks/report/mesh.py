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

from tasks.report.html import Section  # noqa: E402
from tasks.report.view3d import AZIMUTH, DPI, ELEVATION, MeshView, _save  # noqa: E402,F401 (re-exported)

__all__ = ["MeshView", "plot_mesh_segments", "plot_mesh_factors", "mesh_section",
           "SEGMENTS_PNG", "FACTORS_PNG"]

REPO = Path(__file__).resolve().parents[2]
SEGMENTS_PNG = "mesh_segments.png"
FACTORS_PNG = "mesh_factors.png"
REMAINDER_COLOR = "0.78"
EXCITATION_STYLE = dict(marker="*", s=170, c="C3", edgecolors="k", linewidths=0.6)


def _segment_colors(n: int) -> list:
    cmap = colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def _sensors_and_excitation(ax, model, view: MeshView) -> list:
    """Sensor arrows with names, excitation stars and arrows; returns the legend handles."""
    length = 0.12 * view.size
    handles = []
    outputs = model.outputs.tocsc()
    at_nodes = getattr(model, "sensor_nodes", None)
    if at_nodes is not None and len(at_nodes) != model.n_sensors:
        at_nodes = None
    for j, name in enumerate(model.sensor_names):
        arrows = view.arrows(model, outputs[:, j])
        if at_nodes is not None and len(arrows.nodes) > 1:   # read between nodes: one arrow at its nearest node
            arrows = _at_node(model, arrows, int(at_nodes[j]))
        p, d = arrows.positions, arrows.directions
        ax.quiver(p[:, 0], p[:, 1], p[:, 2], d[:, 0], d[:, 1], d[:, 2], length=length, color="k", lw=1.4,
                  arrow_length_ratio=0.3, zorder=5)
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=14, c="k", depthshade=False, zorder=6)
        tip = p[0] + 1.15 * length * d[0]
        ax.text(tip[0], tip[1], tip[2], name, fontsize=7, zorder=7,
                bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.7))
    handles.append(Line2D([], [], color="k", marker=r"$\rightarrow$", ms=10, ls="none",
                          label=f"sensor ({model.n_sensors}): measured direction"))
    exc = view.arrows(model, model.load)
    entries = (getattr(model, "excitation_nodes", None) or {}).get(model.excitation_name)
    if entries:   # read between nodes: an arrow at each entry's nearest node
        exc = _entry_arrows(model, entries)
    p, d = exc.positions, exc.directions
    ax.quiver(p[:, 0], p[:, 1], p[:, 2], d[:, 0], d[:, 1], d[:, 2], length=0.8 * length, color="C3", lw=1.6,
              arrow_length_ratio=0.35, zorder=5)
    ax.scatter(p[:, 0], p[:, 1], p[:, 2], depthshade=False, zorder=8, **EXCITATION_STYLE)
    plural = "s" if len(exc.nodes) > 1 else ""
    handles.append(Line2D([], [], ls="none", marker="*", ms=12, mfc="C3", mec="k",
                          label=f"excitation {model.excitation_name!r} ({len(exc.nodes)} node{plural})"))
    return handles


def _at_node(model, arrows, node: int):
    """One arrow at ``node`` along the sum of a sensor's arrows (a point read through an element's shape
    functions, ``point_placement = "interpolate"``: its direction, drawn at its nearest node)."""
    from fe_core.surface import DofArrows

    total = (arrows.directions * arrows.weights[:, None]).sum(axis=0)
    size = float(np.linalg.norm(total))
    direction = total / size if size > 0 else arrows.directions[int(np.argmax(arrows.weights))]
    return DofArrows(np.array([node]), model.mesh.nodes[[node]], direction[None], np.array([size]))


def _entry_arrows(model, entries):
    """Arrows of an excitation's entries ``[(node, force vector), ...]``, one per node (vectors summed)."""
    from fe_core.surface import DofArrows

    nodes = sorted({int(n) for n, _ in entries})
    vec = np.array([np.sum([f for n, f in entries if n == m], axis=0) for m in nodes], dtype=float)
    size = np.linalg.norm(vec, axis=1)
    return DofArrows(np.array(nodes), model.mesh.nodes[nodes], vec / np.where(size > 0, size, 1.0)[:, None], size)


def plot_mesh_segments(model, path: Path, view: MeshView | None = None, title: str | None = None) -> Path:
    """The outer surface coloured by segment, the remainder grey, with sensors and excitation."""
    view = view or MeshView(model)
    fig = Figure(figsize=(9.0, 6.2))
    ax = view.axes(fig, 111, title or f"Segments, sensors and excitation ({view.n_cells} cells)")
    colors = _segment_colors(model.n_segments)
    rgba = np.array([to_rgba(colors[s]) if s >= 0 else to_rgba(REMAINDER_COLOR) for s in range(-1, model.n_segments)])
    view.paint(ax, rgba)
    handles = [Patch(color=colors[i], label=f"{i + 1}: {name}") for i, name in enumerate(model.segment_names)]
    if np.any(view.cell_segments < 0):
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
    seg = view.segment
    for k, (label, values) in enumerate(factors.items()):
        symbol = label.split(" ")[0]
        ax = view.axes(fig, (1, len(factors), k + 1), f"Updated {label}: " +
                       ("K_i (1 + alpha_i)" if symbol == "alpha" else "M_i (1 + gamma_i)"))
        top = max(float(np.max(np.abs(values))), 1e-3)
        norm = Normalize(-top, top)
        cmap = colormaps["coolwarm"]
        rgba = np.vstack([to_rgba(REMAINDER_COLOR), cmap(norm(values))])
        view.paint(ax, rgba)
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


def mesh_section(data, out: Path) -> Section:
    """The mesh pictures of a run (or one line saying why there are none)."""
    from tasks.model_vtu import VTU_NAME, factors_from_parameters

    title = "Mesh, segments, sensors and updated factors"
    name = data.config.get("model", "three_plate")
    model = data.model
    deck = getattr(model, "deck_view", None)          # a solver deck's mesh (fe_core.io.calculix.vtu)
    if model.mesh is None and deck is None:
        return Section(title=title, notes=[f"No mesh pictures: the model {name} is given as matrices (no "
                                           "cells to draw; its node table, if any, gives points only), and no "
                                           "model.vtu is written for it."])
    _, theta, _ = data.best()
    alpha, gamma = factors_from_parameters(dict(zip(data.names, theta)), model)
    if deck is not None:
        from tasks.report.deck_mesh import MODES_PNG, DeckMeshView, plot_mode_shapes

        view = DeckMeshView(model)
    else:
        view = MeshView(model)
    fig1 = plot_mesh_segments(model, out / SEGMENTS_PNG, view)
    fig2 = plot_mesh_factors(model, alpha, out / FACTORS_PNG, gamma, view)
    cells = np.bincount(view.cell_segments + 1, minlength=model.n_segments + 1)
    table = pd.DataFrame({"segment": [f"{i + 1}: {s}" for i, s in enumerate(model.segment_names)],
                          "cells": cells[1:], "alpha (updated)": alpha})
    if gamma is not None:
        table["gamma (updated)"] = gamma
    vtu = data.root / VTU_NAME
    figures = [(fig1, "Outer surface by segment; sensors (arrows along the measured direction) and the excitation "
                      "(red stars)"),
               (fig2, "Updated factors per segment; the colour bar marks each segment's value")]
    if deck is None:
        paragraphs = [f"{model.mesh.n_cells} cells, {model.mesh.n_nodes} nodes, {model.n_dofs} free DOFs; "
                      f"{int(cells[0])} cells in the fixed remainder. The pictures show the outer surface "
                      f"({view.n_boundary} boundary faces, those facing the viewer drawn)."]
    else:
        skipped = ", ".join(f"{n} {t}" for t, n in sorted(view.skipped.items()))
        paragraphs = [f"The solver deck's mesh: {view.n_cells} cells ({view.n_boundary} shell or solid-surface "
                      f"polygons, {len(view.lines)} beam lines), {len(deck.node_ids)} nodes, {model.n_dofs} DOFs "
                      f"in ccx's matrices; {int(cells[0])} cells in no segment (the fixed remainder)"
                      + (f"; not drawn: {skipped} (no cell type to draw them as)." if skipped else ".")]
        low = float(data.frequencies.min()) if len(data.measured) else 0.0
        fig3, freqs = plot_mode_shapes(model, view, alpha, out / MODES_PNG, gamma, lowest_hz=0.5 * low)
        figures.append((fig3, "Mode shapes of the updated model from half the lowest measured frequency up ("
                              + ", ".join(f"{f:.2f}" for f in freqs) + " Hz), on the deck's nodes (a shell "
                              "node: the mean of ccx's expanded nodes)"))
    paragraphs.append(f"{VTU_NAME} in the run folder holds the mesh with the cell data segment, alpha"
                      f"{' and gamma' if gamma is not None else ''} and the first modes of the updated model as "
                      "point data, for ParaView." if vtu.exists() else
                      f"No {VTU_NAME} in the run folder (it is written when a run finishes).")
    return Section(title=title, paragraphs=paragraphs, tables=[("Segments", table)], figures=figures)
