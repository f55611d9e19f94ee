"""Modes identified from measured FRFs with sdypy-EMA (LSCF poles, LSFD constants), for the modal update.

:func:`identify_modes` takes the complex receptance of one reference (a :class:`MeasuredFRF` read from
UFF58 or a table), finds the poles by LSCF (``sdypy.EMA.Model.get_poles``) up to ``pol_order_high``,
picks the stable pole nearest to each peak of the summed FRF amplitude (``select_closest_poles``: a pole
is stable when its frequency and damping change by less than 0.1 % and 5 % from one order to the next),
fits the modal constants by LSFD with lower and upper residuals, and returns :class:`MeasuredModes`: the
frequencies, damping ratios and the real modes of the constants' columns (the complex-to-real rule of
:func:`tasks.io.measured.modes.real_mode`). The stabilisation result (how many polynomial orders hold a
stable pole within 0.5 % of each chosen frequency) is returned for the report.
"""

from __future__ import annotations

import numpy as np

from tasks.io.measured.frf import MeasuredDataError
from tasks.io.measured.modes import MeasuredModes, real_mode

__all__ = ["identify_modes"]


def identify_modes(measured, lower_hz: float, upper_hz: float, pol_order_high: int = 40,
                   prominence: float = 0.05) -> tuple[MeasuredModes, dict]:
    """Identify modes in ``[lower_hz, upper_hz]`` from one reference's complex FRFs (see the module docstring).

    Returns ``(modes, stabilisation)``; ``stabilisation`` has ``peaks_hz``, ``stable_orders`` per mode and
    ``pol_order_high``.
    """
    from scipy.signal import find_peaks
    from sdypy import EMA

    if measured.complex_frf is None or measured.responses is None:
        raise MeasuredDataError(f"{measured.source}: identifying modes needs complex FRFs with NODE:DIR responses")
    refs = set(measured.references or ())
    if len(refs) != 1:
        raise MeasuredDataError(f"{measured.source}: identifying modes needs one reference, got {sorted(refs)}")
    f = measured.frequencies_hz
    band = (f >= lower_hz) & (f <= upper_hz)
    H = measured.complex_frf[band]
    f = f[band]
    total = np.sum(np.abs(H), axis=1)
    peaks, _ = find_peaks(np.log(total), prominence=prominence)
    if not peaks.size:
        raise MeasuredDataError(f"{measured.source}: no resonance peak between {lower_hz:g} and {upper_hz:g} Hz")
    model = EMA.Model(frf=H.T, freq=f, lower=float(f[0]), upper=float(f[-1]), pol_order_high=pol_order_high,
                      frf_form="receptance")
    model.get_poles(method="lscf", show_progress=False)
    model.select_closest_poles(list(f[peaks]), f_window=max(4.0, 0.1 * float(f[peaks].min())))
    model.get_constants(method="lsfd")
    A = np.asarray(model.A)  # (n_locations, n_modes), complex modal constants
    freqs = np.asarray(model.nat_freq, float)
    stable = [int(np.sum(np.any(np.abs(model.f_stable - fn) < 0.005 * fn, axis=0))) if fn > 0 else 0
              for fn in freqs]
    # a peak without a pole stable over a quarter of the orders is noise (near 0 Hz, at anti-resonances)
    keep = [k for k in range(freqs.size) if freqs[k] > 0 and stable[k] >= pol_order_high // 4]
    if not keep:
        raise MeasuredDataError(f"{measured.source}: no stable pole between {lower_hz:g} and {upper_hz:g} Hz")
    dropped = [float(f[peaks][k]) for k in range(freqs.size) if k not in keep]
    model.nat_freq, model.nat_xi = freqs[keep], np.asarray(model.nat_xi)[keep]
    model.pole_ind = np.asarray(model.pole_ind)[keep]
    model.get_constants(method="lsfd")  # again, with the stable poles only
    A = np.asarray(model.A)
    freqs, stable = freqs[keep], [stable[k] for k in keep]
    shapes, mpcs = zip(*(real_mode(A[:, k]) for k in range(A.shape[1])))
    modes = MeasuredModes(freqs, np.asarray(model.nat_xi, float), np.array(shapes), list(measured.responses),
                          [f"mode {k + 1}" for k in range(freqs.size)], [f"identified mode {k + 1}"
                                                                        for k in range(freqs.size)],
                          measured.source, [f"mode {k + 1}: identified by LSCF/LSFD (sdypy-EMA), MPC {m:.3f}, "
                                            f"stable in {s} of {pol_order_high} orders"
                                            for k, (m, s) in enumerate(zip(mpcs, stable))])
    return modes, {"peaks_hz": f[peaks].tolist(), "dropped_peaks_hz": dropped, "stable_orders": stable, "pol_order_high": pol_order_high,
                   "mpc": list(mpcs)}
