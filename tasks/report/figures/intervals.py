"""How sure: marginal posteriors (Laplace or sampled) with their 95 % intervals, and the correlations of
the parameter estimates."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ._style import TRUE_STYLE, _param_label, _save

__all__ = [
    "plot_intervals",
]


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
