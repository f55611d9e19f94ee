"""Intervals that know when the model does not explain the data: conditional, never called 95 % intervals.

The data come from a model other than the one fitted: the benchmark at the SPEC's actual stiffness with
segment 3's mass 30 % higher (``gamma``), which the six stiffness factors cannot represent, plus 1 %
noise, on 22 lines around the two resonances. The residual at the least-squares optimum is then
structure (about 5 % rms against ~1 % noise), and the summary, the printout and the report must say
the intervals are conditional on a model that does not explain the data.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from fe_core.benchmark import ALPHA_ACTUAL, three_plate
from flows import update
from flows.summary import CONDITIONAL_WORDS, interval_status
from tasks.io.measured import MeasuredFRF, write_measured

FREQS = np.r_[np.arange(106.0, 116.1, 1.0), np.arange(285.0, 295.1, 1.0)]
GAMMA = np.array([0.0, 0.0, 0.3, 0.0, 0.0, 0.0])


def _other_model_data(path: Path) -> Path:
    Z = three_plate().frf(ALPHA_ACTUAL, FREQS, gamma=GAMMA)
    u = np.abs(Z) * np.exp(0.01 * np.random.default_rng(30).standard_normal(Z.shape))
    return write_measured(path, MeasuredFRF(FREQS, np.arange(1, 7), u, source="other model"))


@pytest.mark.slow
def test_structure_makes_the_intervals_conditional_everywhere(reduced_settings, prefect_harness, tmp_path):
    from tasks.report.data import load_run
    from tasks.report.sections import intervals_section

    config = update.UpdateConfig(run_id="other", runs_dir=str(tmp_path / "runs"),
                                 measured=str(_other_model_data(tmp_path / "m.csv")),
                                 **{**reduced_settings, "intervals": True, "posterior_fe": 0,
                                    "true_parameters": ALPHA_ACTUAL.tolist()})
    summary = update.update_flow(config)
    assert summary["residual_check"]["structured"] and summary["residual_check"]["rms"] > 0.03
    assert summary["interval_status"] == "conditional"
    assert summary["conditional_on"].startswith(CONDITIONAL_WORDS) and "structure" in summary["conditional_on"]
    assert "coverage study" not in summary["interval_details"]["method_reason"]
    on_disk = json.loads((Path(config.runs_dir) / "other" / "summary.json").read_text())
    assert on_disk["interval_status"] == "conditional" and on_disk["conditional_on"] == summary["conditional_on"]
    out = io.StringIO()
    update.print_summary(summary, file=out)
    text = out.getvalue()
    assert "95 %" not in text.replace("not 95 % intervals", "")
    assert "+/- (cond.)" in text and CONDITIONAL_WORDS in text
    section = intervals_section(load_run(Path(config.runs_dir) / "other"), tmp_path)
    assert CONDITIONAL_WORDS in section.paragraphs[0] and "not 95 % intervals" in section.paragraphs[0]
    (caption, table), = section.tables
    assert caption == "Intervals conditional on the model" and "low (conditional)" in table.columns
    assert not any("95 %" in str(c) for c in table.columns)


def test_status_rules():
    noise = {"structured": False, "text": "noise"}
    structure = {"structured": True, "text": "rms 5 % vs noise 1 %: structure"}
    assert interval_status({"residual_check": noise, "strategy": "hybrid", "converged": True}) == {
        "interval_status": "95 %"}
    out = interval_status({"residual_check": structure, "strategy": "adaptive", "converged": True})
    assert out["interval_status"] == "conditional" and "rms 5 %" in out["conditional_on"]
    out = interval_status({"residual_check": noise, "strategy": "hybrid", "converged": False,
                           "stop_reason": "budget spent"})
    assert out["interval_status"] == "conditional" and "did not converge (budget spent)" in out["conditional_on"]
    # the paper loop's budget stop alone: its threshold is an error level, the residual check decides
    assert interval_status({"residual_check": noise, "strategy": "adaptive", "converged": False}) == {
        "interval_status": "95 %"}


def test_no_posterior_is_sampled_for_a_model_that_does_not_explain_the_data():
    """The sampled posterior (400 FE runs by default) is kept for runs whose intervals can be 95 % intervals: not a
    run stopped on the evidence of a missing effect, nor a hybrid run that did not converge (its intervals are
    conditional whatever their method); a paper-loop run's budget stop alone is no reason (as above)."""
    from flows.summary import posterior_not_sampled

    assert posterior_not_sampled({"strategy": "hybrid", "converged": True}) == ""
    assert posterior_not_sampled({"strategy": "adaptive", "converged": False}) == ""
    why = posterior_not_sampled({"strategy": "hybrid", "converged": False})
    assert why.startswith("the run did not converge") and "conditional" in why
    assert interval_status({"strategy": "hybrid", "converged": False})["interval_status"] == "conditional"
    why = posterior_not_sampled({"strategy": "hybrid", "converged": False, "evidence": {"choice": "closure"}})
    assert why.startswith("the run stopped on the evidence of a missing effect")


def test_a_run_stopped_at_the_models_own_error_says_so_and_samples_no_posterior():
    """The hybrid's own-error stop (strategies.hybrid, status "own error"): converged, but to the model's own error;
    its intervals conditional on the structured residual, no posterior sampled for a model that explains the data
    only up to that error."""
    from flows.summary import posterior_not_sampled

    reason = "the misfit beyond the noise (3.97% rms of ln|Z|) is at most what one of the band's 6 modes ..."
    structure = {"structured": True, "text": "rms 4.4 % vs noise 1.7 %: structure"}
    summary = {"run_folder": "x", "strategy": "hybrid", "trainer": "gradient", "converged": True, "iterations": 1,
               "fe_evaluations": 8, "wall_seconds": 41.4, "overall_error": 0.032, "parameters": {"alpha_1": 0.17},
               "per_sensor_error": {"sensor_1": 0.025}, "own_error": {"within": True, "reason": reason},
               "residual_check": structure}
    out = io.StringIO()
    update.print_summary(summary, file=out)
    lines = out.getvalue().splitlines()
    assert any("converged to the model's own error after 1 cycles" in line for line in lines)
    assert f"the model's own error: {reason}" in lines
    assert interval_status(summary)["interval_status"] == "conditional"
    assert "own error" in posterior_not_sampled(summary)
    assert posterior_not_sampled({**summary, "own_error": None}) == ""
