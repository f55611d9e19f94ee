"""The parameters per iteration: every FE sample (Figure 6), the best so far with the sampling
distribution (Figure 7) and the distributions as ridges of densities (Figure 8)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ._style import TRUE_STYLE, _bottom_labels_only, _grid, _iteration_axis, _param_label, _save

__all__ = [
    "plot_samples",
    "plot_parameters",
    "plot_distributions",
]


# -- Figures 6-8: parameters -----------------------------------------------------------------------
def plot_samples(samples: pd.DataFrame, names: list[str], path: Path, truth=None,
                 polish: pd.DataFrame | None = None, bounds: tuple[float, float] = (-1.0, 1.0)) -> Path:
    """Figure 6: every FE sample's parameters per iteration, one panel per parameter."""
    nrows, ncols = _grid(len(names), 3)
    fig = Figure(figsize=(12, 3.2 * nrows + 0.6), layout="constrained")
    axes = fig.subplots(nrows, ncols, sharex=True, squeeze=False).ravel()
    iterations = sorted(samples["iteration"].unique())
    has_polish = polish is not None and len(polish) > 0
    cmap = colormaps["viridis"]
    rng = np.random.default_rng(1)
    jitter = rng.uniform(-0.2, 0.2, len(samples))
    colors = cmap((samples["iteration"] - 1) / max(1, len(iterations) - 1))
    for i, (ax, name) in enumerate(zip(axes, names)):
        ax.scatter(samples["iteration"] + jitter, samples[name], s=10, c=colors, lw=0, alpha=0.8)
        if has_polish:
            ax.scatter(np.full(len(polish), max(iterations) + 1), polish[name], s=14, marker="D", color="C2",
                       label="polish-stage FE runs")
        if truth is not None:
            ax.axhline(truth[i], **TRUE_STYLE, label="true value")
        ax.set_ylim(bounds[0] - 0.05, bounds[1] + 0.05)
        ax.set_title(_param_label(name), fontsize=10)
        ax.set_ylabel("stiffness factor (-)")
        ax.grid(True, alpha=0.25)
        _iteration_axis(ax, iterations, "polish" if has_polish else None)
    for ax in axes[len(names):]:
        ax.set_visible(False)
    _bottom_labels_only(axes, len(names), ncols)
    handles, labels = axes[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="outside lower center", ncols=len(handles), frameon=False)
    fig.suptitle("FE samples per iteration (iteration 1: uniform; later: chosen by the MRGP)", fontsize=11)
    return _save(fig, path)


def plot_parameters(best: pd.DataFrame, distributions: pd.DataFrame, names: list[str], path: Path,
                    truth=None, bounds: tuple[float, float] = (-1.0, 1.0), final=None,
                    final_label: str = "polish") -> Path:
    """Figure 7: each parameter of the best sample so far per iteration, with the true value when known.

    The bars (and band) are the sampling distribution computed at that iteration (mean +/- 1 std).
    ``final`` (the reported parameters, when a later stage such as the polish improved on the loop's
    best sample) is drawn one step after the last iteration.
    """
    nrows, ncols = _grid(len(names), 3)
    fig = Figure(figsize=(12, 3.0 * nrows + 0.6), layout="constrained")
    axes = fig.subplots(nrows, ncols, sharex=True, squeeze=False).ravel()
    normal = distributions[distributions["kind"] == "normal"] if len(distributions) else distributions
    last = int(best["iteration"].max())
    for i, (ax, name) in enumerate(zip(axes, names)):
        d = normal[normal["parameter"] == name].sort_values("iteration") if len(normal) else normal
        if len(d):
            if len(d) > 1:
                ax.fill_between(d["iteration"], d["mean"] - d["std"], d["mean"] + d["std"], color="C0", alpha=0.12,
                                lw=0)
            ax.errorbar(d["iteration"], d["mean"], yerr=d["std"], fmt="_", color="C0", alpha=0.45, capsize=3,
                        label="sampling distribution, mean +/- 1 std")
        ax.plot(best["iteration"], best[name], "-o", color="C0", ms=4, lw=1.6, label="best sample so far")
        value = float(best[name].iloc[-1])
        if final is not None:
            value = float(final[i])
            ax.plot([last, last + 1], [best[name].iloc[-1], value], ":", color="C2")
            ax.plot([last + 1], [value], "D", color="C2", ms=5, label=f"after the {final_label} (reported)")
        if truth is not None:
            ax.axhline(truth[i], **TRUE_STYLE, label="true value")
        ax.set_ylim(bounds[0] - 0.05, bounds[1] + 0.05)
        ax.set_title(f"{_param_label(name)}: final {value:+.3f}"
                     + (f" (true {truth[i]:+.2f})" if truth is not None else ""), fontsize=10)
        ax.set_ylabel("stiffness factor (-)")
        ax.grid(True, alpha=0.25)
        _iteration_axis(ax, sorted(best["iteration"]), final_label if final is not None else None)
    for ax in axes[len(names):]:
        ax.set_visible(False)
    _bottom_labels_only(axes, len(names), ncols)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper center", ncols=len(handles), frameon=False)
    return _save(fig, path)


def plot_distributions(distributions: pd.DataFrame, names: list[str], path: Path, truth=None,
                       bounds: tuple[float, float] = (-1.0, 1.0)) -> Path:
    """Figure 8: the sampling distribution of every iteration as a ridge of densities per parameter.

    Each density is scaled to the same height so narrow late distributions and the wide uniform
    start are both visible; the label at the right gives the standard deviation.
    """
    nrows, ncols = _grid(len(names), 3)
    iterations = sorted(distributions["iteration"].unique())
    fig = Figure(figsize=(12, max(3.2, 0.42 * len(iterations) + 1.2) * nrows + 0.6), layout="constrained")
    axes = fig.subplots(nrows, ncols, sharey=True, squeeze=False).ravel()
    cmap = colormaps["viridis"]
    x = np.linspace(bounds[0], bounds[1], 801)
    for i, (ax, name) in enumerate(zip(axes, names)):
        d = distributions[distributions["parameter"] == name]
        for k in iterations:
            row = d[d["iteration"] == k]
            if row.empty:
                continue
            row = row.iloc[0]
            color = cmap((k - iterations[0]) / max(1, iterations[-1] - iterations[0]))
            if row["kind"] == "uniform":
                y = np.where((x >= bounds[0]) & (x <= bounds[1]), 0.5, 0.0)
            else:
                y = np.exp(-0.5 * ((x - row["mean"]) / row["std"]) ** 2)
            y = 0.85 * y / y.max()
            ax.fill_between(x, k, k + y, color=color, alpha=0.55, lw=0)
            ax.plot(x, k + y, color=color, lw=1)
            ax.text(bounds[1] - 0.01 * (bounds[1] - bounds[0]), k + 0.08, f"sd {row['std']:.3f}", fontsize=6.5,
                    va="bottom", ha="right", color="0.25")
        if truth is not None:
            ax.axvline(truth[i], **TRUE_STYLE, label="true value")
        ax.set_xlim(bounds)
        ax.set_title(_param_label(name), fontsize=10)
        ax.set_xlabel("stiffness factor (-)")
        ax.set_ylabel("iteration")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(True, axis="x", alpha=0.25)
    for ax in axes[len(names):]:
        ax.set_visible(False)
    if truth is not None:
        ax0 = axes[0]
        fig.legend(*ax0.get_legend_handles_labels(), loc="outside lower center", frameon=False)
    fig.suptitle("Sampling distribution of the candidates per iteration (uniform, then normal; "
                 "densities scaled to equal height)", fontsize=11)
    return _save(fig, path)
