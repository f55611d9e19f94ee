"""Raw hammer records to H1 FRFs with coherence, averaged over the hits.

A hit is one force record and one record per response channel, sampled together. Per hit:

1. **force**: its baseline (median) removed; the noise level ``sigma`` is the robust spread of the record
   (1.4826 median absolute deviation: the pulse is a few samples of many); the pulse is the run of samples
   around the largest value above ``max(5 sigma, 2 %)`` of it. A hit whose largest force is not above
   ``PULSE_SIGMAS`` (10) times the noise has no pulse and is refused; a second pulse after the force window
   (above ``max(10 sigma, 5 %)`` of the first) is a double hit and is refused.
2. **force window**: rectangular, 1 around the pulse and 0 elsewhere, so the force channel's noise outside
   the pulse does not enter the spectrum. By default it starts one pulse width before the pulse and ends
   two pulse widths after it, at least ``FILTER_SAMPLES`` (16) each side: a pulse of a few samples carries
   the analyser's anti-alias filter's ringing on both sides (a decimating FIR filter rings for 10-20
   samples), and cutting it off biases the force spectrum near the band's top by about 1 % (measured);
   ``force_window_s`` sets the window's length from that start.
3. **exponential window** (``exponential_end``, default none): ``w(t) = exp(-(t - t0) / tau)``, 1 at the
   pulse's start ``t0`` (and slightly above 1 in the pre-trigger, so that the filter's ringing before the
   pulse is weighted consistently), with ``tau`` such that ``w`` is ``exponential_end`` at the record's end, on the
   responses *and* on the force, so that the estimate is exactly the structure's FRF at
   ``s = 1/tau + j omega`` (the Laplace shift theorem). That adds ``1/tau`` to every mode's decay rate: mode
   ``r``'s damping ratio reads ``zeta_r + 1 / (tau omega_r)``, to first order a Rayleigh mass coefficient
   ``a + 2 / tau``; the note says so, and the model must carry that damping (or the window be left out,
   as it should be when the response dies out within the record). A response still above 2 % of its peak
   in the last 5 % of the record without the window is noted (leakage).
4. **record length** (``record_s``, default the whole record) and **line spacing** (``line_spacing_hz``,
   default 1 / record length; a finer spacing zero-pads, which interpolates lines but adds no
   information); **frequency range** (``band_hz``, default above 0 up to ``fs / 2.56``, the band analysers
   keep below their anti-alias filter).

Over the hits: ``H1 = sum X F* / sum |F|^2``, ordinary coherence ``|sum X F*|^2 / (sum |F|^2 sum |X|^2)``,
``averages`` = the number of hits. numpy's FFT, not SDyPy's pyFRF: pyFRF 1.5.0 multiplies H1 by
``len(w_force) / sum(w_exp)`` when force and exponential windows are used (an amplitude normalisation that
is right for a periodic signal and wrong for a transient: x4.65 for an exponential window down to 1 %,
measured on a single-DOF oscillator), and it brings five more packages.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .frf import MeasuredDataError
from .problems import Problems

__all__ = ["Records", "RecordOptions", "h1_from_records", "PULSE_SIGMAS", "ANALYSER_RATIO", "FILTER_SAMPLES"]

#: A pulse must rise above this many times the force channel's noise.
PULSE_SIGMAS = 10.0
#: Samples the force window keeps at least on each side of the pulse (the anti-alias filter's ringing).
FILTER_SAMPLES = 16
#: Default highest line: the sample rate over 2.56 (the band analysers keep below the anti-alias filter).
ANALYSER_RATIO = 2.56
_QUANTITY_KIND = {"displacement": "receptance", "velocity": "mobility", "acceleration": "accelerance"}


@dataclass
class Records:
    """The hits of a test, in SI, checked by the reader (same sample rate and length everywhere).

    Attributes
    ----------
    sample_rate_hz : float
    force : ndarray, shape (h, t), N
        The force of each of the ``h`` hits, ``t`` samples.
    responses : ndarray, shape (h, c, t)
        The ``c`` response channels of each hit, SI (m/s^2, m/s or m).
    labels : list of str, length c
        Response label of each channel (a sensor name or ``NODE:DIR``).
    quantities : list of str, length c
        ``"acceleration"``, ``"velocity"`` or ``"displacement"``.
    reference : str or None
        The force's DOF (``NODE:DIR``) or excitation name; None = the model's default excitation.
    units : list of str, length c
        The unit of each channel's FRF as the file had it (``"g/N"``).
    hits : list of str, length h
        Where each hit's force is in the file (``"dataset 3 (hit 2)"``, ``"hit 2 (line 1026)"``).
    source : str
    notes : list of str
    """

    sample_rate_hz: float
    force: np.ndarray
    responses: np.ndarray
    labels: list
    quantities: list
    reference: str | None
    units: list
    hits: list
    source: str
    notes: list = field(default_factory=list)


@dataclass(frozen=True)
class RecordOptions:
    """The processing choices (module docstring); None = the default.

    Attributes
    ----------
    force_window_s : float or None
        Length of the rectangular force window, s, from one pulse width before the pulse.
    exponential_end : float or None
        Value of the exponential window at the record's end, in (0, 1); None = no exponential window.
    record_s : float or None
        Use the first ``record_s`` seconds of each record.
    line_spacing_hz : float or None
        Spacing of the lines, Hz; at most 1 / record length (finer = zero padding).
    band_hz : tuple of float or None
        ``(low, high)``, Hz: the lines kept (0 Hz is never kept).
    """

    force_window_s: float | None = None
    exponential_end: float | None = None
    record_s: float | None = None
    line_spacing_hz: float | None = None
    band_hz: tuple | None = None

    def check(self, source) -> None:
        for name in ("force_window_s", "record_s", "line_spacing_hz"):
            value = getattr(self, name)
            if value is not None and not (np.isfinite(value) and value > 0):
                raise MeasuredDataError(f"{source}: {name} must be > 0, got {value!r}")
        if self.exponential_end is not None and not 0 < self.exponential_end < 1:
            raise MeasuredDataError(f"{source}: exponential_end must lie in (0, 1) (the window's value at the "
                                    f"record's end, e.g. 0.01), got {self.exponential_end!r}")
        if self.band_hz is not None and not (len(self.band_hz) == 2 and 0 <= self.band_hz[0] < self.band_hz[1]):
            raise MeasuredDataError(f"{source}: band_hz must be (low, high) with 0 <= low < high, got {self.band_hz!r}")


def _pulse(force, fs, place, problems):
    """(start, end) sample of the pulse, the noise level and the peak; a problem (None) without a pulse."""
    sigma = 1.4826 * np.median(np.abs(force))
    peak_at = int(np.argmax(np.abs(force)))
    peak = abs(force[peak_at])
    if peak == 0 or peak <= PULSE_SIGMAS * sigma:
        problems.add(f"{place}: no pulse: the force never rises above {PULSE_SIGMAS:g} times its noise "
                     f"({peak:.3g} N at most, noise {sigma:.3g} N rms); a hit without a hammer impact")
        return None
    above = np.abs(force) > max(5 * sigma, 0.02 * peak)
    start = peak_at
    while start > 0 and above[start - 1]:
        start -= 1
    end = peak_at
    while end < force.size - 1 and above[end + 1]:
        end += 1
    return start, end, sigma, peak


def _force_window(force, fs, pulse, options, place, problems):
    start, end, sigma, peak = pulse
    width = end - start + 1
    first = max(0, start - max(width, FILTER_SAMPLES))
    if options.force_window_s is not None:
        last = min(force.size - 1, first + int(round(options.force_window_s * fs)) - 1)
    else:
        last = min(force.size - 1, end + max(2 * width, FILTER_SAMPLES))
    window = np.zeros(force.size)
    window[first:last + 1] = 1.0
    after = np.flatnonzero(np.abs(force[last + 1:]) > max(10 * sigma, 0.05 * peak))
    if after.size:
        t = (last + 1 + after[0]) / fs
        problems.add(f"{place}: a second pulse at t = {t:.4g} s ({abs(force[last + 1 + after[0]]):.3g} N, the first "
                     f"{peak:.3g} N): a double hit; leave the hit out")
    if last < end:
        problems.add(f"{place}: force_window_s {options.force_window_s!r} ends before the pulse does "
                     f"({(end - first + 1) / fs:.3g} s from the window's start)")
    return window, first, last


def h1_from_records(records: Records, options: RecordOptions | None = None):
    """H1 FRFs, ordinary coherence and the number of averages from raw hammer records.

    Parameters
    ----------
    records : Records
    options : RecordOptions, optional

    Returns
    -------
    dict
        ``frequency_hz`` (p,), Hz; ``frf`` (p, c) complex, response quantity (SI) per N; ``coherence`` (p, c);
        ``kinds`` (c,) FRF kind per channel; ``averages`` (number of hits); ``notes`` (list of str).

    Raises
    ------
    MeasuredDataError
        A hit without a pulse, a double hit, choices that do not fit the records; every hit checked first.
    """
    options = options or RecordOptions()
    source = records.source
    options.check(source)
    fs = records.sample_rate_hz
    force, responses = records.force, records.responses
    n_hits, n_channels, n_samples = responses.shape
    if options.record_s is not None:
        keep = int(round(options.record_s * fs))
        if keep > n_samples:
            raise MeasuredDataError(f"{source}: record_s {options.record_s!r} s is longer than the records "
                                    f"({n_samples / fs:g} s)")
        force, responses, n_samples = force[:, :keep], responses[:, :, :keep], keep
    n_fft = n_samples
    if options.line_spacing_hz is not None:
        n_fft = int(round(fs / options.line_spacing_hz))
        if abs(fs / options.line_spacing_hz - n_fft) > 1e-6 * n_fft:
            raise MeasuredDataError(f"{source}: line_spacing_hz {options.line_spacing_hz!r}: the sample rate "
                                    f"{fs:g} Hz is not a whole number of lines apart")
        if n_fft < n_samples:
            raise MeasuredDataError(f"{source}: line_spacing_hz {options.line_spacing_hz!r} is coarser than 1 / record "
                                    f"length ({fs / n_samples:g} Hz); shorten the record with record_s")
    problems = Problems(source)
    windows = []
    for h in range(n_hits):
        f = force[h] - np.median(force[h])
        pulse = _pulse(f, fs, records.hits[h], problems)
        if pulse is not None:
            windows.append((f, pulse) + _force_window(f, fs, pulse, options, records.hits[h], problems))
    problems.check()
    notes = [f"raw records: {n_hits} hits of {n_samples} samples at {fs:g} Hz ({n_samples / fs:g} s), "
             f"{n_channels} response channel(s)"]
    t = np.arange(n_samples) / fs
    sxf = np.zeros((n_fft // 2 + 1, n_channels), complex)
    sff = np.zeros(n_fft // 2 + 1)
    sxx = np.zeros((n_fft // 2 + 1, n_channels))
    lengths, decay, leaking = [], None, set()
    for h, (f, pulse, window, first, last) in enumerate(windows):
        lengths.append((last - first + 1) / fs)
        x = responses[h]
        if options.exponential_end is not None:
            t0 = pulse[0] / fs
            tau = (t[-1] - t0) / -np.log(options.exponential_end)
            exp = np.exp(-(t - t0) / tau)  # over the whole record (above 1 before t0): the shift is then exact
            decay = 1.0 / tau if decay is None else max(decay, 1.0 / tau)
            window, x = window * exp, x * exp
        else:
            tail = np.sqrt(np.mean(x[:, -max(n_samples // 20, 1):] ** 2, axis=1))
            leaking |= set(np.flatnonzero(tail > 0.02 * np.max(np.abs(x), axis=1)).tolist())
        F = np.fft.rfft(f * window, n_fft)
        X = np.fft.rfft(x, n_fft, axis=1).T
        sxf += X * np.conj(F)[:, None]
        sff += np.abs(F) ** 2
        sxx += np.abs(X) ** 2
    notes.append(f"force window: rectangular, {min(lengths) * 1e3:.3g}..{max(lengths) * 1e3:.3g} ms around each "
                 f"pulse" + ("" if options.force_window_s is None else f" (force_window_s {options.force_window_s:g})"))
    if decay is not None:
        notes.append(f"exponential window to {options.exponential_end:g} at the record's end on force and responses: "
                     f"decay rate {decay:.4g} 1/s added to every mode (damping ratio + {decay:.4g} / omega_r; to "
                     f"first order Rayleigh a + {2 * decay:.4g} 1/s): the FRF is the structure's at s = "
                     f"{decay:.4g} + j omega")
    elif leaking:
        names = ", ".join(records.labels[c] for c in sorted(leaking))
        notes.append(f"the response of {names} has not died out by the record's end (last 5 % above 2 % of its "
                     "peak): leakage; use an exponential window (exponential_end) or longer records")
    lines = np.arange(n_fft // 2 + 1) * fs / n_fft
    low, high = options.band_hz if options.band_hz is not None else (0.0, fs / ANALYSER_RATIO)
    keep = (lines > 0) & (lines >= low) & (lines <= high * (1 + 1e-12))
    if not keep.any():
        raise MeasuredDataError(f"{source}: no line in the band {low:g}..{high:g} Hz (lines {fs / n_fft:g} Hz apart)")
    with np.errstate(divide="ignore", invalid="ignore"):
        frf = sxf[keep] / sff[keep, None]
        coherence = np.clip(np.abs(sxf[keep]) ** 2 / (sff[keep, None] * sxx[keep]), 0.0, 1.0)
    bad = ~np.isfinite(frf).all(axis=1) | ~np.isfinite(coherence).all(axis=1)
    if bad.any():
        raise MeasuredDataError(f"{source}: the force spectrum is 0 at {lines[keep][bad][0]:g} Hz: no excitation "
                                "there; narrow the band (band_hz)")
    pad = "" if n_fft == n_samples else f", zero-padded to {n_fft} samples"
    notes.append(f"H1 and ordinary coherence over {n_hits} hits at {int(keep.sum())} lines "
                 f"{lines[keep][0]:g}..{lines[keep][-1]:g} Hz ({fs / n_fft:g} Hz apart{pad})")
    return {"frequency_hz": lines[keep], "frf": frf, "coherence": coherence, "averages": n_hits, "notes": notes,
            "kinds": [_QUANTITY_KIND[q] for q in records.quantities]}
