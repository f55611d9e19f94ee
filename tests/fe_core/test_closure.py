"""Closing the loop on data with an undeclared effect (data/cases/three_plate_effects), judged against its truth file.

Each closure starts from the nominal model with the cheap multi-start
least-squares update (no MRGP run), with the settings of
``benchmarks/closure.py``. The truth (``truth.json``) is read only here.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fe_core.closure.loop import close_loop
from fe_core.inference.residual import analyse_residual, overall_error
from tasks.io.measured import read_measured

DATA = Path(__file__).resolve().parents[2] / "data" / "cases" / "three_plate_effects"
SETTINGS = dict(noise=0.005, restarts=2, per_type=1)
TRUTH = json.loads((DATA / "truth.json").read_text())
EFFECT_FILES = [name for name, t in TRUTH["data"].items() if t["effect"]]
CLEAN_FILES = [name for name, t in TRUTH["data"].items() if not t["effect"]]


@pytest.fixture(scope="module")
def library(benchmark_model):
    """Every registered effect for the benchmark, built once for the module's closures."""
    from fe_core.closure.effects import build_library

    return build_library(benchmark_model)


def closure(benchmark_model, name, library):
    """The first round of the closure (one effect at most: these data sets hold one)."""
    measured = read_measured(DATA / name)
    result = close_loop(benchmark_model, measured.frequencies_hz, measured.amplitude, np.zeros(6), library,
                        max_effects=1, **SETTINGS)
    return measured, result


def within_one_element(model, true_node: int, found: str) -> bool:
    """Both nodes are corners of one cell."""
    node = int(found.split()[1])
    cells = model.mesh.cells
    return bool(np.any(np.any(cells == true_node, axis=1) & np.any(cells == node, axis=1)))


def test_the_data_sets_cover_every_effect_type_and_five_clean_seeds():
    assert sorted(TRUTH["data"][n]["effect"] for n in EFFECT_FILES) == sorted(
        ["point_mass", "grounded_spring", "joint_band", "segment_mass", "damping"])
    assert len(CLEAN_FILES) == 5 and TRUTH["noise"] == 0.005


@pytest.mark.slow
@pytest.mark.parametrize("name", EFFECT_FILES)
def test_the_missing_effect_is_found_located_sized_and_removes_the_misfit(benchmark_model, library, name):
    truth = TRUTH["data"][name]
    measured, result = closure(benchmark_model, name, library)
    u = measured.amplitude
    assert result.before.structured
    # Also with the noise level estimated from the residual instead of configured.
    assert analyse_residual(result.baseline.residual, measured.frequencies_hz, 6).structured
    first = result.candidates[0]
    assert first is result.chosen, "the added effect is the first-ranked candidate"
    assert first.effect == truth["effect"]
    if "node" in truth:
        assert within_one_element(benchmark_model, truth["node"], first.location), (first.location, truth)
    else:
        assert first.location == truth["location"]
    assert first.fit.values[0] == pytest.approx(truth["value"], rel=0.20)
    before = overall_error(result.baseline.relative(u))
    after = overall_error(result.final.relative(u))
    assert after <= before / 5 or not result.after.structured, (before, after, result.after.summary())
    assert after < before


@pytest.mark.slow
@pytest.mark.parametrize("name", CLEAN_FILES)
def test_clean_data_gets_no_effect(benchmark_model, library, name):
    measured, result = closure(benchmark_model, name, library)
    assert result.chosen is None
    assert not result.before.structured
    assert not analyse_residual(result.baseline.residual, measured.frequencies_hz, 6).structured  # sigma estimated
    np.testing.assert_array_equal(result.final.alpha, result.baseline.alpha)
    # The update itself is right: every alpha within 0.02 of the truth.
    assert np.max(np.abs(result.baseline.alpha - np.array(TRUTH["alpha"]))) < 0.02


# -- issue 18: plausibility, verdicts, joint refits -----------------------------------------------------
def test_a_fit_on_a_plausibility_bound_is_flagged_but_not_one_at_the_effects_absence(benchmark_model):
    from fe_core.closure.decisions import at_bound
    from fe_core.closure.effects import ElementBand, PointMass

    pm = PointMass(benchmark_model)
    top = pm.bounds_at("node 337")[1][0]
    assert top == pytest.approx(0.2 * benchmark_model.total_mass())
    assert at_bound(pm, "node 337", [top]) and at_bound(pm, "node 337", [top - 1e-4])
    assert not at_bound(pm, "node 337", [0.0])  # no mass: nothing, not implausible
    assert not at_bound(pm, "node 337", [0.12])
    band = ElementBand(benchmark_model, {"b": np.arange(10)})
    assert at_bound(band, "b", [-0.999]) and not at_bound(band, "b", [-0.6])


def test_verdicts_name_noise_explained_and_partly_explained():
    from fe_core.closure.decisions import verdict

    class A:  # only .structured is read
        def __init__(self, structured):
            self.structured = structured

    assert verdict(A(False), A(False), 0) == "noise"
    assert verdict(A(True), A(False), 2) == "explained"
    assert verdict(A(True), A(True), 2) == "partly explained"
    assert verdict(A(True), A(True), 0) == "not explained"  # nothing stands out: nothing explained
    assert verdict(A(True), A(True), 0, own_misfit=True) == "not explained"


def test_an_earlier_effect_is_refitted_with_alpha_and_the_new_one(benchmark_model):
    """Noise-free data with two effects: from a wrong earlier value, the joint fit recovers both."""
    from fe_core.benchmark import ALPHA_ACTUAL
    from fe_core.closure.fits import fit_update
    from fe_core.closure.effects import Applied, GroundedSpring, PointMass, extended_frf

    freqs = np.linspace(20, 400, 40)
    pm, gs = PointMass(benchmark_model), GroundedSpring(benchmark_model)
    truth = [Applied(pm, "node 337", np.array([0.12])), Applied(gs, "node 919", np.array([4e5]))]
    u = np.abs(extended_frf(benchmark_model, ALPHA_ACTUAL, freqs, truth, method="direct"))
    fit = fit_update(benchmark_model, freqs, u, ALPHA_ACTUAL, gs, "node 919", [2e5],
                     prior=[Applied(pm, "node 337", np.array([0.06]))], max_evaluations=300)
    assert fit.n_parameters == 8 and [a.location for a in fit.applied] == ["node 337", "node 919"]
    assert fit.prior[0].values[0] == pytest.approx(0.12, rel=1e-3)
    assert fit.values[0] == pytest.approx(4e5, rel=1e-3)
    assert np.max(np.abs(fit.alpha - ALPHA_ACTUAL)) < 1e-3


def test_the_exact_and_the_difference_jacobian_reach_the_same_optimum(benchmark_model):
    """fit_update's exact Krylov Jacobian against the forward differences (step FD_STEP) it replaced.

    Noise-free data of the true alpha with a 0.12 kg mass (direct solver), fitted from alpha 0.03 off
    and 0.08 kg: both end at the truth (1e-10 measured; 1e-6 allowed: the data's direct solve and the
    fits' Krylov FRF agree to the FE core's 1e-9, the fits stop at tol 1e-8 on scaled parameters), the
    exact one in fewer FE runs (7 against 56 measured).
    """
    from fe_core.benchmark import ALPHA_ACTUAL
    from fe_core.closure.fits import fit_update
    from fe_core.closure.effects import Applied, PointMass, extended_frf

    freqs = np.linspace(20, 400, 30)
    pm = PointMass(benchmark_model)
    u = np.abs(extended_frf(benchmark_model, ALPHA_ACTUAL, freqs, [Applied(pm, "node 337", np.array([0.12]))],
                            method="direct"))
    fits = {j: fit_update(benchmark_model, freqs, u, ALPHA_ACTUAL + 0.03, pm, "node 337", [0.08], jacobian=j)
            for j in ("exact", "difference")}
    for fit in fits.values():
        assert np.max(np.abs(fit.alpha - ALPHA_ACTUAL)) < 1e-6 and fit.values[0] == pytest.approx(0.12, rel=1e-6)
    assert fits["exact"].evaluations < fits["difference"].evaluations
    with pytest.raises(ValueError, match="Jacobian"):
        fit_update(benchmark_model, freqs, u, np.zeros(6), jacobian="secant")


# -- issue 18: data/cases/three_plate_closure_table (full table: python -m benchmarks.closure --table) ---------------------------
DATA2 = DATA.parent / "three_plate_closure_table"
TRUTH2 = json.loads((DATA2 / "truth.json").read_text())["data"]


def closure2(model, name, kinds):
    """Forward selection from the nominal model with a small library (the cheapest that asserts the point)."""
    from fe_core.closure.effects import build_library

    measured = read_measured(DATA2 / name)
    return close_loop(model, measured.frequencies_hz, measured.amplitude, np.zeros(6),
                      build_library(model, kinds), **SETTINGS)


@pytest.mark.slow
def test_a_sensor_reading_8_percent_high_is_named_as_its_gain_not_as_structure(benchmark_model):
    truth = TRUTH2["sensor_gain.csv"]["effects"][0]
    result = closure2(benchmark_model, "sensor_gain.csv", ["sensor_gain", "point_mass", "grounded_spring"])
    assert result.verdict == "explained"
    assert [(c.effect, c.location) for c in result.steps] == [("sensor_gain", truth["location"])]
    assert result.final.values[0] == pytest.approx(truth["value"], abs=0.01)


@pytest.mark.slow
def test_an_effect_outside_the_library_is_never_called_explained(benchmark_model):
    assert not TRUTH2["outside_library.csv"]["in_library"]
    result = closure2(benchmark_model, "outside_library.csv",
                      ["sensor_gain", "point_mass", "sensor_mass", "grounded_spring"])
    assert result.before.structured
    # the stand-in (a 0.8 kg point mass for a spring tying two plates) takes out a good part of the residual but
    # shifts no mode by 0.1 % and leaves 45 % of the misfit: not plausible in size as the first effect
    # (fe_core.closure.far.plausible.mark_first_negligible; before that rule the half-band check dropped it).
    # What it leaves beyond the noise, 0.97 % rms of ln|Z|, is less than one of the band's modes 0.5 % off would
    # (4.1 %): as far as the size rule can tell, the model's own error, so `noise` (it said `not explained`).
    assert result.verdict == "noise" and result.after.structured and not result.steps
    assert result.own_error.within and result.stopped == "the model's own error"
    from fe_core.closure.far.plausible import MIN_SHIFT

    stand_in = [c for c in result.rounds[0] if c.fit is not None and c.effect == "point_mass"]
    assert stand_in and all(c.negligible and c.largest_shift < MIN_SHIFT for c in stand_in)


@pytest.mark.slow
def test_clean_data_far_from_nominal_get_noise(benchmark_model):
    result = closure2(benchmark_model, "far_clean.csv", ["point_mass"])
    assert result.verdict == "noise" and not result.steps
    # Stiff segments (alpha_5 = 0.5) are weaker in the data: within 0.05 at 0.5 % noise (0.041 measured).
    assert np.max(np.abs(result.baseline.alpha - np.array(TRUTH2["far_clean.csv"]["alpha"]))) < 0.05
