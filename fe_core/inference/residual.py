"""Residual analysis after updating: what is left, how large noise is, noise or structure.

The measured quantity is an FRF amplitude with multiplicative noise
(``u = |Z| (1 + sigma e)``), so the natural residual is logarithmic,
``r = ln(|Z_model| / u)``: pure noise gives ``r ~ N(0, sigma^2)`` at every
sensor and frequency, whatever the amplitude. The paper's relative residual
``|Z_model| / u - 1`` (Eq. 5) agrees with it to first order and is what the
errors of Eqs. 6b and 15 average.

Decision "noise or structure" (:func:`analyse_residual`):

* **chi-square**: ``T = sum r^2 / sigma^2`` after fitting ``k`` parameters to
  ``N`` values is chi-square with ``N - k`` degrees of freedom if the residual
  is noise and sigma the known level; structure if ``P(chi2 >= T) < significance``.
  With sigma estimated from the same residual, ``P(T >= T_observed)`` comes from
  white-noise residuals of the same layout with the level estimated alike
  (:func:`estimated_noise_test`);
* **runs** (reported, not part of the decision): along frequency, within
  each sensor and each contiguous band, noise changes sign at random; a
  smooth misfit gives long runs of one sign (Wald-Wolfowitz, one-sided).

The noise level is configured (the measurement's known relative accuracy) or
estimated with :func:`estimate_noise` from second differences along
frequency within evenly stepped bands, which remove a residual that is smooth
in frequency, clipped at 3 standard deviations, which drops the few large
differences a misfit leaves near resonances (an estimate that structure still
inflates somewhat, so the test then errs towards "noise"; docs/guide/noise-estimate.md).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from functools import lru_cache

import numpy as np

from .levels import CLIP, CLIP_FACTOR, _clipped_level, estimate_noise, frequency_bands, second_differences

__all__ = [
    "STRUCTURED_ESTIMATE",
    "MAX_NOISE",
    "log_residual",
    "relative_residual",
    "overall_error",
    "per_sensor_error",
    "frequency_bands",
    "second_differences",
    "estimate_noise",
    "estimated_noise_test",
    "chi_square_test",
    "runs_test",
    "ResidualAnalysis",
    "analyse_residual",
    "noise_floor_error",
]


def log_residual(model_amplitude, measured_amplitude) -> np.ndarray:
    """``ln(|Z_model| / u)``, same shape as the inputs, e.g. (p, n)."""
    return np.log(np.asarray(model_amplitude, float) / np.asarray(measured_amplitude, float))


def relative_residual(model_amplitude, measured_amplitude) -> np.ndarray:
    """Eq. 5's ``(|Z_model| - u) / u``, same shape as the inputs."""
    u = np.asarray(measured_amplitude, float)
    return (np.asarray(model_amplitude, float) - u) / u


def overall_error(relative: np.ndarray) -> float:
    """Eq. 6b: mean absolute relative residual."""
    return float(np.mean(np.abs(relative)))


def per_sensor_error(relative: np.ndarray) -> np.ndarray:
    """Eq. 15: mean absolute relative residual per sensor, from a (p, n) array."""
    return np.mean(np.abs(np.asarray(relative)), axis=0)


def noise_floor_error(sigma: float) -> float:
    """Overall error (Eq. 6b) of pure noise of relative level sigma: ``E|e| = sigma sqrt(2 / pi)``."""
    return float(sigma * np.sqrt(2.0 / np.pi))


#: White-noise draws for the null distribution of the test with an estimated level (:func:`estimated_noise_test`);
#: fewer (down to ``NULL_DRAWS_MIN``) where a residual has more than ``NULL_VALUES`` / ``NULL_DRAWS`` values.
NULL_DRAWS, NULL_DRAWS_MIN, NULL_VALUES = 4000, 400, 40_000_000


@lru_cache(maxsize=64)
def _null_statistic(band_sizes: tuple[int, ...], n_lines: int, n_sensors: int, n_fitted: int) -> np.ndarray:
    """Sorted ``sum r^2 / sigma_hat^2`` of white-noise residuals of this layout (fixed seed), in chunks of at most
    2 million values."""
    rng = np.random.default_rng(0)
    size = n_lines * n_sensors
    draws = int(np.clip(NULL_VALUES // size, NULL_DRAWS_MIN, NULL_DRAWS))
    chunk = max(1, min(draws, 2_000_000 // size))
    out = []
    for start in range(0, draws, chunk):
        k = min(chunk, draws - start)
        e = rng.standard_normal((k, n_lines, n_sensors))
        d2, line = [], 0
        for b in band_sizes:
            if b >= 3:
                d2.append(np.diff(e[:, line:line + b], n=2, axis=1).reshape(k, -1))
            line += b
        sigma = _clipped_level(np.concatenate(d2, axis=1))
        # n_fitted parameters fitted to the data take about n_fitted values' worth of the sum of squares away.
        out.append(np.sum(e.reshape(k, -1)[:, n_fitted:] ** 2, axis=1) / sigma**2)
    return np.sort(np.concatenate(out))


def estimated_noise_test(residual: np.ndarray, freqs_hz, n_fitted: int) -> tuple[float, float, int, float]:
    """``(sigma, T, dof, p)``: the chi-square statistic against the level estimated from the residual itself.

    ``T = sum r^2 / sigma^2`` with ``sigma`` from :func:`estimate_noise`. The level is an estimate from the same
    values (its spread 8-10 % on issue 28's 27-33 lines, 14 % on the benchmark's 12), so ``T`` is not chi-square:
    against the chi-square a residual of pure noise was called structure 5-8 % of the time at the 1 % level
    (22-27 % with the old bands' estimate from one window), often enough to turn a found effect's verdict into
    `partly explained`. ``p`` is the share of ``NULL_DRAWS`` = 4,000 white-noise residuals of the same layout
    (lines, bands, sensors; fixed seed; cached per layout), with the level estimated the same way, whose statistic
    is at least ``T`` (``n_fitted`` values' squares left out of each draw's sum, as a fit takes them): 1-2 % of
    pure-noise residuals are then called structure at 1 % (docs/guide/noise-estimate.md). The smallest p is 1 / 4001.
    """
    r = np.asarray(residual, float)
    sigma = estimate_noise(r, freqs_hz)
    dof = r.size - int(n_fitted)
    if dof < 1:
        raise ValueError(f"{r.size} residuals cannot test a fit of {n_fitted} parameters")
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError("the noise level cannot be estimated (no band of three frequencies); configure it")
    T = float(np.sum(r**2) / sigma**2)
    null = _null_statistic(tuple(b.size for b in frequency_bands(freqs_hz)), r.shape[0], r.shape[1], int(n_fitted))
    p = float((null.size - np.searchsorted(null, T, side="left") + 1) / (null.size + 1))
    return sigma, T, dof, p


def chi_square_test(residual: np.ndarray, sigma: float, n_fitted: int) -> tuple[float, int, float]:
    """``(T, dof, p)``: ``T = sum r^2 / sigma^2`` against chi-square with ``N - n_fitted`` dof."""
    from scipy import stats  # here, not at the top: 0.7 s of CPU to import, unused by most runs
    r = np.asarray(residual, float).ravel()
    dof = r.size - int(n_fitted)
    if dof < 1:
        raise ValueError(f"{r.size} residuals cannot test a fit of {n_fitted} parameters")
    if not sigma > 0:
        raise ValueError(f"the noise level must be positive, got {sigma}")
    T = float(np.sum(r**2) / sigma**2)
    return T, dof, float(stats.chi2.sf(T, dof))


def runs_test(residual: np.ndarray, freqs_hz) -> tuple[int, float, float]:
    """Sign runs along frequency per sensor and band: ``(runs, z, p)``, p small = too few runs.

    Each (sensor, band) sequence is a separate series; the expected number of
    runs and its variance (given the counts of each sign) are summed over them.
    """
    from scipy import stats  # here, not at the top: 0.7 s of CPU to import, unused by most runs
    r = np.asarray(residual, float)
    runs, mean, var = 0, 0.0, 0.0
    for idx in frequency_bands(freqs_hz):
        for s in range(r.shape[1]):
            signs = r[idx, s] > 0
            n = signs.size
            n1 = int(signs.sum())
            n2 = n - n1
            runs += 1 + int(np.sum(signs[1:] != signs[:-1]))
            if n1 == 0 or n2 == 0:
                mean += 1.0
                continue
            mean += 1.0 + 2.0 * n1 * n2 / n
            var += 2.0 * n1 * n2 * (2.0 * n1 * n2 - n) / (n**2 * (n - 1))
    if var <= 0:
        return runs, 0.0, 1.0
    z = (runs - mean) / np.sqrt(var)
    return runs, float(z), float(stats.norm.cdf(z))


#: ``ResidualAnalysis.sigma_source`` of a noise level estimated from a residual the test calls structure.
STRUCTURED_ESTIMATE = "estimated from a residual that is structure: an upper bound, not the measured noise"

#: An estimated relative noise level above this is not believed for measured amplitudes: the residual is called
#: structure (a model far off varies from line to line across resonances far more than noise does, and its second
#: differences then "estimate" tens of per cent). The hybrid's check uses the same ceiling (``HybridOptions``).
MAX_NOISE = 0.05


@dataclass(frozen=True)
class ResidualAnalysis:
    """Statistics of one residual (see :func:`analyse_residual`)."""

    n_values: int
    n_fitted: int
    rss: float
    rms: float
    sigma: float
    sigma_source: str
    sigma_estimated: float
    chi2: float
    dof: int
    p_chi2: float
    runs: int
    runs_z: float
    p_runs: float
    significance: float
    structured: bool
    overall_error: float
    noise_floor: float
    noise_model: dict | None = None
    model: object = field(default=None, compare=False, repr=False)
    spec: object = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict:
        out = {k: v for k, v in asdict(self).items() if k not in ("model", "spec")}
        return {**out, "noise_known": self.noise_known}

    @property
    def noise_known(self) -> bool:
        """Whether ``sigma`` is the measurement's noise: configured, measured (coherence, records), or estimated
        from a residual the test calls noise. A level estimated from a residual that is structure is an upper bound
        only (the structure's curvature along frequency adds to it), labelled so and never the floor for calling the
        rest noise."""
        return self.sigma_source in ("configured", "estimated", "coherence", "records")

    @property
    def next_noise(self):
        """What a later test of these data takes as their noise (``noise=`` of :func:`analyse_residual`): the
        configured level or the measured model as they are; else an estimate made anew from that residual (the
        model of a relative term and a floor when this one was, :class:`fe_core.inference.noise.Estimated`): a
        level estimated from a structured residual is an upper bound and would call too much noise."""
        if self.sigma_source in ("coherence", "records", "configured") and self.model is not None:
            return self.model
        if self.sigma_source == "configured":
            return self.sigma
        from .noise import Estimated

        return self.spec if isinstance(self.spec, Estimated) else None

    def summary(self) -> str:
        verdict = "structure" if self.structured else "noise"
        return (f"rms {self.rms:.3%} vs noise {self.sigma:.3%} ({self.sigma_source}); chi2 {self.chi2:.1f} on "
                f"{self.dof} dof, p = {self.p_chi2:.3g}; runs z = {self.runs_z:.2f} (p = {self.p_runs:.3g}): {verdict}")


def analyse_residual(residual: np.ndarray, freqs_hz, n_fitted: int, noise=None, significance: float = 0.01,
                     relative: np.ndarray | None = None, max_noise: float = MAX_NOISE) -> ResidualAnalysis:
    """Noise or structure?

    Parameters
    ----------
    residual : ndarray, shape (p, n)
        Log residuals ``ln(|Z_model| / u)`` after the fit.
    freqs_hz : ndarray, shape (p,)
    n_fitted : int
        Parameters fitted to these data.
    noise : float, NoiseModel or Estimated, optional
        Relative noise level (standard deviation, e.g. 0.005), or the noise per line and channel
        (:class:`fe_core.inference.noise.NoiseModel`, e.g. from the measured coherence), or
        :class:`fe_core.inference.noise.Estimated` (the model of a relative term and a floor per channel estimated
        from this residual, tested against white noise of that model); one relative level estimated from the
        residual when None (:func:`estimate_noise`).
    significance : float
        Chi-square level below which the residual is called structure.
    relative : ndarray, shape (p, n), optional
        Relative residuals for the overall error; from ``residual`` if None.
    max_noise : float
        An estimated relative level above this is not believed: the residual is structure, whatever the
        chi-square says (the level, too high, would call any misfit noise).
    """
    from .noise import Estimated, judged_by, noise_model_test, one_level

    r = np.asarray(residual, float)
    if r.ndim != 2:
        raise ValueError(f"residual must be (frequencies, sensors), got shape {r.shape}")
    estimated = estimate_noise(r, freqs_hz)
    model, amplitude = None, None
    if one_level(noise, freqs_hz):
        noise = None if isinstance(noise, Estimated) else noise  # a few windows of lines: one estimated level
    else:  # measured (its level checked here), configured, or estimated from this residual
        model = judged_by(noise, r, freqs_hz)
        amplitude = np.asarray(noise.amplitude, float) if isinstance(noise, Estimated) else None
    if model is not None:
        T, dof, p = noise_model_test(r, model, n_fitted, amplitude, freqs_hz)
        sigma, source = float(np.median(model.sigma)), model.source
        relative_level = float(np.max(model.relative)) if model.relative is not None else sigma
        structured = bool(p < significance) or (source == "estimated" and relative_level > max_noise)
    else:
        if noise is None:
            if not np.isfinite(estimated) or estimated <= 0:
                raise ValueError("the noise level cannot be estimated (no band of three frequencies); configure it")
            sigma, source = estimated, "estimated"
            _, T, dof, p = estimated_noise_test(r, freqs_hz, n_fitted)  # the level's own spread counted
        else:
            sigma, source = float(noise), "configured"
            T, dof, p = chi_square_test(r, sigma, n_fitted)
        structured = bool(p < significance) or (source == "estimated" and sigma > max_noise)
    runs, z, p_runs = runs_test(r, freqs_hz)
    rel = np.expm1(r) if relative is None else np.asarray(relative, float)
    if source == "estimated" and structured:
        source = STRUCTURED_ESTIMATE
    return ResidualAnalysis(
        n_values=int(r.size), n_fitted=int(n_fitted), rss=float(np.sum(r**2)), rms=float(np.sqrt(np.mean(r**2))),
        sigma=sigma, sigma_source=source, sigma_estimated=estimated, chi2=T, dof=dof, p_chi2=p,
        runs=runs, runs_z=z, p_runs=p_runs, significance=float(significance), structured=structured,
        overall_error=overall_error(rel), noise_floor=noise_floor_error(sigma),
        noise_model=None if model is None else model.to_dict(), model=model, spec=noise,
    )
