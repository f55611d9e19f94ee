"""Laplace intervals (fe_core.inference.intervals) against linear regression, where they are exact, and the FE fit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ
from fe_core.inference.intervals import fit_log_amplitudes, parameter_intervals
from fe_core.inference.laplace import laplace_intervals
from fe_core.solvers.sensitivity import log_amplitude_jacobian


def _linear_fit(X, y):
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    return beta, X @ beta - y  # residual model - data, Jacobian X


def test_simple_regression_matches_scipy_linregress(rng):
    x = rng.uniform(0, 10, 40)
    y = 1.5 - 0.7 * x + 0.3 * rng.normal(size=40)
    X = np.column_stack([np.ones_like(x), x])
    beta, r = _linear_fit(X, y)
    iv = laplace_intervals(r, X, beta, names=["intercept", "slope"])
    ref = stats.linregress(x, y)
    np.testing.assert_allclose(iv.estimate, [ref.intercept, ref.slope], rtol=1e-10)
    np.testing.assert_allclose(iv.std, [ref.intercept_stderr, ref.stderr], rtol=1e-10)
    t = stats.t.ppf(0.975, 38)
    assert iv.distribution == "student-t" and iv.dof == 38 and iv.quantile == pytest.approx(t, rel=1e-12)
    assert iv.low[1] == pytest.approx(ref.slope - t * ref.stderr, rel=1e-10)
    assert iv.high[1] == pytest.approx(ref.slope + t * ref.stderr, rel=1e-10)
    assert iv.noise_sigma == pytest.approx(np.sqrt(r @ r / 38), rel=1e-12) and iv.noise_source == "estimated"


def test_given_noise_gives_sigma2_inverse_normal_matrix_and_normal_quantile(rng):
    X = rng.normal(size=(30, 4))
    y = X @ [1.0, -2.0, 0.5, 0.0] + 0.1 * rng.normal(size=30)
    beta, r = _linear_fit(X, y)
    iv = laplace_intervals(r, X, beta, noise=0.1, level=0.9)
    cov = 0.01 * np.linalg.inv(X.T @ X)
    np.testing.assert_allclose(iv.covariance, cov, rtol=1e-10)
    np.testing.assert_allclose(iv.correlation, cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov))), atol=1e-12)
    assert iv.distribution == "normal" and iv.quantile == pytest.approx(stats.norm.ppf(0.95), rel=1e-12)
    np.testing.assert_allclose(iv.high - iv.low, 2 * stats.norm.ppf(0.95) * np.sqrt(np.diag(cov)), rtol=1e-10)


def test_linear_model_intervals_cover_at_their_level(rng):
    """Exact for a linear model: coverage of 2000 replicates within 4 binomial standard errors of 0.95."""
    X = np.column_stack([np.ones(12), np.linspace(-1, 1, 12), np.linspace(-1, 1, 12) ** 2])
    truth = np.array([0.3, -1.0, 2.0])
    n = 2000
    covered = np.zeros((n, 3), bool)
    for k in range(n):
        beta, r = _linear_fit(X, X @ truth + 0.05 * rng.normal(size=12))
        covered[k] = laplace_intervals(r, X, beta).contains(truth)
    se = np.sqrt(0.95 * 0.05 / n)
    assert np.all(np.abs(covered.mean(axis=0) - 0.95) < 4 * se)


def test_unseen_and_wide_parameters_and_bounds_are_flagged(rng):
    X = rng.normal(size=(20, 3))
    X[:, 2] = X[:, 1]  # the data see only alpha_2 + alpha_3
    r = 0.01 * rng.normal(size=20)
    iv = laplace_intervals(r, X, [0.95, 0.1, 0.1], noise=0.05, lower=-0.999, upper=1.0, width_threshold=0.2)
    assert np.isinf(iv.std[1:]).all() and np.isfinite(iv.std[0])
    assert list(iv.unpinned) == [False, True, True]
    assert iv.near_bound[0] == (iv.high[0] > 1.0)
    text = " ".join(iv.flag_lines())
    assert "alpha_2 is not pinned down" in text and "alpha_3 is not pinned down" in text and "unbounded" in text
    summary = iv.to_summary()
    assert summary["intervals"]["alpha_2"] == [None, None] and summary["interval_method"] == "laplace"
    assert summary["interval_details"]["unpinned"] == ["alpha_2", "alpha_3"]

    wide = laplace_intervals(r, 0.1 * X[:, :2], [0.0, 0.0], noise=0.05, width_threshold=0.2)
    assert np.all(wide.high - wide.low > 0.2) and wide.unpinned.all()
    assert "wide (threshold 0.2)" in wide.flag_lines()[0]


@pytest.mark.parametrize("kwargs, match", [
    ({"noise": 0.0}, "noise must be a positive"),
    ({"noise": float("nan")}, "noise must be a positive"),
    ({"level": 1.0}, "level"),
    ({"names": ["a"]}, "1 names for 2 parameters"),
])
def test_bad_input_is_refused(kwargs, match):
    X = np.eye(4)[:, :2]
    with pytest.raises(ValueError, match=match):
        laplace_intervals(np.ones(4), X, [0.0, 0.0], **kwargs)
    with pytest.raises(ValueError, match="jacobian must be"):
        laplace_intervals(np.ones(4), X.T, [0.0, 0.0])
    with pytest.raises(ValueError, match="cannot estimate the noise"):
        laplace_intervals(np.ones(2), np.eye(2), [0.0, 0.0])


@pytest.mark.slow
def test_fe_fit_recovers_noise_free_truth_and_its_jacobian_matches_central_differences(benchmark_model):
    freqs = MEASUREMENT_FREQUENCIES_HZ[[0, 3, 6, 9]]  # 24 amplitudes for 6 parameters: cheaper, still determined
    u = np.abs(benchmark_model.frf(ALPHA_ACTUAL, freqs, method="direct"))
    fit = fit_log_amplitudes(benchmark_model, freqs, u, ALPHA_ACTUAL + 0.01, -0.999, 1.0)
    np.testing.assert_allclose(fit.alpha, ALPHA_ACTUAL, atol=1e-6)
    assert np.max(np.abs(fit.residual)) < 1e-7 and fit.jacobians >= 1

    def residual(a):
        return np.log(np.abs(benchmark_model.frf(a, freqs))).ravel() - np.log(u).ravel()

    h = 1e-4  # Krylov FRF to ~1e-10: the difference quotient is good to ~1e-6, its truncation error ~1e-8
    fd = np.column_stack([(residual(fit.alpha + h * e) - residual(fit.alpha - h * e)) / (2 * h)
                          for e in np.eye(fit.alpha.size)])
    np.testing.assert_allclose(fit.jacobian, fd, atol=1e-5 * np.abs(fd).max())
    # noise-free data with a small given noise level: tiny intervals around the truth (0.01 % noise on
    # 24 amplitudes: widths up to ~1e-3; with the estimated noise, the round-off residual, far smaller)
    iv = laplace_intervals(fit.residual, fit.jacobian, fit.alpha, noise=1e-4)
    assert iv.contains(ALPHA_ACTUAL).all() and np.max(iv.high - iv.low) < 2e-3
    assert np.max(laplace_intervals(fit.residual, fit.jacobian, fit.alpha).high - fit.alpha) < 1e-5


@pytest.mark.slow
def test_gauss_newton_steps_from_a_nearby_start_reach_the_truth_of_noise_free_data(benchmark_model):
    freqs = MEASUREMENT_FREQUENCIES_HZ[[0, 3, 6, 9]]
    u = np.abs(benchmark_model.frf(ALPHA_ACTUAL, freqs, method="direct"))
    start = ALPHA_ACTUAL + np.array([0.004, -0.01, 0.01, 0.0, 0.01, -0.004])
    refined = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=1e-4, max_jacobians=4)
    iv = refined.intervals
    np.testing.assert_allclose(iv.estimate, ALPHA_ACTUAL, atol=1e-5)
    # each point costs one Jacobian, whose Krylov space gives the residual too: no separate FE run (a model this
    # small takes no chord steps)
    assert refined.at_optimum and refined.jacobians >= 2 and refined.fe_runs == 0
    np.testing.assert_array_equal(refined.jacobian_at, iv.estimate)
    assert iv.contains(ALPHA_ACTUAL).all() and np.max(iv.high - iv.low) < 2e-3 and not iv.unpinned.any()
    # one step was not enough from this start with a budget of one Jacobian
    once = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=1e-4, max_jacobians=1)
    assert not once.at_optimum and once.jacobians == 1 and once.fe_runs == 0
    np.testing.assert_allclose(refined.jacobian, log_amplitude_jacobian(benchmark_model, iv.estimate, freqs,
                                                                        method="direct"),
                               atol=1e-7 * np.abs(refined.jacobian).max())


@pytest.mark.slow
def test_a_chord_step_within_a_standard_deviation_costs_an_frf_and_takes_the_same_step(benchmark_model, rng):
    """A start half a standard deviation from the optimum: the chord step (the start's Jacobian kept, one FRF at
    the new point) ends where the step with a new Jacobian ends; the intervals differ only by the Jacobian's move
    over half a standard deviation. From three standard deviations no chord is tried. On a model this small the
    default takes no chord steps at all."""
    freqs = MEASUREMENT_FREQUENCIES_HZ
    u = np.abs(benchmark_model.frf(ALPHA_ACTUAL, freqs, method="direct")) * np.exp(
        0.01 * rng.normal(size=(freqs.size, 6)))
    opt = parameter_intervals(benchmark_model, freqs, u, ALPHA_ACTUAL, -0.999, 1.0, noise=0.01, max_jacobians=5,
                              chord_std=0.0)
    assert opt.at_optimum
    sd = opt.intervals.std
    signs = np.array([1, -1, 1, -1, 1, -1.0])
    start = opt.intervals.estimate + 0.5 * signs * sd
    exact = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=0.01, chord_std=0.0)
    chord = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=0.01, chord_std=1.0)
    assert (exact.jacobians, exact.fe_runs) == (2, 0) and (chord.jacobians, chord.fe_runs) == (1, 1)
    assert chord.at_optimum and chord.last_step_in_std <= 0.1
    np.testing.assert_array_equal(chord.jacobian_at, start)
    # the chord step's FRF is the receptance at the estimate (for the run's own error there); none without a chord
    np.testing.assert_array_equal(chord.frf_at_estimate, benchmark_model.parameter_frf(chord.intervals.estimate, freqs))
    assert exact.frf_at_estimate is None
    # the same step from the same Jacobian: the same estimate (to the FRF's digits, far below a standard deviation)
    np.testing.assert_allclose(chord.intervals.estimate, exact.intervals.estimate, rtol=0, atol=1e-6 * sd.min())
    np.testing.assert_allclose(chord.residual, exact.residual, atol=1e-8)
    # the widths: the Jacobian half a standard deviation away (a few per cent here, at 1 % noise on 60 values)
    np.testing.assert_allclose(chord.intervals.std, exact.intervals.std, rtol=0.05)
    # three standard deviations away the first step gets a new Jacobian; both end at the optimum
    far = opt.intervals.estimate + 3.0 * signs * sd
    a = parameter_intervals(benchmark_model, freqs, u, far, -0.999, 1.0, noise=0.01, chord_std=1.0)
    assert a.jacobians >= 2 and a.at_optimum
    assert np.max(np.abs(a.intervals.estimate - opt.intervals.estimate) / sd) < 0.2
    # the default on this 3,510-DOF model: no chord (its Jacobian costs seconds)
    default = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=0.01)
    assert (default.jacobians, default.fe_runs) == (2, 0)
    np.testing.assert_array_equal(default.intervals.std, exact.intervals.std)


@pytest.mark.slow
def test_a_chord_step_whose_second_order_term_is_below_the_noise_takes_the_first_order_frf(benchmark_model, rng,
                                                                                           monkeypatch):
    """At 0.1 % noise a chord step of half a standard deviation changes each value so little that the term the
    first-order FRF leaves out (|x|^2 / 2 a value, whitened by the noise) cannot move the estimate by LINEAR_STD: its
    FRF is the start's first-order expansion, no FE run. The same step with the FE run's FRF (LINEAR_STD 0) gives
    the same estimate and widths to far below a standard deviation, and the expanded receptance at the estimate is
    the direct solve's there to about the square of the largest change. At 1 % noise on these 60 values (the test
    above) the same half standard deviation is an FE run."""
    from fe_core.inference import intervals as module

    freqs = MEASUREMENT_FREQUENCIES_HZ
    u = np.abs(benchmark_model.frf(ALPHA_ACTUAL, freqs, method="direct")) * np.exp(
        1e-3 * rng.normal(size=(freqs.size, 6)))
    opt = parameter_intervals(benchmark_model, freqs, u, ALPHA_ACTUAL, -0.999, 1.0, noise=1e-3, max_jacobians=5,
                              chord_std=0.0)
    sd = opt.intervals.std
    start = opt.intervals.estimate + 0.5 * np.array([1, -1, 1, -1, 1, -1.0]) * sd
    linear = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=1e-3, chord_std=1.0)
    bar = module.LINEAR_STD
    monkeypatch.setattr(module, "LINEAR_STD", 0.0)
    solved = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=1e-3, chord_std=1.0)
    assert (linear.jacobians, linear.fe_runs, linear.first_order_frfs) == (1, 0, 1) and linear.at_optimum
    assert (solved.jacobians, solved.fe_runs, solved.first_order_frfs) == (1, 1, 0) and solved.at_optimum
    np.testing.assert_allclose(linear.intervals.estimate, solved.intervals.estimate, rtol=0, atol=0.1 * bar * sd.min())
    np.testing.assert_allclose(linear.intervals.std, solved.intervals.std, rtol=1e-3)
    direct = benchmark_model.frf(linear.intervals.estimate, freqs, method="direct")
    change = np.abs(direct - benchmark_model.frf(start, freqs, method="direct")) / np.abs(direct)
    assert np.linalg.norm(0.5 * change**2 / 1e-3) < bar  # the step's size that chose the expansion
    assert np.max(np.abs(linear.frf_at_estimate - direct) / np.abs(direct)) < 3 * change.max() ** 2


def test_a_given_jacobian_at_the_start_is_used_and_not_computed_again(benchmark_model, rng):
    """``known``: the start's receptance and derivative from an FE run made there (a large model's confirmed local
    centre). The same Jacobian given: the same intervals, one Jacobian fewer. A wrong one given: other intervals
    (it is used, not computed again)."""
    from fe_core.solvers.sensitivity import frf_jacobian

    freqs = MEASUREMENT_FREQUENCIES_HZ
    u = np.abs(benchmark_model.frf(ALPHA_ACTUAL, freqs, method="direct")) * np.exp(
        0.01 * rng.normal(size=(freqs.size, 6)))
    start = np.asarray(ALPHA_ACTUAL) + 0.002
    plain = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=0.01, chord_std=0.0)
    Z, dZ = frf_jacobian(benchmark_model, start, freqs)
    given = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=0.01, chord_std=0.0,
                                known=(Z, dZ))
    assert given.jacobians == plain.jacobians - 1 and given.fe_runs == plain.fe_runs
    np.testing.assert_array_equal(given.intervals.estimate, plain.intervals.estimate)
    np.testing.assert_array_equal(given.intervals.std, plain.intervals.std)
    one = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=0.01, max_jacobians=1)
    wrong = parameter_intervals(benchmark_model, freqs, u, start, -0.999, 1.0, noise=0.01, max_jacobians=1,
                                known=(Z, 2.0 * dZ))
    assert (one.jacobians, wrong.jacobians) == (1, 0)
    np.testing.assert_allclose(wrong.intervals.std, one.intervals.std / 2, rtol=1e-9)  # twice the slopes: half


# -- the closure's extended model: alpha and the added effects' values ------------------------------------
def _effects(model):
    """A point mass, a grounded spring, a joint band (scales with alpha), a damping change and a sensor gain."""
    from fe_core.closure.effects import Applied, GroundedSpring, PointMass, RayleighDamping, SensorGain, build_library

    band = build_library(model, ["joint_band"])[0]
    return [Applied(PointMass(model), "node 337", np.array([0.05])),
            Applied(GroundedSpring(model), "node 919", np.array([2e5])),
            Applied(band, band.locations()[0], np.array([-0.3])),
            Applied(RayleighDamping(model), "a", np.array([2.0])),
            Applied(SensorGain(model), "sensor 2", np.array([0.03]))]


def test_extended_jacobian_columns_match_central_differences_of_the_extended_frf(benchmark_model):
    """Every column: alpha (with the band's alpha-dependence), mass, spring, band, damping, gain."""
    from fe_core.closure.effects import Applied, extended_frf
    from fe_core.closure.jacobian import extended_log_jacobian

    freqs = MEASUREMENT_FREQUENCIES_HZ[[0, 3, 6, 9]]
    alpha = ALPHA_ACTUAL
    applied = _effects(benchmark_model)
    J, Z = extended_log_jacobian(benchmark_model, alpha, freqs, applied)
    assert J.shape == (freqs.size * 6, 6 + len(applied))
    Zd = extended_frf(benchmark_model, alpha, freqs, applied, method="direct")
    assert np.abs(Z - Zd).max() <= 1e-8 * np.abs(Zd).max()

    def log_amp(a, items):
        return np.log(np.abs(extended_frf(benchmark_model, a, freqs, items))).ravel()

    h = 1e-4  # relative to each parameter's scale; Krylov FRFs to 1e-10: differences good to ~1e-6
    for i in range(6):
        e = np.zeros(6)
        e[i] = h
        fd = (log_amp(alpha + e, applied) - log_amp(alpha - e, applied)) / (2 * h)
        np.testing.assert_allclose(J[:, i], fd, atol=1e-5 * np.abs(fd).max(), err_msg=f"alpha_{i + 1}")
    def moved(k, s):
        return [Applied(x.effect, x.location, x.values + (s if j == k else 0.0)) for j, x in enumerate(applied)]

    for k, item in enumerate(applied):
        step = h * item.effect.scale_at(item.location)
        fd = (log_amp(alpha, moved(k, step)) - log_amp(alpha, moved(k, -step))) / (2 * step)
        np.testing.assert_allclose(J[:, 6 + k], fd, atol=1e-5 * np.abs(fd).max(), err_msg=item.effect.kind)


@pytest.mark.slow
def test_extended_intervals_step_to_the_truth_of_noise_free_data_and_flag_an_absent_effect(benchmark_model):
    from fe_core.closure.effects import Applied, RayleighDamping, extended_frf
    from fe_core.closure.intervals import extended_intervals

    freqs = MEASUREMENT_FREQUENCIES_HZ
    truth = _effects(benchmark_model)[:2]  # point mass and spring
    u = np.abs(extended_frf(benchmark_model, ALPHA_ACTUAL, freqs, truth, method="direct"))
    # Start a little off (as a closure's fit to its tolerance), with a third effect that is not there.
    start = [Applied(t.effect, t.location, t.values * 1.02) for t in truth]
    start.append(Applied(RayleighDamping(benchmark_model), "b", np.array([1e-7])))
    refined = extended_intervals(benchmark_model, freqs, u, ALPHA_ACTUAL + 0.002, start, noise=1e-4,
                                 max_jacobians=4)
    iv = refined.intervals
    theta = np.concatenate([ALPHA_ACTUAL, [0.05, 2e5, 0.0]])
    assert iv.names[6:] == ["point_mass.mass", "grounded_spring.k", "damping.delta"]
    assert refined.at_optimum and refined.fe_runs == 0
    np.testing.assert_allclose(iv.estimate, theta, rtol=1e-4, atol=1e-9)
    assert iv.contains(theta).all()
    # The damping change that is not there: its interval holds zero, in words; the others are told apart.
    assert list(iv.unpinned[6:]) == [False, False, True]
    assert any("damping.delta" in line and "contains zero" in line for line in iv.flag_lines())


def test_extended_intervals_of_a_model_with_mass_factors_are_those_of_its_stiffness_model(benchmark_model):
    """The extended model holds updated mass factors at nominal: the same alpha box and intervals, no crash."""
    import dataclasses

    from fe_core.closure.effects import extended_frf
    from fe_core.closure.intervals import extended_intervals

    freqs = MEASUREMENT_FREQUENCIES_HZ[[0, 3, 6, 9]]
    truth = _effects(benchmark_model)[:1]  # the point mass
    u = np.abs(extended_frf(benchmark_model, ALPHA_ACTUAL, freqs, truth, method="direct"))
    with_gamma = dataclasses.replace(benchmark_model, mass_parameters=np.array([1, 4]))
    plain = extended_intervals(benchmark_model, freqs, u, ALPHA_ACTUAL, truth, noise=1e-3, max_jacobians=1)
    gamma = extended_intervals(with_gamma, freqs, u, ALPHA_ACTUAL, truth, noise=1e-3, max_jacobians=1)
    assert gamma.intervals.names == plain.intervals.names
    np.testing.assert_allclose(gamma.intervals.covariance, plain.intervals.covariance, rtol=1e-9)
