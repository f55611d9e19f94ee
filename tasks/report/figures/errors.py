"""The updating loop per iteration: overall and per-sensor errors (Figures 4, 5) and the MRGP training
time (Figure 9)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from ._style import PERCENT, _iteration_axis, _save, _threshold_line

__all__ = [
    "plot_error_overall",
    "plot_error_per_sensor",
    "plot_training_time",
]


# -- Figures 4 and 5: errors per iteration ------------------------------------------------------
def plot_error_overall(errors: pd.DataFrame, best: pd.DataFrame, path: Path, threshold: float | None = None,
                       polish: pd.DataFrame | None = None) -> Path:
    """Figure 4: overall error (Eq. 6b) of every FE sample per iteration and the best so far.

    Parameters
    ----------
    errors : DataFrame
        ``iteration, overall_error, status``.
    best : DataFrame
        ``iteration, overall_error, fe_evaluations`` (best so far).
    polish : DataFrame, optional
        Polish-stage points with ``overall_error``, drawn after the last iteration.
    """
    fig = Figure(figsize=(8, 4.6), layout="constrained")
    ax = fig.subplots()
    ok = errors[errors["status"] == "ok"]
    rng = np.random.default_rng(0)
    jitter = rng.uniform(-0.18, 0.18, len(ok))
    ax.scatter(ok["iteration"] + jitter, ok["overall_error"], s=12, color="0.55", alpha=0.6, lw=0,
               label="FE samples of the iteration")
    ax.plot(best["iteration"], best["overall_error"], "-o", color="C0", lw=2, ms=5, label="best so far")
    for _, row in best.iterrows():
        ax.annotate(f"{100 * row['overall_error']:.3g}%", (row["iteration"], row["overall_error"]),
                    textcoords="offset points", xytext=(0, -13), ha="center", fontsize=7.5, color="C0")
    has_polish = polish is not None and "overall_error" in polish and polish["overall_error"].notna().any()
    if has_polish:
        x = best["iteration"].max() + 1
        pe = polish["overall_error"].dropna()
        ax.scatter(np.full(len(pe), x), pe, s=16, marker="D", color="C2", label="polish stage")
        ax.plot([best["iteration"].max(), x], [best["overall_error"].iloc[-1], pe.min()], ":", color="C2")
    _threshold_line(ax, threshold, np.concatenate([ok["overall_error"].to_numpy(),
                                                   polish["overall_error"].dropna().to_numpy() if has_polish else []]))
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(PERCENT)
    ax.set_ylabel("overall error, Eq. 6b (mean |relative residual|)")
    _iteration_axis(ax, sorted(best["iteration"]), "polish" if has_polish else None)
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=8.5, loc="best")
    fe = int(best["fe_evaluations"].iloc[-1])
    n_polish = len(polish) if has_polish else 0
    ax.set_title(f"Overall error per iteration ({fe} FE runs" + (f" + {n_polish} in the polish)" if n_polish else ")"),
                 fontsize=11)
    return _save(fig, path)


def plot_error_per_sensor(best: pd.DataFrame, path: Path) -> Path:
    """Figure 5: per-sensor error (Eq. 15) of the best sample so far, per iteration."""
    cols = sorted([c for c in best.columns if c.startswith("error_sensor_")], key=lambda c: int(c.rsplit("_", 1)[1]))
    fig = Figure(figsize=(8, 4.6), layout="constrained")
    ax = fig.subplots()
    markers = "osD^v<>ph*"
    for i, c in enumerate(cols):
        ax.plot(best["iteration"], best[c], marker=markers[i % len(markers)], ms=4.5, lw=1.4,
                label=f"sensor {c.rsplit('_', 1)[1]}")
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(PERCENT)
    ax.set_ylabel("sensor error, Eq. 15 (mean |relative residual|)")
    _iteration_axis(ax, sorted(best["iteration"]))
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=8.5, ncols=2)
    ax.set_title("Per-sensor error of the best sample so far", fontsize=11)
    return _save(fig, path)


# -- Figure 9: training time -------------------------------------------------------------------
def plot_training_time(training: pd.DataFrame, path: Path, series: str = "trainer") -> Path:
    """Figure 9: MRGP training time per iteration, grouped bars, one colour per ``series`` value.

    Parameters
    ----------
    training : DataFrame
        ``iteration, seconds, n_train`` and the ``series`` column.
    """
    fig = Figure(figsize=(8, 4.4), layout="constrained")
    ax = fig.subplots()
    groups = list(dict.fromkeys(training[series]))
    iterations = sorted(training["iteration"].unique())
    width = 0.8 / max(1, len(groups))
    for g_i, g in enumerate(groups):
        part = training[training[series] == g].groupby("iteration", as_index=False)["seconds"].mean()
        xs = part["iteration"] + (g_i - (len(groups) - 1) / 2) * width
        ax.bar(xs, part["seconds"], width=width * 0.95, label=str(g), color=f"C{g_i % 10}")
    n_train = training.groupby("iteration")["n_train"].max()
    ax.set_xticks(iterations, [f"{k}\n{int(n_train[k])}" if pd.notna(n_train.get(k)) else str(k)
                               for k in iterations], fontsize=8)
    ax.set_xlabel("iteration\nFE runs in the training set")
    ax.set_ylabel("training time (s)")
    if training["seconds"].max() > 50 * max(training["seconds"].min(), 1e-6):
        ax.set_yscale("log")
    ax.grid(True, axis="y", which="both", alpha=0.25)
    ax.legend(title=series, fontsize=8.5)
    ax.set_title("MRGP hyper-parameter training time per iteration", fontsize=11)
    return _save(fig, path)
