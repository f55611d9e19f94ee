"""The hybrid's check: is what is left at a minimum noise, or structure? (:func:`check`)

The chi-square test of the log amplitude residual (:func:`fe_core.inference.residual.chi_square_test`) against
the configured noise, or the noise estimated from second differences along frequency, which a misfit smooth in
frequency (a wrong basin) does not inflate. The measured data object (:class:`fe_core.inference.frf_data.FRFData`) says where the k values sit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fe_core.inference.residual import (
    STRUCTURED_ESTIMATE,
    chi_square_test,
    estimate_noise,
    estimated_noise_test,
)

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


def check(Z: np.ndarray, data, n_fitted: int, options: HybridOptions) -> Check:
    """Is the residual at ``Z`` (shape (k,), the model at the kept values of ``data``, an
    :class:`fe_core.inference.frf_data.FRFData`) noise? The chi-square test of the log amplitude residual.

    ``ln(|Z| / |measured|)`` (:mod:`fe_core.inference.residual`: multiplicative noise is additive there) against the
    configured noise, or the noise estimated from second differences along frequency on the lines where every
    channel is kept (``estimate_noise``, its p from ``estimated_noise_test``); an estimate above ``max_noise`` is
    not believed. Noise when the test passes or the rms is
    within ``noise_ratio`` times the noise (a wrong basin leaves several times the noise: 10-40 % against
    1 % on the benchmark's suite).
    """
    Z = np.asarray(Z)
    error = data.error(Z)
    r = data.log_residual(Z)
    rms = float(np.sqrt(np.mean(r**2)))
    if error <= options.target:
        return Check(True, f"overall error {error:.3e} <= target {options.target:.1e}", rms, float("nan"), "none", 1.0)
    grid = data.log_grid(Z)
    complete = data.complete_lines
    freqs = np.asarray(data.frequencies_hz, float)
    if options.noise is not None:
        sigma, source = float(options.noise), "configured"
        T, dof, p_chi2 = chi_square_test(r, sigma, n_fitted)
    else:
        sigma, source = estimate_noise(grid[complete], freqs[complete]), "estimated"
        if not (np.isfinite(sigma) and sigma > 0):
            return Check(False, "the noise cannot be estimated (no band of three complete lines) and is not "
                                "configured: treated as structure", rms, float("nan"), "none", 0.0)
        # The level's own spread counted: P(T >= T_observed) over white-noise residuals of the complete lines.
        _, _, _, p_chi2 = estimated_noise_test(grid[complete], freqs[complete], n_fitted)
        T, dof = float(np.sum(r**2) / sigma**2), r.size - int(n_fitted)
    at_floor = p_chi2 >= options.significance or rms <= options.noise_ratio * sigma
    if source == "estimated" and (sigma > options.max_noise or not at_floor):
        source = STRUCTURED_ESTIMATE  # a level estimated from a residual that is structure bounds the noise only
    reason = f"rms {rms:.3%} vs noise {sigma:.3%} ({source}); chi2 {T:.1f} on {dof} dof, p = {p_chi2:.3g}"
    if source == STRUCTURED_ESTIMATE and sigma > options.max_noise:
        return Check(False, f"{reason}; but an estimated noise of {sigma:.1%} is above the {options.max_noise:.0%} "
                            "believed for measured amplitudes: structure", rms, sigma, source, p_chi2)
    why = "noise" if p_chi2 >= options.significance else (f"rms within {options.noise_ratio:g} x the noise"
                                                           if at_floor else "structure")
    return Check(at_floor, f"{reason}: {why}", rms, sigma, source, p_chi2)
