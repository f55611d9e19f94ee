"""The closure's residual figure: per sensor, the residual before and after the added effect.

``plot_residuals(closure_folder)`` reads ``residual_before.parquet``,
``residual_after.parquet`` and ``closure.json`` from the folder and writes
``residuals.png`` beside them (matplotlib, Agg backend: no display needed).
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pandas as pd

from tasks.report.figures._style import LABEL_EVERY_LINE_UP_TO, frequency_ticks
from tasks.runstore import atomic_write_bytes

__all__ = ["plot_residuals"]


def plot_residuals(folder: Path | str, out: Path | str | None = None) -> Path:
    """Residual (Eq. 5, per cent) against frequency per sensor, before and after; the noise band shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    info = json.loads((folder / "closure.json").read_text())
    before = pd.read_parquet(folder / "residual_before.parquet")
    after = pd.read_parquet(folder / "residual_after.parquet")
    sensors = sorted(before["sensor"].unique())
    freqs = np.sort(before["frequency_hz"].unique())
    x = np.arange(freqs.size)  # even spacing: the two bands sit side by side
    ticks, joins = _ticks(freqs)
    few = freqs.size <= LABEL_EVERY_LINE_UP_TO
    sigma = info["residual_before"]["sigma"]
    cols = 3
    rows = int(np.ceil(len(sensors) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(11, 3.0 * rows), sharex=True, squeeze=False)
    effect = info.get("effect")
    label_after = "after: + " + (f"{effect['type']} at {effect['location']}" if effect else "no effect")
    for ax, s in zip(axes.ravel(), sensors):
        b = before[before["sensor"] == s].sort_values("frequency_hz")["residual"].to_numpy()
        a = after[after["sensor"] == s].sort_values("frequency_hz")["residual"].to_numpy()
        ax.axhspan(-200 * sigma, 200 * sigma, color="0.9", label="noise, 2 sigma")
        ax.plot(x, 100 * b, marker="o" if few else None, ms=3, lw=1.0, label="before (alpha only)")
        ax.plot(x, 100 * a, marker="s" if few else None, ms=3, lw=1.0, label=label_after)
        ax.axhline(0.0, color="0.5", lw=0.5)
        for j in joins:
            ax.axvline(j - 0.5, color="0.6", lw=0.6, ls=":")
        ax.set_title(f"sensor {s}", fontsize=9)
        ax.set_xticks(ticks)
        ax.set_xticklabels([f"{f:g}" for f in freqs[ticks]], rotation=90, fontsize=7)
        ax.tick_params(axis="y", labelsize=7)
    for ax in axes.ravel()[len(sensors):]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("residual [%]", fontsize=8)
    for ax in axes[-1, :]:
        ax.set_xlabel("frequency [Hz]", fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="best")
    what = (f"added {effect['type']} at {effect['location']}, {effect['parameter']} = {effect['value']:.4g} "
            f"{effect['unit']}" if effect else "no effect added")
    fig.suptitle(f"overall error {info['error_before']:.2%} -> {info['error_after']:.2%}: {what}", fontsize=9)
    fig.tight_layout()
    path = Path(out) if out else folder / "residuals.png"
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _ticks(freqs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the lines labelled on the axis (:func:`tasks.report.figures._style.frequency_ticks`) and, beyond
    a few lines, the indices where a band starts after a gap of more than ten times the median spacing (two bands
    side by side; lines dropped here and there leave smaller gaps)."""
    n = freqs.size
    if n <= LABEL_EVERY_LINE_UP_TO:
        return frequency_ticks(n), np.array([], int)
    step = np.diff(freqs)
    return frequency_ticks(n), np.flatnonzero(step > 10.0 * np.median(step)) + 1
