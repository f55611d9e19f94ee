"""Which parameters the sensors see: Pearson correlations of parameters and FRF amplitudes (Figures 14-19,
bars and a heat map) and the singular values of the normalised sensitivity."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ._style import TRUE_STYLE, _grid, _param_label, _save

__all__ = [
    "plot_correlation",
    "plot_correlation_heatmap",
    "plot_singular_values",
]


# -- Figures 14-19: correlation ----------------------------------------------------------------
def plot_correlation(corr: pd.DataFrame, names: list[str], path: Path, n_samples: int | None = None) -> Path:
    """Figures 14-19 in one: Pearson correlation of each parameter with each sensor's amplitude.

    One panel per sensor, grouped bars: x = frequency, one bar per parameter.

    Parameters
    ----------
    corr : DataFrame
        ``parameter, sensor, frequency_hz, rho``.
    """
    sensors = sorted(corr["sensor"].unique())
    freqs = np.sort(corr["frequency_hz"].unique())
    nrows, ncols = _grid(len(sensors), 2)
    fig = Figure(figsize=(13, 2.7 * nrows + 1.0), layout="constrained")
    axes = fig.subplots(nrows, ncols, sharey=True, squeeze=False).ravel()
    width = 0.8 / len(names)
    x = np.arange(len(freqs))
    for ax, s in zip(axes, sensors):
        part = corr[corr["sensor"] == s]
        for i, name in enumerate(names):
            v = part[part["parameter"] == name].set_index("frequency_hz").reindex(freqs)["rho"]
            ax.bar(x + (i - (len(names) - 1) / 2) * width, v, width=width, color=f"C{i % 10}",
                   label=_param_label(name))
        ax.axhline(0, color="k", lw=0.6)
        ax.set_xticks(x, [f"{f:g}" for f in freqs], fontsize=7.5, rotation=90)
        ax.set_ylim(-1, 1)
        ax.set_title(f"sensor {s}", fontsize=10)
        ax.set_ylabel("Pearson rho (-)")
        ax.grid(True, axis="y", alpha=0.25)
    for ax in axes[len(sensors):]:
        ax.set_visible(False)
    for ax in axes[max(0, len(sensors) - ncols):len(sensors)]:
        ax.set_xlabel("frequency (Hz)")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=len(names), frameon=False)
    fig.suptitle("Correlation of each parameter with each sensor's FRF amplitude (Eq. 16"
                 + (f", {n_samples:,} FE samples uniform in [-1, 1]" if n_samples else "") + ")", fontsize=11)
    return _save(fig, path)


def plot_correlation_heatmap(corr: pd.DataFrame, names: list[str], path: Path) -> Path:
    """All coefficients at once: rows parameters, columns (sensor, frequency); one map per column
    of ``corr`` among ``rho`` (amplitude, Eq. 16) and ``rho_log`` (log amplitude)."""
    panels = [(c, t) for c, t in (("rho", "Pearson rho with |Z| (Eq. 16)"),
                                  ("rho_log", "Pearson rho with log |Z|")) if c in corr.columns]
    fig = Figure(figsize=(13, (0.42 * len(names) + 1.6) * len(panels) + 0.6), layout="constrained")
    axes = fig.subplots(len(panels), 1, squeeze=False)[:, 0]
    for ax, (col, title) in zip(axes, panels):
        wide = corr.pivot_table(index="parameter", columns=["sensor", "frequency_hz"], values=col).reindex(names)
        im = ax.imshow(wide.to_numpy(), cmap="RdBu_r", vmin=-1, vmax=1, aspect="auto")
        cols = list(wide.columns)
        ax.set_xticks(range(len(cols)), [f"{f:g}" for _, f in cols], rotation=90, fontsize=6.5)
        ax.set_yticks(range(len(names)), [_param_label(n) for n in names])
        sensors = [s for s, _ in cols]
        for i in range(1, len(cols)):
            if sensors[i] != sensors[i - 1]:
                ax.axvline(i - 0.5, color="k", lw=1)
        for s in dict.fromkeys(sensors):
            idx = [i for i, t in enumerate(sensors) if t == s]
            ax.text(np.mean(idx), -0.7, f"sensor {s}", ha="center", va="bottom", fontsize=8.5)
        ax.set_xlabel("frequency (Hz), grouped by sensor")
        ax.set_title(title, fontsize=10, pad=24, loc="left")
        cb = fig.colorbar(im, ax=ax, shrink=0.9)
        cb.set_label("rho (-)")
    return _save(fig, path)


def plot_singular_values(results: dict[str, object], path: Path) -> Path:
    """Singular values of the normalised sensitivity matrix at each reference point (log scale),
    and the noise-implied identification limit.

    Parameters
    ----------
    results : dict of str to :class:`fe_core.solvers.sensitivity.Identifiability`
    """
    fig = Figure(figsize=(11, 4.4), layout="constrained")
    ax, ax2 = fig.subplots(1, 2)
    for i, (label, r) in enumerate(results.items()):
        k = np.arange(1, len(r.singular_values) + 1)
        ax.semilogy(k, r.singular_values, "-o", color=f"C{i}", label=label)
        x = np.arange(len(r.names))
        xs = x + (i - (len(results) - 1) / 2) * 0.8 / len(results)
        finite = np.isfinite(r.std)
        ax2.bar(xs[finite], r.std[finite], width=0.8 / len(results), color=f"C{i}", label=label)
        for xi in xs[~finite]:
            ax2.annotate("unbounded", (xi, r.tolerance), rotation=90, ha="center", va="bottom", fontsize=7,
                         color=f"C{i}")
    first = next(iter(results.values()))
    stds = np.concatenate([r.std[np.isfinite(r.std)] for r in results.values()] + [[first.tolerance]])
    ax2.set_ylim(0.5 * stds.min(), 8 * stds.max())  # room above the bars for the legend
    ax.axhline(first.noise / first.tolerance, **TRUE_STYLE,
               label=f"noise / tolerance = {first.noise:.0%} / {first.tolerance:g}")
    ax.set_xlabel("singular value index")
    ax.set_ylabel("singular value of d log|Z| / d alpha (-)")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=8)
    ax.set_title("Normalised sensitivity: singular values", fontsize=10)
    ax2.axhline(first.tolerance, **TRUE_STYLE, label=f"tolerance {first.tolerance:g}")
    ax2.set_yscale("log")
    ax2.set_xticks(np.arange(len(first.names)), [_param_label(n) for n in first.names])
    ax2.set_ylabel(f"linearised std of the estimate at {first.noise:.0%} noise (-)")
    ax2.grid(True, axis="y", which="both", alpha=0.25)
    ax2.legend(fontsize=8, ncols=2, loc="upper left")
    ax2.set_title("Which parameters the sensors pin down (below the line)", fontsize=10)
    return _save(fig, path)
