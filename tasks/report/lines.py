"""The report's picture of the measured data: which lines and values entered the update, and why.

Reads ``<run>/measured.parquet`` (written by the update: every measured line
and channel as read, in receptance, with ``selected`` and ``used``) and the
manifest's ``measured_data`` (conversions, channel matches, the selection).
Runs made before these files existed get no section.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from tasks.report.figures._style import _grid, _save
from tasks.report.html import Section

__all__ = ["lines_section", "plot_line_selection", "channels_of_run", "MAX_PANELS"]

#: Channels drawn at most (the first ones in the file).
MAX_PANELS = 12


def plot_line_selection(table: pd.DataFrame, windows: list, path: Path, min_coherence: float | None = None) -> Path:
    """Measured receptance per channel: values used (dots), lines not selected (grey), values left out
    for coherence (red crosses), selected windows shaded; the coherence on a second axis when measured.

    Parameters
    ----------
    table : DataFrame
        ``frequency_hz, sensor, channel, amplitude, selected, used[, coherence]``.
    windows : list of (low, high), Hz
    """
    channels = list(dict.fromkeys(table["sensor"]))[:MAX_PANELS]
    nrows, ncols = _grid(len(channels), 2)
    fig = Figure(figsize=(11, 2.5 * nrows + 0.9), layout="constrained")
    axes = fig.subplots(nrows, ncols, sharex=True, squeeze=False).ravel()
    has_coherence = "coherence" in table.columns
    coherence_line = None
    for ax, s in zip(axes, channels):
        c = table[table["sensor"] == s].sort_values("frequency_hz")
        for lo, hi in windows:
            ax.axvspan(lo, hi, color="C1", alpha=0.10, lw=0)
        out = c[~c["selected"]]
        dropped = c[c["selected"] & ~c["used"]]
        used = c[c["used"]]
        ax.semilogy(out["frequency_hz"], out["amplitude"], ".", color="0.7", ms=2, label="line not selected")
        ax.semilogy(used["frequency_hz"], used["amplitude"], ".", color="C0", ms=2, label="used")
        ax.semilogy(dropped["frequency_hz"], dropped["amplitude"], "x", color="C3", ms=3,
                    label="left out (coherence)")
        ax.set_title(str(c["channel"].iloc[0]), fontsize=9)
        ax.set_ylabel("|H| (m/N)")
        ax.grid(True, which="major", alpha=0.3)
        if has_coherence:
            twin = ax.twinx()
            (line,) = twin.plot(c["frequency_hz"], c["coherence"], color="C2", lw=0.6, alpha=0.7)
            coherence_line = coherence_line or line
            if min_coherence:
                twin.axhline(min_coherence, color="C2", ls=":", lw=0.8)
            twin.set_ylim(0, 1.05)
            twin.set_ylabel("coherence", color="C2", fontsize=8)
    for ax in axes[len(channels):]:
        ax.set_visible(False)
    for ax in axes[max(0, len(channels) - ncols):len(channels)]:
        ax.set_xlabel("frequency (Hz)")
    handles, labels = axes[0].get_legend_handles_labels()
    if coherence_line is not None:
        handles.append(coherence_line)
        labels.append("coherence (right axis)")
    fig.legend(handles, labels, loc="outside lower center", ncols=4, frameon=False)
    fig.suptitle("Measured receptance per channel: the values that enter the update (shaded: selected windows)",
                 fontsize=11)
    return _save(fig, path)


def lines_section(data, out: Path) -> Section | None:
    """What was read, converted and selected, with the figure; None for runs without ``measured.parquet``."""
    path = Path(data.root) / "measured.parquet"
    info = data.manifest.get("measured_data")
    if not path.exists() or info is None:
        return None
    table = pd.read_parquet(path)
    sel = info["selection"]
    fig = plot_line_selection(table, [tuple(w) for w in sel["windows"]], out / "line_selection.png",
                              sel.get("min_coherence"))
    mode = sel["mode"] + (f", half-power bands x {sel['widen']:g}" if sel["mode"] == "resonances" else "")
    rows = [("source", info["source"]), ("form", info["form"]), ("residual", f"{info['residual']} (k = "
                                                                            f"{info['values']} values)"),
            ("lines", mode), ("windows", ", ".join(f"{lo:.4g}-{hi:.4g} Hz" for lo, hi in sel["windows"]) or "-"),
            ("resonances found", ", ".join(f"{f:.4g} Hz" for f in sel.get("resonances_hz", [])) or "-"),
            ("lines selected", f"{sel['lines_selected']} of {sel['lines_in_file']}"),
            ("values left out (coherence < " + f"{sel['min_coherence']:g})",
             f"{sel['coherence_dropped']} of {sel['values_in_windows']} ({sel['lines_dropped']} lines left empty)")]
    rows += [("read", note) for note in info.get("notes", [])]
    channels = pd.DataFrame(info["channels"])[["label", "sensor", "excitation", "sign", "kind", "place"]]
    return Section(
        title="Measured data: channels, lines and coherence",
        paragraphs=["What the update fitted: the file's channels matched to the model's sensors and excitations "
                    "(a sign of -1: the test's direction is opposite to the model's), converted to receptance, "
                    "and the lines and values the line selection and the coherence threshold kept."],
        tables=[("Selection", pd.DataFrame(rows, columns=["item", "value"])), ("Channels", channels)],
        figures=[(fig, "Measured receptance per channel; used, not selected and left-out values, with coherence")],
    )


def channels_of_run(manifest: dict, model) -> tuple[np.ndarray, np.ndarray] | None:
    """The run's channels as (sensor, excitation) indices of ``model``, or None for the model's own FRF."""
    info = manifest.get("measured_data")
    if not info or info["form"].startswith("legacy"):
        return None
    responses = [model.sensor_names.index(c["sensor"]) for c in info["channels"]]
    references = [model.excitation_names.index(c["excitation"]) for c in info["channels"]]
    default = model.excitation_names.index(model.excitation_name)
    if responses == list(range(model.n_sensors)) and all(r == default for r in references):
        return None
    return np.array(responses), np.array(references)
