"""Closing the loop on data with an undeclared effect (data/effects), judged against its truth file.

Each closure starts from the nominal model with the cheap multi-start
least-squares update (no MRGP run), with the settings of
``benchmarks/closure.py``. The truth (``truth.json``) is read only here.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fe_core.closure import close_loop
from fe_core.residual import analyse_residual, overall_error
from tasks.io.measured import read_measured

DATA = Path(__file__).resolve().parents[2] / "data" / "effects"
SETTINGS = dict(noise=0.005, restarts=2, per_type=1)
TRUTH = json.loads((DATA / "truth.json").read_text())
EFFECT_FILES = [name for name, t in TRUTH["data"].items() if t["effect"]]
CLEAN_FILES = [name for name, t in TRUTH["data"].items() if not t["effect"]]


def closure(benchmark_model, name):
    measured = read_measured(DATA / name)
    result = close_loop(benchmark_model, measured.frequencies_hz, measured.amplitude, np.zeros(6), **SETTINGS)
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
def test_the_missing_effect_is_found_located_sized_and_removes_the_misfit(benchmark_model, name):
    truth = TRUTH["data"][name]
    measured, result = closure(benchmark_model, name)
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
def test_clean_data_gets_no_effect(benchmark_model, name):
    measured, result = closure(benchmark_model, name)
    assert result.chosen is None
    assert not result.before.structured
    assert not analyse_residual(result.baseline.residual, measured.frequencies_hz, 6).structured  # sigma estimated
    np.testing.assert_array_equal(result.final.alpha, result.baseline.alpha)
    # The update itself is right: every alpha within 0.02 of the truth.
    assert np.max(np.abs(result.baseline.alpha - np.array(TRUTH["alpha"]))) < 0.02
