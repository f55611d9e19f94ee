"""The report's figures: plain functions from DataFrames to PNG files (matplotlib, Agg).

Each function draws one figure of Zhou & Tang (numbers in the docstrings),
writes it to ``path`` and returns the path. No pyplot state is used (each
figure is its own :class:`matplotlib.figure.Figure`), so they can run in any
thread or process without a display.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless; must precede any pyplot import anywhere in the process

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib import colormaps  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.ticker import FuncFormatter, MaxNLocator, PercentFormatter  # noqa: E402

__all__ = [
    "plot_frf_overview",
    "plot_frf_zoom",
    "plot_residual_maps",
    "plot_error_overall",
    "plot_error_per_sensor",
    "plot_samples",
    "plot_parameters",
    "plot_distributions",
    "plot_training_time",
    "plot_error_trends",
    "plot_repeats_error",
    "plot_repeats_parameters",
    "plot_candidates",
    "plot_correlation",
    "plot_correlation_heatmap",
    "plot_singular_values",
    "plot_intervals",
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


def _measured_style(n_points: int) -> dict:
    """Squares for a few measured lines, small dots for a test's hundreds or thousands."""
    return MEASURED_STYLE if n_points <= 100 else dict(MEASURED_STYLE, marker=".", ms=2.5, mfc="C3")


def _param_label(name: str) -> str:
    return name.replace("alpha_", "alpha ").replace("gamma_", "gamma ")


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
        ax.set_xticks(range(wide.shape[1]), [f"{f:g}" for f in wide.columns], rotation=90, fontsize=8)
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


# -- Figures 4 and 5: errors per iteration ------------------------------------------------------
def _iteration_axis(ax, iterations, extra_label: str | None = None):
    ticks = list(iterations)
    labels = [str(k) for k in ticks]
    if extra_label:
        ticks.append(max(iterations) + 1)
        labels.append(extra_label)
    ax.set_xticks(ticks, labels)
    ax.set_xlabel("iteration")


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


def plot_intervals(names: list[str], estimate, std, low, high, correlation, path: Path, truth=None,
                   bounds: tuple[float, float] | None = None, title: str = "", samples=None, weights=None,
                   laplace_std=None) -> Path:
    """Marginal posteriors (Laplace: normal, mean ``estimate``, sd ``std``; sampled: weighted histograms of
    ``samples``, with the Laplace normal of ``laplace_std`` dashed) with their 95 % intervals, and the
    pairwise correlations of the parameter estimates.

    Parameters
    ----------
    names : list of str, length m
    estimate, std, low, high : array_like, shape (m,)
        ``std`` may hold inf (a parameter the data cannot see: no curve drawn).
    correlation : array_like, shape (m, m)
    truth : array_like (m,), optional
    bounds : (lower, upper), optional
        The search box, drawn as grey lines where it falls inside a panel.
    samples : array_like, shape (n, m), optional
        Points of a sampled posterior, with ``weights`` (shape (n,)).
    laplace_std : array_like, shape (m,), optional
        The Laplace standard deviations, drawn dashed beside a sampled posterior.
    """
    m = len(names)
    est, sd, lo, hi = (np.asarray(v, float) for v in (estimate, std, low, high))
    corr = np.asarray(correlation, float)
    sampled = samples is not None and weights is not None
    ncols = min(m, 3)
    nrows = -(-m // ncols)
    fig = Figure(figsize=(4.0 * ncols + 4.6, 2.5 * nrows + 0.6), layout="constrained")
    grid = fig.add_gridspec(nrows, ncols + 2)
    for i, name in enumerate(names):
        ax = fig.add_subplot(grid[i // ncols, i % ncols])
        if np.isfinite(sd[i]) and sd[i] > 0:
            x = np.linspace(est[i] - 4 * sd[i], est[i] + 4 * sd[i], 201)
            if sampled:
                ax.hist(np.asarray(samples)[:, i], bins=30, weights=np.asarray(weights), density=True, color="C0",
                        alpha=0.45, label="sampled posterior")
                lsd = np.asarray(laplace_std, float)[i] if laplace_std is not None else np.nan
                if np.isfinite(lsd) and lsd > 0:
                    x = np.linspace(est[i] - 4 * lsd, est[i] + 4 * lsd, 201)
                    ax.plot(x, np.exp(-0.5 * ((x - est[i]) / lsd) ** 2) / (lsd * np.sqrt(2 * np.pi)), color="C1",
                            ls="--", lw=1.2, label="Laplace")
                    ax.set_xlim(x[0], x[-1])  # samples of negligible weight far out would stretch the panel
            else:
                ax.plot(x, np.exp(-0.5 * ((x - est[i]) / sd[i]) ** 2) / (sd[i] * np.sqrt(2 * np.pi)), color="C0")
            ax.axvspan(lo[i], hi[i], color="C0", alpha=0.15, label="95 % interval")
            if bounds is not None:
                for b in bounds:
                    if x[0] <= b <= x[-1]:
                        ax.axvline(b, color="0.4", lw=1.5, label="search box")
        else:
            ax.text(0.5, 0.5, "not seen by the data", ha="center", va="center", transform=ax.transAxes)
        ax.axvline(est[i], color="C0", lw=1)
        if truth is not None:
            ax.axvline(truth[i], label="true", **TRUE_STYLE)
        ax.set_title(f"{_param_label(name)} = {est[i]:.4g} +/- {(hi[i] - lo[i]) / 2:.2g}", fontsize=9.5)
        ax.set_yticks([])
        if i == 0:
            ax.legend(fontsize=7.5, loc="upper right")
    ax = fig.add_subplot(grid[:, ncols:])
    im = ax.imshow(corr, cmap="RdBu_r", vmin=-1, vmax=1)
    labels = [_param_label(n) for n in names]
    ax.set_xticks(range(m), labels, rotation=90)
    ax.set_yticks(range(m), labels)
    for a in range(m):
        for b in range(m):
            if np.isfinite(corr[a, b]):
                ax.text(b, a, f"{corr[a, b]:.2f}", ha="center", va="center", fontsize=7.5,
                        color="w" if abs(corr[a, b]) > 0.6 else "k")
    ax.set_title("correlation of the estimates", fontsize=10)
    fig.colorbar(im, ax=ax, shrink=0.7)
    if title:
        fig.suptitle(title, fontsize=11)
    return _save(fig, path)
