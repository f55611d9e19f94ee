"""Dense FRF curves of a few parameter vectors, cached as Parquet in the report folder.

The run only holds the FRF at the measured frequencies; Figure 3 needs the
curve between and around them. The FE model is run once per vector (the
Krylov solver gives a thousand frequencies for the price of about one), and
the result is kept in ``report/cache/frf_dense.parquet``; it is reused while
the vectors, the model and the frequency grid stay the same.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from tasks.runstore import atomic_write_bytes, _parquet_bytes

__all__ = ["dense_frequencies", "frequency_clusters", "dense_frf"]

log = logging.getLogger(__name__)


def frequency_clusters(freqs_hz) -> list[np.ndarray]:
    """Split sorted measurement frequencies into groups at gaps wider than 3x the typical spacing.

    The benchmark's 12 points form two groups (106-116 Hz, 285-295 Hz), one around each resonance.
    """
    f = np.sort(np.asarray(freqs_hz, dtype=float))
    if f.size < 2:
        return [f]
    gaps = np.diff(f)
    split = gaps > 3.0 * np.median(gaps)
    return np.split(f, np.flatnonzero(split) + 1)


def dense_frequencies(freqs_hz, n_overview: int = 800, n_zoom: int = 241) -> np.ndarray:
    """A frequency grid for smooth FRF curves: a sweep over the whole band and dense points per cluster.

    The sweep runs from half the lowest to 1.3 times the highest measured
    frequency (so resonances that moved out of the measured windows, as the
    nominal model's do, stay in view); each cluster gets ``n_zoom`` points
    over its span widened by its own width (at least 4 Hz) on both sides. The measured
    frequencies are included exactly.
    """
    f = np.sort(np.asarray(freqs_hz, dtype=float))
    parts = [np.linspace(0.5 * f[0], 1.3 * f[-1], n_overview), f]
    for lo, hi in zoom_windows(f):
        parts.append(np.linspace(lo, hi, n_zoom))
    grid = np.unique(np.round(np.concatenate(parts), 9))
    return grid[grid > 0]


def zoom_windows(freqs_hz) -> list[tuple[float, float]]:
    """(low, high) frequency window of each measurement cluster, Hz."""
    out = []
    for c in frequency_clusters(freqs_hz):
        pad = max(c[-1] - c[0], 4.0)
        out.append((max(c[0] - pad, 0.5 * c[0]), c[-1] + pad))
    return out


def dense_frf(model, model_name: str, vectors: dict[str, np.ndarray], freqs_hz: np.ndarray, cache: Path,
              channels: tuple[np.ndarray, np.ndarray] | None = None, names: list[str] | None = None) -> pd.DataFrame:
    """FRF amplitude of each named parameter vector at every frequency, from the cache when valid.

    Parameters
    ----------
    model : fe_core.model.ParametricModel
        The run's model (run only for curves the cache does not hold).
    model_name : str
        As in the run's manifest (``three_plate``): the cache's key.
    vectors : dict of str to ndarray, shape (n_parameters,)
        Curve name -> parameter vector, e.g. ``{"initial": zeros, "updated": alpha}``.
    freqs_hz : ndarray
    cache : Path
        Parquet file; rewritten when a curve is missing or differs.
    channels : (responses, references), optional
        The run's measured channels (model sensor and excitation indices,
        :func:`tasks.report.lines.channels_of_run`); default the model's sensors
        under its default excitation. Column ``sensor`` is the channel number.
    names : list of str, optional
        The parameters' names (the run's sample columns: ``alpha_*``, then ``gamma_*``); ``alpha_1 ..``
        by default.

    Returns
    -------
    DataFrame
        ``curve, frequency_hz, sensor, real, imag, amplitude`` plus the curve's parameters (``alpha_*``, ``gamma_*``).
    """
    freqs_hz = np.asarray(freqs_hz, dtype=float)
    cached = None
    if cache.exists():
        try:
            cached = pd.read_parquet(cache)
        except Exception:
            log.warning("report cache %s is unreadable; recomputing", cache)
    frames, changed = [], False
    for name, alpha in vectors.items():
        alpha = np.asarray(alpha, dtype=float)
        cols = list(names) if names is not None else [f"alpha_{i + 1}" for i in range(alpha.size)]
        key = "" if channels is None else repr([list(map(int, c)) for c in channels])
        hit = _cached_curve(cached, model_name, name, alpha, cols, freqs_hz, key)
        if hit is None:
            Z = model.parameter_frf(alpha, freqs_hz, channels)  # (p, n_channels), m/N
            p, n = Z.shape
            hit = pd.DataFrame({
                "model": model_name,
                "curve": name,
                "frequency_hz": np.repeat(freqs_hz, n),
                "sensor": np.tile(np.arange(1, n + 1), p).astype(np.int64),
                "real": Z.real.ravel(),
                "imag": Z.imag.ravel(),
                "channels": key,
            })
            for c, v in zip(cols, alpha):
                hit[c] = v
            changed = True
        frames.append(hit)
    out = pd.concat(frames, ignore_index=True)
    out["amplitude"] = np.hypot(out["real"], out["imag"])
    if changed:
        atomic_write_bytes(cache, _parquet_bytes(out.drop(columns="amplitude")))
    return out


def _cached_curve(cached, model_name, name, alpha, cols, freqs_hz, key=""):
    if cached is None or not set(cols + ["curve", "model"]) <= set(cached.columns):
        return None
    channels = cached["channels"] if "channels" in cached.columns else pd.Series("", index=cached.index)
    part = cached[(cached["curve"] == name) & (cached["model"] == model_name) & (channels == key)]
    if part.empty or not np.array_equal(part[cols].iloc[0].to_numpy(float), alpha):
        return None
    f = np.unique(part["frequency_hz"].to_numpy())
    if f.size != freqs_hz.size or not np.allclose(f, np.sort(freqs_hz), rtol=0, atol=1e-9):
        return None
    return part.reset_index(drop=True)
