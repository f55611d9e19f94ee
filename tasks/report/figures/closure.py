"""The closure's figures: the FRF at the measured frequencies with and without the added effects, and
the ranked candidate effects."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from ._style import _grid, _save

__all__ = [
    "plot_closure_frf",
    "plot_candidates",
]


def plot_closure_frf(table: pd.DataFrame, path: Path, title: str | None = None) -> Path:
    """Measured amplitude and the model's, alpha-only and with the added effects.

    ``table``: columns ``frequency_hz, sensor, measured, alpha_only, extended`` (m/N) at the measured
    frequencies (the closure's own fits, no extra solves). One panel per sensor and frequency band
    (bands side by side would leave the panel empty between them) when there are at most 3 bands
    and 8 sensors, else one panel per sensor with the lines broken at the gaps.
    """
    from fe_core.inference.residual import frequency_bands

    sensors = sorted(table["sensor"].unique())
    freqs = np.sort(table["frequency_hz"].unique())
    bands = [freqs[b] for b in frequency_bands(freqs)]
    split = 1 < len(bands) <= 3 and len(sensors) <= 8
    if split:
        nrows, ncols = len(bands), len(sensors)
        fig = Figure(figsize=(2.6 * ncols, 2.6 * nrows), layout="constrained")
        axes = fig.subplots(nrows, ncols, squeeze=False)
        panels = [(axes[i, j], s, band) for j, s in enumerate(sensors) for i, band in enumerate(bands)]
    else:
        nrows, ncols = _grid(len(sensors), 3)
        fig = Figure(figsize=(4.2 * ncols, 3.0 * nrows), layout="constrained")
        flat = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
        panels = [(ax, s, freqs) for ax, s in zip(flat, sensors)]
        for ax in flat[len(sensors):]:
            ax.set_visible(False)
    for ax, s, band in panels:
        d = table[(table["sensor"] == s) & table["frequency_hz"].isin(band)].sort_values("frequency_hz")
        f = d["frequency_hz"].to_numpy()
        gaps = [g[-1] + 1 for g in frequency_bands(f)[:-1]]  # lines within a measured band only
        fg = np.insert(f, gaps, np.nan)
        ax.semilogy(f, d["measured"], "k.", ms=5, label="measured")
        ax.semilogy(fg, np.insert(d["alpha_only"].to_numpy(), gaps, np.nan), "-", color="tab:blue", lw=1,
                    label="alpha only")
        ax.semilogy(fg, np.insert(d["extended"].to_numpy(), gaps, np.nan), "--", color="tab:red", lw=1.2,
                    label="with the added effects")
        ax.set_title(f"sensor {s}" + (f", {band[0]:g}-{band[-1]:g} Hz" if split else ""), fontsize=9)
        ax.set_xlabel("frequency (Hz)", fontsize=8)
        ax.tick_params(labelsize=7)
    panels[0][0].set_ylabel("|Z| (m/N)")
    panels[0][0].legend(fontsize=7)
    fig.suptitle(title or "FRF at the measured frequencies: alpha-only and extended model", fontsize=11)
    return _save(fig, path)


# -- close the loop ----------------------------------------------------------------------------
def plot_candidates(table: pd.DataFrame, path: Path, score: str, chosen: str | None = None) -> Path:
    """Ranked candidate effects of a close-the-loop run as horizontal bars (best on top).

    Parameters
    ----------
    table : DataFrame
        ``label`` and the ``score`` column, already ranked best first.
    chosen : str, optional
        Label of the effect that was added (highlighted).
    """
    table = table.head(15)
    fig = Figure(figsize=(8, max(3.2, 0.34 * len(table) + 1.6)), layout="constrained")
    ax = fig.subplots()
    y = np.arange(len(table))[::-1]
    colors = ["C2" if chosen is not None and str(lbl) == chosen else "C0" for lbl in table["label"]]
    light = table["_light"].to_numpy(bool) if "_light" in table else np.zeros(len(table), bool)
    bars = ax.barh(y, table[score], color=colors)
    for bar, is_light in zip(bars, light):
        if is_light:
            bar.set_alpha(0.4)
    ax.bar_label(bars, [f"{v:.3g}" for v in table[score]], fontsize=7.5, padding=2)
    ax.set_yticks(y, [str(v) for v in table["label"]], fontsize=8)
    ax.set_xlabel(score.replace("_", " "))
    ax.grid(True, axis="x", alpha=0.25)
    ax.set_title("Candidate effects, best first" + (" (green: added)" if chosen else ""), fontsize=11)
    return _save(fig, path)
