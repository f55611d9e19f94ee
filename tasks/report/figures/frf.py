"""Figure 3, the FRF amplitude at the sensors (overview and zoom on the measurement windows), and the
relative residual maps per sensor and frequency."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import PercentFormatter

from ._style import CURVE_STYLE, _grid, _measured_style, _save, frequency_ticks

__all__ = [
    "plot_frf_overview",
    "plot_frf_zoom",
    "plot_residual_maps",
]


# -- Figure 3: FRF amplitude ----------------------------------------------------------------------
def plot_frf_overview(dense: pd.DataFrame, measured: pd.DataFrame, path: Path,
                      windows: list[tuple[float, float]] | None = None, title: str | None = None,
                      labels: dict | None = None) -> Path:
    """Figure 3: measured points and the dense initial/updated FRF amplitude, one panel per sensor.

    Parameters
    ----------
    dense : DataFrame
        ``curve, frequency_hz, sensor, amplitude`` (m/N); curves ``initial`` and ``updated``.
    measured : DataFrame
        ``frequency_hz, sensor, amplitude`` (m/N).
    windows : list of (low, high), Hz
        Measurement windows, shaded.
    labels : dict of int to str, optional
        Panel title per sensor (channel) number, e.g. ``"s2 / hammer"``; default ``"sensor <n>"``.
    """
    sensors = sorted(measured["sensor"].unique())
    nrows, ncols = _grid(len(sensors), 2)
    fig = Figure(figsize=(11, 2.6 * nrows + 0.8), layout="constrained")
    axes = fig.subplots(nrows, ncols, sharex=True, squeeze=False).ravel()
    for ax, s in zip(axes, sensors):
        for lo, hi in windows or []:
            ax.axvspan(lo, hi, color="C1", alpha=0.08, lw=0)
        for name, style in CURVE_STYLE.items():
            c = dense[(dense["curve"] == name) & (dense["sensor"] == s)].sort_values("frequency_hz")
            if not c.empty:
                ax.semilogy(c["frequency_hz"], c["amplitude"], **style)
        m = measured[measured["sensor"] == s]
        ax.semilogy(m["frequency_hz"], m["amplitude"], **_measured_style(len(m)))
        ax.set_title((labels or {}).get(s, f"sensor {s}"), fontsize=10)
        ax.set_ylabel("|Z| (m/N)")
        ax.grid(True, which="major", alpha=0.3)
    for ax in axes[len(sensors):]:
        ax.set_visible(False)
    for ax in axes[max(0, len(sensors) - ncols):len(sensors)]:
        ax.set_xlabel("frequency (Hz)")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=3, frameon=False)
    fig.suptitle(title or "FRF amplitude at the sensors (shaded: measurement windows)", fontsize=11)
    return _save(fig, path)


def plot_frf_zoom(dense: pd.DataFrame, measured: pd.DataFrame, path: Path,
                  windows: list[tuple[float, float]], labels: dict | None = None) -> Path:
    """Figure 3, zoomed: each measurement window of each sensor, measured points against both models."""
    sensors = sorted(measured["sensor"].unique())
    nrows, ncols = len(sensors), len(windows)
    fig = Figure(figsize=(4.6 * ncols + 0.6, 1.9 * nrows + 1.0), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for i, s in enumerate(sensors):
        for j, (lo, hi) in enumerate(windows):
            ax = axes[i, j]
            for name, style in CURVE_STYLE.items():
                c = dense[(dense["curve"] == name) & (dense["sensor"] == s)
                          & dense["frequency_hz"].between(lo, hi)].sort_values("frequency_hz")
                if not c.empty:
                    ax.semilogy(c["frequency_hz"], c["amplitude"], **style)
            m = measured[(measured["sensor"] == s) & measured["frequency_hz"].between(lo, hi)]
            ax.semilogy(m["frequency_hz"], m["amplitude"], **_measured_style(len(m)))
            ax.set_xlim(lo, hi)
            ax.grid(True, which="both", alpha=0.25)
            if j == 0:
                ax.set_ylabel(f"{(labels or {}).get(s, f'sensor {s}')}\n|Z| (m/N)")
            if i == nrows - 1:
                ax.set_xlabel("frequency (Hz)")
            if i == 0:
                ax.set_title(f"{lo:.0f}-{hi:.0f} Hz", fontsize=10)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper center", ncols=3, frameon=False)
    return _save(fig, path)


def plot_residual_maps(maps: dict[str, pd.DataFrame], path: Path, title: str | None = None,
                       shared_scale: bool = False) -> Path:
    """Relative residual ``(|Z| - u) / u`` per sensor and frequency, one heat map per entry of ``maps``.

    Colour scales are symmetric about zero, per map or (``shared_scale``) common to all, so that a
    before/after pair shows the change; the values are written in the cells in percent.
    """
    n = len(maps)
    common = max(float(np.nanmax(np.abs(df["residual"].to_numpy()))) for df in maps.values())
    fig = Figure(figsize=(min(6.4 * n, 19), 4.4), layout="constrained")
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, (name, df) in zip(axes, maps.items()):
        wide = df.pivot_table(index="sensor", columns="frequency_hz", values="residual").sort_index()
        values = wide.to_numpy()
        vmax = common if shared_scale else float(np.nanmax(np.abs(values))) if np.isfinite(values).any() else 1.0
        im = ax.imshow(values, cmap="RdBu_r", vmin=-vmax, vmax=vmax, aspect="auto")
        ticks = frequency_ticks(wide.shape[1])
        ax.set_xticks(ticks, [f"{wide.columns[k]:g}" for k in ticks], rotation=90, fontsize=8)
        ax.set_yticks(range(wide.shape[0]), [str(s) for s in wide.index])
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("sensor")
        mean_abs = float(np.nanmean(np.abs(values)))
        ax.set_title(f"{name}: mean |residual| {mean_abs:.2%}", fontsize=10)
        if values.size <= 200:
            for (r, c), v in np.ndenumerate(values):
                ax.text(c, r, f"{100 * v:.0f}" if abs(v) >= 0.995 else f"{100 * v:.1f}", ha="center", va="center",
                        fontsize=6.5, color="white" if abs(v) > 0.6 * vmax else "black")
        cb = fig.colorbar(im, ax=ax, shrink=0.9)
        cb.ax.yaxis.set_major_formatter(PercentFormatter(1.0))
        cb.set_label("relative residual (%)")
    fig.suptitle(title or "Relative residual (|Z| - u) / u in percent", fontsize=11)
    return _save(fig, path)
