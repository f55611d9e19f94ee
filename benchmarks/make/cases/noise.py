"""The measurement as an impact test produces it, and the file a test system exports.

Per channel group (the channels measured in one run; the run with fewer hits is a group of its own), each hit is
a half-sine force pulse (contact time ``PULSE_S`` of the band's top, peak force varying by +-30 %) and, per line,
complex Gaussian noise:

* response: ``relative * sqrt(averages)`` of the response per hit (so the H1 estimate of a channel with the
  full number of averages carries ``relative`` noise), plus a sensor floor of ``floor`` times the channel's
  largest response (an accelerometer's floor is an acceleration: where the accelerance is small, near 0 Hz and
  at the anti-resonances, the floor dominates and the coherence drops);
* force: ``force`` of the force per hit.

The FRF is the H1 estimate ``sum X F* / sum |F|^2`` and the ordinary coherence
``|sum X F*|^2 / (sum |F|^2 sum |X|^2)`` per line, as analysers compute them (``benchmarks.make.hammer`` does the
same for the benchmark). A channel with fewer averages has the same per-hit noise, so more noise after averaging
and a lower coherence.

The file: a long table (``response,frequency_hz,real,imag,coherence,averages``; ``# kind = accelerance``), every
line from 0 Hz to the band's top at the step, 7 significant digits (a test system's single precision), each
channel's number of averages in its rows (docs/measured-formats.md).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

PULSE_OF_TOP = 0.4      # contact time = PULSE_OF_TOP / top (Hz): the force's first zero at 3.75 times the top
PEAK_FORCE_N = 100.0


def pulse_spectrum(f_hz: np.ndarray, peak: float, duration: float) -> np.ndarray:
    """Fourier transform of ``peak sin(pi t / duration)`` on ``0 <= t <= duration``, N s."""
    w = 2 * np.pi * np.asarray(f_hz, float)
    a = np.pi / duration
    return peak * a * (1 + np.exp(-1j * w * duration)) / (a**2 - w**2)


def simulate(accelerance: np.ndarray, f_hz: np.ndarray, settings: dict, rng: np.random.Generator):
    """H1 estimate and ordinary coherence of the simulated hits.

    Parameters
    ----------
    accelerance : ndarray, shape (p, n), complex, (m/s^2)/N
    f_hz : ndarray, shape (p,), Hz
    settings : dict
        ``relative``, ``floor``, ``force`` (fractions), ``channel_averages`` (n,) ints.

    Returns
    -------
    H1 : ndarray, shape (p, n), complex
    coherence : ndarray, shape (p, n)
    """
    p, n = accelerance.shape
    averages = np.asarray(settings["channel_averages"], int)
    full = int(averages.max())
    duration = PULSE_OF_TOP / float(f_hz.max())
    mean_force = pulse_spectrum(f_hz, PEAK_FORCE_N, duration)
    floor = settings["floor"] * np.max(np.abs(accelerance * mean_force[:, None]), axis=0)   # (n,)
    H1 = np.zeros((p, n), complex)
    coherence = np.zeros((p, n))
    for group in sorted(set(averages.tolist()), reverse=True):
        cols = np.flatnonzero(averages == group)
        sxf = np.zeros((p, cols.size), complex)
        sff = np.zeros(p)
        sxx = np.zeros((p, cols.size))
        for _ in range(group):
            force = mean_force * rng.uniform(0.7, 1.3)
            response = accelerance[:, cols] * force[:, None]
            sigma = np.sqrt((settings["relative"] * np.sqrt(full) * np.abs(response)) ** 2 + floor[cols] ** 2)
            x = response + sigma * (rng.standard_normal((p, cols.size)) + 1j * rng.standard_normal((p, cols.size))) \
                / np.sqrt(2)
            fm = force + settings["force"] * np.abs(force) * (rng.standard_normal(p) + 1j * rng.standard_normal(p)) \
                / np.sqrt(2)
            sxf += x * np.conj(fm)[:, None]
            sff += np.abs(fm) ** 2
            sxx += np.abs(x) ** 2
        H1[:, cols] = sxf / sff[:, None]
        coherence[:, cols] = np.abs(sxf) ** 2 / (sff[:, None] * sxx)
    return H1, np.clip(coherence, 0.0, 1.0)


def write_table(path: Path, names, f_hz, H1, coherence, averages, header: list[str]) -> str:
    """Write the long table (module docstring) atomically; returns its SHA-256."""
    rows = [f"# {h}" for h in header] + ["# kind = accelerance", "response,frequency_hz,real,imag,coherence,averages"]
    for j, name in enumerate(names):
        for k, f in enumerate(f_hz):
            rows.append(f"{name},{f:.7g},{H1[k, j].real:.7g},{H1[k, j].imag:.7g},{coherence[k, j]:.6f},"
                        f"{int(averages[j])}")
    text = "\n".join(rows) + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return hashlib.sha256(text.encode()).hexdigest()
