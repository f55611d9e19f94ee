"""Measurement noise as a test system makes it: a relative response noise, a floor per channel and force noise."""

from __future__ import annotations

import numpy as np


#: The accelerometers' floor, relative to each channel's peak acceleration response (80 dB of dynamic range).
FLOOR = 1e-4


def noisy(H: np.ndarray, rng: np.random.Generator, freqs_hz, relative: float = 0.01, floor: float = FLOOR,
          force: float = 0.002) -> tuple[np.ndarray, np.ndarray]:
    """The receptance ``H`` (p, n) as measured with accelerometers: ``H (1 + relative e_r) / (1 + force e_f)`` plus
    a floor of ``floor`` times each channel's peak *acceleration* response, ``floor max|w^2 H_s| e_s / w^2``, with
    complex standard normal ``e`` (``e_f`` one per line, shared by the channels: the hammer's force). The floor is
    the accelerometer's (its own units), so in receptance it falls as 1 / w^2: at the band's top it matters only at
    antiresonances, at the lowest lines (far below the first mode) it dominates.

    Returns the noisy FRF and the ordinary coherence a test system would export with it, ``|H|^2 / (|H|^2 +
    n^2)`` with ``n`` the floor in receptance (the relative and force noise, a per cent, hardly lower it)."""
    def cn(*shape):
        return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(2)

    p, n = H.shape
    w2 = (2 * np.pi * np.asarray(freqs_hz, float))[:, None] ** 2
    peak = np.max(np.abs(w2 * H), axis=0)
    level = floor * peak[None, :] / w2
    coherence = np.abs(H) ** 2 / (np.abs(H) ** 2 + level**2)
    return H * (1 + relative * cn(p, n)) / (1 + force * cn(p, 1)) + level * cn(p, n), coherence


def write_table(path, freqs_hz, H: np.ndarray, coherence: np.ndarray) -> None:
    """``sensor, frequency_hz, amplitude, real, imag, coherence`` (receptance, sensors 1..n under the model's
    excitation)."""
    rows = ["sensor,frequency_hz,amplitude,real,imag,coherence"]
    for k, f in enumerate(np.asarray(freqs_hz, float)):
        for j in range(H.shape[1]):
            h = complex(H[k, j])
            rows.append(f"{j + 1},{float(f)!r},{abs(h)!r},{h.real!r},{h.imag!r},{float(coherence[k, j]):.6f}")
    path.write_text("\n".join(rows) + "\n")
