"""The noise per line and channel (fe_core/inference/noise.py): the estimated model recovers the noise it was
drawn from, its test passes that noise and rejects a smooth misfit, a measured model's level is checked against
the residual, and few windows of lines fall back to one level.

The measured amplitudes are those of a two-mode oscillator across a band (resonances and an anti-resonance, so
a floor matters there); the noise is drawn from known models, the reference every estimate is checked against.
"""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.inference.noise import Estimated, NoiseModel, calibrate, estimate_noise_model, noise_model_test
from fe_core.inference.residual import STRUCTURED_ESTIMATE, analyse_residual

FREQS = np.linspace(5.0, 400.0, 800)


def _amplitudes() -> np.ndarray:
    """|H| (p, 3) of a two-mode oscillator seen at three points: peaks near 80 and 260 Hz, anti-resonances."""
    w = 2 * np.pi * FREQS
    modes = [(2 * np.pi * 80.0, 0.02, np.array([1.0, 0.7, -0.4])), (2 * np.pi * 260.0, 0.02, np.array([0.5, -0.8, 1.0]))]
    H = sum(np.outer(1.0 / (wr**2 - w**2 + 2j * z * wr * w), phi) for wr, z, phi in modes)
    return np.abs(H)


U = _amplitudes()
RELATIVE, FLOOR = 0.006, 2e-3 * U.max(axis=0)  # 0.6 % relative, a floor of 2e-3 of each channel's peak
SIGMA = np.sqrt(RELATIVE**2 + (FLOOR / U) ** 2)


def _noise(seed: int, sigma=SIGMA) -> np.ndarray:
    return sigma * np.random.default_rng(seed).standard_normal(sigma.shape)


def test_the_estimated_model_recovers_the_noise_it_was_drawn_from():
    """Where the floor dominates (most lines off the resonances) the two terms trade off, so the check is on what
    the tests use, sigma per line and channel, and on the floor, which the anti-resonances pin down."""
    fits = [estimate_noise_model(_noise(seed), U, FREQS) for seed in range(6)]
    ratio = np.array([f.sigma / SIGMA for f in fits])  # (draws, p, n)
    # 797 second differences a channel: sigma within 10 % at the median line of every fit, the mean of six
    # within 5 % at 95 % of the lines; the floor within 15 % of the truth in every channel of every fit
    assert np.all(np.abs(np.median(ratio, axis=1) - 1) < 0.10)
    assert np.quantile(np.abs(ratio.mean(axis=0) - 1), 0.95) < 0.05
    floor = np.array([f.floor for f in fits])
    assert np.all(np.abs(floor / FLOOR - 1) < 0.15)


def test_noise_of_the_model_passes_its_test_and_a_smooth_misfit_does_not():
    p = [noise_model_test(r, estimate_noise_model(r, U, FREQS), 2, U, FREQS)[2] for r in map(_noise, range(4))]
    assert min(p) > 0.01, p  # fixed seeds: four draws of the model's own noise, none called structure
    # the same noise on a model whose second mode is 1 % too high: smooth along frequency, far above the noise
    w = 2 * np.pi * FREQS
    shifted = np.log(np.abs(1.0 / ((2 * np.pi * 262.6) ** 2 - w**2 + 2j * 0.02 * 2 * np.pi * 262.6 * w))
                     / np.abs(1.0 / ((2 * np.pi * 260.0) ** 2 - w**2 + 2j * 0.02 * 2 * np.pi * 260.0 * w)))
    r = _noise(99) + 0.5 * shifted[:, None]
    model = estimate_noise_model(r, U, FREQS)
    assert noise_model_test(r, model, 2, U, FREQS)[2] < 0.01


def test_one_relative_level_calls_floor_noise_structure_and_the_model_calls_it_noise():
    """Issue 40's hammer test in small: with a floor, the relative noise is large at the anti-resonances; one level
    for every value sees that as structure."""
    r = _noise(5)
    one = analyse_residual(r, FREQS, 2)
    model = analyse_residual(r, FREQS, 2, Estimated(U))
    assert one.structured and one.sigma_source == STRUCTURED_ESTIMATE
    assert not model.structured and model.sigma_source == "estimated" and model.noise_model["floor"][0] > 0


def test_a_measured_models_level_is_checked_against_the_residual():
    """Coherence that understates the noise by 20 % in one channel: the calibrated model says so and passes; the
    model as stated calls the same residual structure."""
    stated = NoiseModel(SIGMA, "coherence")
    truth = SIGMA * np.array([1.0, 1.2, 1.0])
    scales = np.array([calibrate(stated, _noise(seed, truth), FREQS).scale for seed in range(6)])
    # the level from 797 second differences: within 10 % each, the mean of six within 4 %
    assert np.all(np.abs(scales / [1.0, 1.2, 1.0] - 1) < 0.10)
    assert scales.mean(axis=0) == pytest.approx([1.0, 1.2, 1.0], rel=0.04)
    r = _noise(11, truth)
    a = analyse_residual(r, FREQS, 2, stated)
    assert not a.structured and a.sigma_source == "coherence" and a.noise_model["scale"][1] > 1.1
    assert noise_model_test(r, NoiseModel(SIGMA, "configured"), 2)[2] < 1e-6


def test_student_t_residuals_of_coherence_noise_pass_and_normal_ones_of_twice_the_level_do_not():
    """A residual over a sigma estimated from n averages is Student-t with 2 (n - 1) degrees of freedom."""
    rng = np.random.default_rng(3)
    n_avg = 5
    t_dof = np.full(U.shape, 2.0 * (n_avg - 1))
    model = NoiseModel(SIGMA, "configured", t_dof=t_dof)
    r = SIGMA * rng.standard_t(t_dof)
    assert noise_model_test(r, model, 2)[2] > 0.01
    assert noise_model_test(2 * r, model, 2)[2] < 1e-6


def test_a_few_windows_of_lines_take_one_level_for_every_value():
    """27 lines in three windows: a relative term and a floor per channel would fit a misfit; one level it is."""
    lines = np.concatenate([np.arange(i, i + 9) for i in (100, 400, 700)])
    r = _noise(2)[lines]
    a = analyse_residual(r, FREQS[lines], 2, Estimated(U[lines]))
    assert a.noise_model is None and a.sigma_source in ("estimated", STRUCTURED_ESTIMATE)


def test_a_coherence_written_as_exactly_one_gets_its_lines_level_not_an_infinite_weight():
    """Coherence exported with a few digits reads 1 at strong peaks: the line's sigma is that of its neighbours
    (the smoothed model), so a residual of the stated noise passes instead of weighing infinitely."""
    n_avg = 10
    g2 = 1.0 / (1.0 + 2.0 * (n_avg - 1) * SIGMA**2)  # the coherence whose random error is SIGMA (inverted)
    ones = SIGMA <= np.sort(SIGMA, axis=0)[6]  # each channel's seven best lines, at its peaks, written as 1
    written = np.where(ones, 1.0, g2)
    model = NoiseModel.from_coherence(written, n_avg, U)
    assert np.all(np.isfinite(model.sigma)) and np.all(model.sigma > 0)
    # at those lines the sigma is the smoothed level of the line: within 10 % of the truth
    assert np.all(np.abs(model.sigma[ones] / SIGMA[ones] - 1) < 0.10)
    a = analyse_residual(_noise(5), FREQS, 2, model)
    assert np.isfinite(a.chi2) and not a.structured
