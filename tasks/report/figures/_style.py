"""What the report's figures share: size, resolution, curve and marker styles, the percent axis, the
stopping threshold line, panel grids and labels, and saving a figure to PNG."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter

__all__ = [
    "DPI",
    "CURVE_STYLE",
    "MEASURED_STYLE",
    "TRUE_STYLE",
    "PERCENT",
]


DPI = 110
CURVE_STYLE = {
    "initial": dict(color="0.45", ls="--", lw=1.3, label="initial model (alpha = 0)"),
    "updated": dict(color="C0", ls="-", lw=1.6, label="updated model"),
}
MEASURED_STYLE = dict(marker="s", ms=4.5, ls="none", mfc="none", mec="C3", mew=1.3, label="measured")
TRUE_STYLE = dict(color="C3", ls="--", lw=1.2)


def _save(fig: Figure, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    return path


def _grid(n: int, ncols: int) -> tuple[int, int]:
    return max(1, math.ceil(n / ncols)), min(n, ncols)


#: Fractions as percentages with 3 significant digits (0.0123 -> "1.23%", 1e-4 -> "0.01%").
PERCENT = FuncFormatter(lambda y, _: f"{100 * y:.3g}%")


def _threshold_line(ax, threshold, values) -> None:
    """The stopping threshold as a dashed line, unless it is far below the data (it would squash the axis)."""
    if not threshold:
        return
    lowest = float(np.nanmin(values)) if len(values) else threshold
    if threshold >= lowest / 50:
        ax.axhline(threshold, **TRUE_STYLE, label=f"threshold {100 * threshold:.3g}%")
    else:
        ax.plot([], [], **TRUE_STYLE, label=f"threshold {100 * threshold:.3g}% (below the axis)")


def _bottom_labels_only(axes, n: int, ncols: int) -> None:
    """Drop the x label of panels that have another panel below them (shared x axes)."""
    for i, ax in enumerate(axes[:n]):
        if i + ncols < n:
            ax.set_xlabel("")


#: Lines up to which each gets its label on a frequency axis of line indices (and its marker where a figure draws
#: them); beyond, about :data:`FREQUENCY_LABELS` spread evenly: a test system's export has a line every 0.5-1 Hz,
#: and hb07's 1,270 lines labelled one by one were a black bar that took 20 s of its closure to lay out.
LABEL_EVERY_LINE_UP_TO = 60
FREQUENCY_LABELS = 12


def frequency_ticks(n_lines: int) -> np.ndarray:
    """Indices of the lines labelled on an axis of ``n_lines`` line indices: all up to
    :data:`LABEL_EVERY_LINE_UP_TO`, else :data:`FREQUENCY_LABELS` evenly spread, the first and last among them."""
    if n_lines <= LABEL_EVERY_LINE_UP_TO:
        return np.arange(n_lines)
    return np.unique(np.linspace(0, n_lines - 1, FREQUENCY_LABELS).round().astype(int))


def _measured_style(n_points: int) -> dict:
    """Squares for a few measured lines, small dots for a test's hundreds or thousands."""
    return MEASURED_STYLE if n_points <= 100 else dict(MEASURED_STYLE, marker=".", ms=2.5, mfc="C3")


def _param_label(name: str) -> str:
    return name.replace("alpha_", "alpha ").replace("gamma_", "gamma ")


def _iteration_axis(ax, iterations, extra_label: str | None = None):
    ticks = list(iterations)
    labels = [str(k) for k in ticks]
    if extra_label:
        ticks.append(max(iterations) + 1)
        labels.append(extra_label)
    ax.set_xticks(ticks, labels)
    ax.set_xlabel("iteration")
