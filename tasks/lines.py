"""Which measured lines enter the update: all, listed windows, or windows around the resonances.

Pure numpy/scipy on the measured receptance (the file's kind does not matter:
the conversion changes every channel by the same factor per line, so the
peaks and bands found here are the same for a receptance, a mobility or an
accelerance file up to rounding).

Resonances
    The power sum of the channels, each normalised to its own largest
    amplitude so that weak channels count, ``S(f) = mean_c (|H_c(f)| /
    max |H_c|)^2`` over the values whose coherence passes (lines without any
    are left out: converted to receptance, noise near 0 Hz makes false
    peaks); its peaks whose prominence is at least
    ``PEAK_PROMINENCE_DECADES`` decades (a factor 2 in power) are resonances.
    Each one's half-power band is where ``S`` stays above half the peak
    (``|H|`` above ``1/sqrt(2)`` of it), walking outwards at most to the
    lowest point between neighbouring peaks. The window is that band widened
    by ``widen`` about the peak: ``[f0 - widen (f0 - f_lo), f0 + widen
    (f_hi - f0)]``; overlapping windows merge.

Coherence
    A line of a channel whose ordinary coherence is below ``min_coherence``
    is left out of the residual (a noise-dominated estimate); a line left
    with no channel is dropped. The counts go to the run's manifest.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["LINE_MODES", "PEAK_PROMINENCE_DECADES", "LineSelection", "resonance_windows", "select_lines"]

LINE_MODES = ("all", "windows", "resonances")
#: Smallest prominence of a resonance peak in log10 of the power sum: 0.3 decades is a factor 2.
PEAK_PROMINENCE_DECADES = 0.3


@dataclass(frozen=True)
class LineSelection:
    """The lines and (line, channel) values that enter the update.

    Attributes
    ----------
    lines : ndarray of bool, shape (p,)
        Over the measured lines.
    mask : ndarray of bool, shape (p_selected, n)
        Over the selected lines: the values whose coherence passed.
    mode : str
    windows : list of (float, float), Hz
        The windows given or found (empty for ``all``).
    resonances_hz : list of float
        Peaks found (``resonances`` mode).
    coherence_dropped : int
        Values (line, channel) of the selected windows left out for coherence.
    lines_dropped : int
        Selected lines left with no channel after the coherence threshold.
    """

    lines: np.ndarray
    mask: np.ndarray
    mode: str
    windows: list = field(default_factory=list)
    resonances_hz: list = field(default_factory=list)
    coherence_dropped: int = 0
    lines_dropped: int = 0


def resonance_windows(frequencies_hz, amplitude, widen: float = 2.0,
                      prominence: float = PEAK_PROMINENCE_DECADES, valid=None) -> tuple[list, list]:
    """Windows around the resonances of measured FRFs (see the module docstring).

    Parameters
    ----------
    frequencies_hz : ndarray, shape (p,), Hz, increasing
    amplitude : ndarray, shape (p, n)
    widen : float
        >= 1; 1 keeps the half-power band itself.
    prominence : float
        In decades of the power sum.
    valid : ndarray of bool, shape (p, n), optional
        Values to use (e.g. coherence above the threshold): the power sum
        averages the valid channels of each line, lines with none are left
        out of the search (noise-dominated lines make false peaks).

    Returns
    -------
    windows : list of (low, high), Hz, merged and sorted
    peaks : list of float, Hz
    """
    from scipy.signal import find_peaks

    f = np.asarray(frequencies_hz, float)
    a = np.asarray(amplitude, float)
    valid = np.ones(a.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    rows = valid.any(axis=1)
    f, a, valid = f[rows], a[rows], valid[rows]
    if f.size < 3:
        return [], []
    peak = np.array([a[valid[:, c], c].max() if valid[:, c].any() else 1.0 for c in range(a.shape[1])])
    power = np.sum(np.where(valid, (a / peak) ** 2, 0.0), axis=1) / valid.sum(axis=1)
    log_power = np.log10(power)
    peaks, _ = find_peaks(log_power, prominence=prominence)
    windows = []
    for k, i in enumerate(peaks):
        left_stop = peaks[k - 1] + np.argmin(power[peaks[k - 1]:i + 1]) if k else 0
        right_stop = i + np.argmin(power[i:peaks[k + 1] + 1]) if k + 1 < peaks.size else f.size - 1
        lo = i
        while lo > left_stop and power[lo - 1] >= 0.5 * power[i]:
            lo -= 1
        hi = i
        while hi < right_stop and power[hi + 1] >= 0.5 * power[i]:
            hi += 1
        f_lo = _crossing(f, power, lo, lo - 1, 0.5 * power[i]) if lo > left_stop else f[lo]
        f_hi = _crossing(f, power, hi, hi + 1, 0.5 * power[i]) if hi < right_stop else f[hi]
        windows.append((f[i] - widen * (f[i] - f_lo), f[i] + widen * (f_hi - f[i])))
    return _merge(windows), [float(f[i]) for i in peaks]


def _crossing(f, power, inside, outside, level) -> float:
    """Where ``power`` crosses ``level`` between two neighbouring lines (linear interpolation)."""
    p0, p1 = power[inside], power[outside]
    t = (p0 - level) / (p0 - p1) if p0 != p1 else 0.0
    return float(f[inside] + t * (f[outside] - f[inside]))


def _merge(windows) -> list:
    out = []
    for lo, hi in sorted(windows):
        if out and lo <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((float(lo), float(hi)))
    return out


def select_lines(frequencies_hz, amplitude, coherence=None, mode: str = "all", windows=None, widen: float = 2.0,
                 min_coherence: float = 0.0) -> LineSelection:
    """The lines and values of the update (see the module docstring).

    Parameters
    ----------
    frequencies_hz : ndarray, shape (p,), Hz
    amplitude : ndarray, shape (p, n)
    coherence : ndarray, shape (p, n), optional
    mode : {"all", "windows", "resonances"}
    windows : sequence of (low, high), Hz
        For ``windows``; a line on an edge is inside.
    widen : float
        For ``resonances``.
    min_coherence : float
        Values below it are left out (no effect without coherence).
    """
    if mode not in LINE_MODES:
        raise ValueError(f"lines must be one of {', '.join(LINE_MODES)}, got {mode!r}")
    f = np.asarray(frequencies_hz, float)
    peaks: list = []
    if mode == "all":
        windows = []
        lines = np.ones(f.size, dtype=bool)
    else:
        if mode == "resonances":
            valid = None if coherence is None or min_coherence <= 0 else np.asarray(coherence) >= min_coherence
            windows, peaks = resonance_windows(f, amplitude, widen, valid=valid)
        windows = [(float(lo), float(hi)) for lo, hi in windows]
        lines = np.zeros(f.size, dtype=bool)
        for lo, hi in windows:
            lines |= (f >= lo) & (f <= hi)
    mask = np.ones((int(lines.sum()), np.shape(amplitude)[1]), dtype=bool)
    dropped = 0
    if coherence is not None and min_coherence > 0:
        mask = np.asarray(coherence)[lines] >= min_coherence
        dropped = int((~mask).sum())
    empty = ~mask.any(axis=1)
    if empty.any():
        keep = np.flatnonzero(lines)
        lines = lines.copy()
        lines[keep[empty]] = False
        mask = mask[~empty]
    return LineSelection(lines=lines, mask=mask, mode=mode, windows=windows, resonances_hz=peaks,
                         coherence_dropped=dropped, lines_dropped=int(empty.sum()))
