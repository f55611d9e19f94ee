"""The hybrid's check: is what is left at a minimum noise, or structure? (:func:`check`)

The log amplitude residual tested against its noise per line and channel
(:func:`fe_core.inference.residual.analyse_residual`): the configured level, the noise the measurement states
(coherence and averages), or a relative term and a floor per channel estimated from the residual, which a misfit
smooth in frequency (a wrong basin) does not inflate. The measured data object
(:class:`fe_core.inference.frf_data.FRFData`) says where the k values sit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fe_core.inference.residual import STRUCTURED_ESTIMATE, analyse_residual

from .hybrid_phases import HybridOptions

__all__ = ["Check", "check"]


@dataclass(frozen=True)
class Check:
    """Noise or structure at a minimum (:func:`check`)."""

    at_floor: bool
    reason: str
    rms: float
    sigma: float
    sigma_source: str
    p_chi2: float
    noise_model: dict | None = None


def check(Z: np.ndarray, data, n_fitted: int, options: HybridOptions) -> Check:
    """Is the residual at ``Z`` (shape (k,), the model at the kept values of ``data``, an
    :class:`fe_core.inference.frf_data.FRFData`) noise? The test of the log amplitude residual against its noise.

    ``ln(|Z| / |measured|)`` (:mod:`fe_core.inference.residual`: multiplicative noise is additive there) on the
    lines where every channel is kept, against the noise per line and channel (:meth:`FRFData.noise_spec`): the
    configured level, or the noise the measurement states (coherence and averages), or a relative term and a
    floor per channel estimated from this residual and tested against white noise of that model (a misfit
    smooth in frequency, a wrong basin, does not inflate it). An estimated relative term above ``max_noise`` is
    not believed. Noise when the test passes or the residual's rms is within ``noise_ratio`` times the noise (a
    wrong basin leaves several times the noise: 10-40 % against 1 % on the benchmark's suite).
    """
    Z = np.asarray(Z)
    error = data.error(Z)
    r = data.log_residual(Z)
    rms = float(np.sqrt(np.mean(r**2)))
    if error <= options.target:
        return Check(True, f"overall error {error:.3e} <= target {options.target:.1e}", rms, float("nan"), "none", 1.0)
    complete = data.complete_lines
    grid = data.log_grid(Z)[complete]
    freqs = np.asarray(data.frequencies_hz, float)[complete]
    try:
        a = analyse_residual(grid, freqs, n_fitted, data.noise_spec(options.noise, complete), options.significance,
                             max_noise=options.max_noise)
    except ValueError as exc:
        return Check(False, f"{exc}: treated as structure", rms, float("nan"), "none", 0.0)
    sigma = a.model.sigma if a.model is not None else a.sigma
    ratio = float(np.sqrt(np.mean((grid / sigma) ** 2)))  # rms of the residual in units of its noise
    where = "configured" if a.sigma_source == "configured" and a.model is None else a.sigma_source
    reason = (f"rms {rms:.3%} vs noise {a.sigma:.3%}{' (median)' if a.model is not None else ''} ({where}); "
              f"chi2 {a.chi2:.1f} on {a.dof} dof, p = {a.p_chi2:.3g}")
    level = float(np.max(a.model.relative)) if a.model is not None and a.model.relative is not None else a.sigma
    if a.sigma_source == STRUCTURED_ESTIMATE and level > options.max_noise:
        return Check(False, f"{reason}; but an estimated noise of {level:.1%} is above the {options.max_noise:.0%} "
                            "believed for measured amplitudes: structure", rms, a.sigma, a.sigma_source, a.p_chi2,
                     a.noise_model)
    at_floor = a.p_chi2 >= options.significance or ratio <= options.noise_ratio
    why = "noise" if a.p_chi2 >= options.significance else (f"rms within {options.noise_ratio:g} x the noise"
                                                             if at_floor else "structure")
    source = a.sigma_source
    if source == STRUCTURED_ESTIMATE and at_floor:
        source = "estimated"  # within noise_ratio of it: the level is the noise's
    return Check(at_floor, f"{reason}: {why}", rms, a.sigma, source, a.p_chi2, a.noise_model)
