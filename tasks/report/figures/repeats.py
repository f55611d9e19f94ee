"""Repeated runs: convergence of each run, final errors and identified parameters (Figures 10-13)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from ._style import PERCENT, TRUE_STYLE, _param_label, _save, _threshold_line

__all__ = [
    "plot_error_trends",
    "plot_repeats_error",
    "plot_repeats_parameters",
]


# -- Figures 10-13: repeated runs -----------------------------------------------------------------
def plot_error_trends(trends: dict[str, pd.DataFrame], path: Path, threshold: float | None = None) -> Path:
    """Best overall error so far against the number of FE runs, one line per repeat."""
    fig = Figure(figsize=(8, 4.6), layout="constrained")
    ax = fig.subplots()
    for i, (label, best) in enumerate(trends.items()):
        ax.plot(best["fe_evaluations"], best["overall_error"], "-o", ms=3.5, lw=1.4, color=f"C{i % 10}", label=label)
    _threshold_line(ax, threshold, np.concatenate([b["overall_error"].to_numpy() for b in trends.values()]))
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(PERCENT)
    ax.set_xlabel("FE runs")
    ax.set_ylabel("best overall error so far (Eq. 6b)")
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=8, ncols=2)
    ax.set_title("Convergence of each run", fontsize=11)
    return _save(fig, path)


def plot_repeats_error(table: pd.DataFrame, path: Path, threshold: float | None = None, title: str = "") -> Path:
    """Figures 10 / 12: final overall error of each run, with the mean.

    Parameters
    ----------
    table : DataFrame
        ``label, overall_error`` (one row per run).
    """
    fig = Figure(figsize=(7.5, 4.4), layout="constrained")
    ax = fig.subplots()
    x = np.arange(len(table))
    bars = ax.bar(x, table["overall_error"], color="C0", width=0.6)
    ax.bar_label(bars, [f"{100 * v:.3g}%" for v in table["overall_error"]], fontsize=8, padding=2)
    mean = float(table["overall_error"].mean())
    std = float(table["overall_error"].std(ddof=1)) if len(table) > 1 else 0.0
    ax.axhline(mean, color="C1", lw=1.5, label=f"mean {100 * mean:.3g}% (std {100 * std:.3g}%)")
    _threshold_line(ax, threshold, table["overall_error"].to_numpy())
    ax.set_xticks(x, table["label"], fontsize=8.5)
    ax.set_xlabel("run")
    ax.yaxis.set_major_formatter(PERCENT)
    ax.set_ylabel("final overall error (Eq. 6b)")
    ax.set_ylim(0, 1.2 * max(float(table["overall_error"].max()), threshold or 0))
    ax.grid(True, axis="y", alpha=0.25)
    ax.legend(fontsize=8.5, loc="upper left")
    ax.set_title(title or "Final overall error of each run", fontsize=11)
    return _save(fig, path)


def plot_repeats_parameters(table: pd.DataFrame, names: list[str], path: Path, truth=None, title: str = "",
                            bounds: tuple[float, float] = (-1.0, 1.0)) -> Path:
    """Figures 11 / 13: identified parameters of each run, mean +/- std, true values.

    Parameters
    ----------
    table : DataFrame
        ``label`` and ``alpha_*`` (one row per run).
    """
    fig = Figure(figsize=(9, 4.6), layout="constrained")
    ax = fig.subplots()
    x = np.arange(len(names))
    n = len(table)
    offsets = np.linspace(-0.25, 0.25, n) if n > 1 else np.zeros(1)
    for j, (_, row) in enumerate(table.iterrows()):
        ax.scatter(x + offsets[j], row[names].to_numpy(float), s=22, color=f"C{j % 10}", label=str(row["label"]),
                   zorder=3)
    values = table[names].to_numpy(float)
    ax.errorbar(x + 0.38, values.mean(axis=0), yerr=values.std(axis=0, ddof=1) if n > 1 else None, fmt="o",
                color="k", ms=5, capsize=4, label="mean +/- std")
    if truth is not None:
        ax.hlines(truth, x - 0.4, x + 0.45, **{**TRUE_STYLE, "lw": 2}, label="true value")
    ax.set_xticks(x, [_param_label(n_) for n_ in names])
    ax.set_ylabel("identified stiffness factor (-)")
    ax.set_ylim(bounds[0] - 0.05, bounds[1] + 0.05)
    ax.grid(True, axis="y", alpha=0.25)
    ax.legend(fontsize=7.5, ncols=4, loc="upper center", bbox_to_anchor=(0.5, -0.08), frameon=False)
    ax.set_title(title or "Identified parameters of each run", fontsize=11)
    return _save(fig, path)
