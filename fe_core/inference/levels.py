"""Noise levels from second differences along frequency: the evenly stepped bands, the differences, and the
clipped mean square that is unbiased for white noise and barely moved by a misfit smooth in frequency.

Shared by the one-level tests (:mod:`fe_core.inference.residual`) and the noise model per line and channel
(:mod:`fe_core.inference.noise`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr

__all__ = ["frequency_bands", "second_differences", "estimate_noise", "CLIP", "CLIP_FACTOR"]


def frequency_bands(freqs_hz, step_factor: float = 1.5) -> list[np.ndarray]:
    """Indices of contiguous, evenly stepped runs of increasing frequencies (a partition of the lines).

    A band goes on while each step is within ``step_factor`` of the step before it; where the step changes (a
    gap, or windows of different steps side by side) a new band starts at the next line. A line alone between a
    gap and an evenly stepped run is a band of its own. So every evenly stepped run of lines is one band whatever
    the other runs' steps (the benchmark's 106-116 Hz and 285-295 Hz give two; issue 28's windows of 9 lines
    round each mode, each at its own step, give one each, where a cut at 1.5 x the smallest step of all lines
    kept the lowest window only and split the others into single lines).
    """
    f = np.asarray(freqs_hz, float)
    if f.ndim != 1 or f.size == 0:
        raise ValueError("frequencies must be a non-empty 1-D array")
    order = np.argsort(f, kind="stable")
    steps = np.diff(f[order])

    def even(a: float, b: float) -> bool:
        return a > 0 and b > 0 and max(a, b) <= step_factor * min(a, b)

    bands, i, n = [], 0, f.size
    while i < n:
        j = min(i + 2, n)  # lines i..j-1; a band's first step needs no neighbour
        while j < n and even(steps[j - 1], steps[j - 2]):
            j += 1
        if j - i == 2 and j + 1 < n and even(steps[j], steps[j - 1]) and not even(steps[j - 1], steps[j - 2]):
            j = i + 1  # a line alone after a gap: the next line starts an evenly stepped run without it
        bands.append(order[i:j])
        i = j
    return bands


#: Second differences beyond this many standard deviations are not noise (:func:`estimate_noise`).
CLIP = 3.0
#: ``E[x^2 | |x| <= CLIP]`` for a standard normal x: the clipped mean square's factor for white noise.
#: (The standard normal's pdf and cdf as scipy.stats.norm computes them, without importing scipy.stats at import
#: time: 0.7 s of CPU in every process, most of which never call it.)
CLIP_FACTOR = float(1.0 - 2.0 * CLIP * (math.exp(-CLIP**2 / 2.0) / math.sqrt(2.0 * math.pi))
                    / (2.0 * ndtr(CLIP) - 1.0))


def second_differences(residual: np.ndarray, freqs_hz) -> np.ndarray:
    """``r[i-1] - 2 r[i] + r[i+1]`` along frequency within every evenly stepped band of three lines or more
    (:func:`frequency_bands`), every sensor, flattened; white noise of deviation sigma gives ``6 sigma^2`` each."""
    r = np.asarray(residual, float)
    d2 = [np.diff(r[idx], n=2, axis=0).ravel() for idx in frequency_bands(freqs_hz) if idx.size >= 3]
    return np.concatenate(d2) if d2 else np.empty(0)


def estimate_noise(residual: np.ndarray, freqs_hz) -> float:
    """Relative noise level from second differences of the residual along frequency, clipped at 3 sigma.

    For white noise of standard deviation sigma, ``d = r[i-1] - 2 r[i] + r[i+1]`` is normal with variance
    ``6 sigma^2``; a misfit that is smooth in frequency adds little. A misfit of a model near resonances is not
    smooth on lines stepped 5 % of a mode apart: it adds large second differences at a few lines. So the mean
    square is taken over the differences within ``CLIP`` = 3 of the level itself, iterated from the lower
    quartile's level (``q25(|d|) / (0.3186 sqrt 6)``) up to the fixed point ``sigma^2 = mean(d^2 : |d| <= 3 sqrt(6)
    sigma) / (6 CLIP_FACTOR)``; ``CLIP_FACTOR`` = 0.9733 is the clipped normal's second moment, so the level is unbiased for
    white noise (it drops 0.27 % of its differences; measured: mean of 3,000 estimates within 0.5 % of sigma on the
    own cases' lines, spread 8-10 % where the plain mean square's is 8-9 %). Differences of a structured residual
    that stand out are dropped: on issue 28's frame with a damaged patch, after the alpha-only fit (rms 3.8 %,
    noise 0.5 %), 0.76 % where the plain mean square gives 3.1 % (docs/guide/noise-estimate.md).

    Uses every sensor and every band with at least three frequencies (:func:`frequency_bands`).

    Parameters
    ----------
    residual : ndarray, shape (p, n)
        Log (or relative) residuals, frequencies in the order of ``freqs_hz``.
    freqs_hz : ndarray, shape (p,)

    Returns
    -------
    float
        sigma; NaN if no band has three frequencies.
    """
    d = second_differences(residual, freqs_hz)
    return float(_clipped_level(d[None, :])[0]) if d.size else float("nan")


def _clipped_level(d: np.ndarray) -> np.ndarray:
    """:func:`estimate_noise`'s level from second differences ``d``, shape (draws, m): one level per row."""
    from scipy import stats  # here, not at the top: 0.7 s of CPU to import, unused by most runs

    d = np.abs(d) / np.sqrt(6.0)
    # From below (the lower quartile's level): the iteration rises to the smallest fixed point, the noise's,
    # not to one a misfit at many lines would hold up (from the median it did where 3 of 7 differences were a peak).
    sigma = np.quantile(d, 0.25, axis=1) / stats.norm.ppf(0.625)
    rms = np.sqrt(np.mean(d**2, axis=1))
    sigma = np.where(sigma > 0, sigma, rms)  # quartile 0: most lines exact (noise-free data)
    for _ in range(200):
        kept = d <= CLIP * sigma[:, None]
        n = kept.sum(axis=1)
        new = np.sqrt(np.where(kept, d**2, 0.0).sum(axis=1) / np.maximum(n, 1) / CLIP_FACTOR)
        new = np.where(n > 0, new, sigma)
        if np.all(np.abs(new - sigma) <= 1e-9 * sigma):
            return new
        sigma = new
    return sigma


