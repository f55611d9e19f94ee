"""The benchmark's hammer test through the update flow: FRF kinds and units do not matter, the run records its data.

A reduced version of ``python -m benchmarks.hammer_kinds``: ``data/benchmark/hammer.uff``
written again as accelerance, mobility and receptance, a band around the first
resonance, the reduced budget of ``tests/flows/conftest.py``.
"""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flows import update
from flows.config import REPO, UpdateConfig
from flows.diagnose import DiagnoseError, closure_data
from fe_core.benchmark import ALPHA_ACTUAL
from tasks.io.measured import read_measured, write_measured
from flows.problem import load_model as _load


def load_model(name):
    return _load(name)[0]
from tasks.update_data import update_data

_spec = importlib.util.spec_from_file_location("units_helpers", REPO / "tests" / "tasks" / "test_measured_units.py")
_helpers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)
write_variant = _helpers.write_variant

HAMMER = REPO / "data" / "benchmark" / "hammer.uff"
#: The issue's target: the same parameters from every kind of the same data.
SAME_TOL = 1e-6
WINDOWS = [[100.0, 125.0]]


@pytest.fixture(scope="module")
def kinds(tmp_path_factory) -> dict[str, Path]:
    """hammer.uff itself (accelerance, SI) and the same FRFs written as mobility and receptance (the writer's round
    trip of every kind: tests/tasks/test_measured_channels.py)."""
    folder = tmp_path_factory.mktemp("kinds")
    measured = read_measured(HAMMER)
    return {"accelerance": HAMMER, **{kind: write_measured(folder / f"{kind}.uff", measured, kind=kind)
                                      for kind in ("mobility", "receptance")}}


def _window_run(runs: Path, run_id: str, path: Path, settings) -> dict:
    config = UpdateConfig(run_id=run_id, runs_dir=str(runs), measured=str(path), lines="windows",
                          line_windows=WINDOWS, **dict(settings))
    return update.update_flow(config)


@pytest.fixture(scope="module")
def kind_runs(kinds, tmp_path_factory, reduced_settings_frozen, prefect_harness) -> tuple[Path, dict]:
    """(runs folder, summaries) of the reduced run of each kind; the accelerance one is the SI file's run, also the
    reference of the units' run (tests/flows/test_measured_units_flow.py has their conversions)."""
    runs = tmp_path_factory.mktemp("kind-runs")
    return runs, {kind: _window_run(runs, kind, path, reduced_settings_frozen) for kind, path in kinds.items()}


@pytest.mark.slow
def test_accelerance_mobility_and_receptance_give_the_same_parameters(kind_runs):
    runs, summaries = kind_runs
    reference = np.array(list(summaries["accelerance"]["parameters"].values()))
    for kind, summary in summaries.items():
        alpha = np.array(list(summary["parameters"].values()))
        np.testing.assert_allclose(alpha, reference, rtol=0, atol=SAME_TOL, err_msg=kind)
        assert summary["fe_evaluations"] == summaries["accelerance"]["fe_evaluations"]
    # What the run recorded about its data: the conversion, the channels, the selection, the table.
    root = runs / "mobility"
    info = json.loads((root / "manifest.json").read_text())["measured_data"]
    assert any("from mobility to receptance" in note for note in info["notes"])
    assert [c["excitation"] for c in info["channels"]] == ["hammer"] * 6
    assert [c["sensor"] for c in info["channels"]] == [f"s{j}" for j in range(1, 7)]
    assert info["residual"] == "complex" and info["selection"]["mode"] == "windows"
    table = pd.read_parquet(root / "measured.parquet")
    used = table[table["used"]]
    assert used["frequency_hz"].between(*WINDOWS[0]).all()
    assert info["values"] == 2 * len(used) == 2 * info["selection"]["values_kept"]


@pytest.mark.slow
def test_a_g_per_newton_file_gives_the_si_parameters(kind_runs, reduced_settings_frozen, tmp_path):
    """Units through the update (moved from tests/flows/test_measured_units_flow.py, whose SI run was this module's
    accelerance run): hammer.uff in g/N (``write_variant`` of tests/tasks/test_measured_units.py, read back to 1e-10
    relative) gives the SI file's parameters to SAME_TOL; the mm/s and lbf files reach the fit as the same residual
    vectors (that module's tests), which with the same deterministic run gives the same parameters. The run records
    the unit and its conversion in the manifest."""
    _, summaries = kind_runs
    g = _window_run(tmp_path / "runs", "g", write_variant(tmp_path / "g.uff", "g"), reduced_settings_frozen)
    reference = np.array(list(summaries["accelerance"]["parameters"].values()))
    assert np.max(np.abs(reference)) > 0.01  # the run moved: equal parameters are not the start point
    np.testing.assert_allclose(np.array(list(g["parameters"].values())), reference, rtol=0, atol=SAME_TOL)
    info = json.loads((tmp_path / "runs" / "g" / "manifest.json").read_text())["measured_data"]
    assert [c["unit"] for c in info["channels"]] == ["g/N"] * 6
    assert any(note.startswith("unit g/N (accelerance) in 6 dataset(s)") and "x 9.80665" in note
               for note in info["notes"])


def test_the_closure_takes_the_hammer_test_only_as_the_models_default_excitation(tmp_path):
    model = load_model("three_plate")
    with pytest.raises(DiagnoseError, match="excitation = \"hammer\""):
        closure_data(update_data(read_measured(HAMMER), model, lines="windows", line_windows=WINDOWS), model)
    for name in ("model.toml", "three_plate.inp"):
        shutil.copy(REPO / "data" / "benchmark" / name, tmp_path / name)
    toml = tmp_path / "model.toml"
    toml.write_text(toml.read_text().replace('excitation = "combined"', 'excitation = "hammer"'))
    hammer_model = load_model(str(toml))
    data = closure_data(update_data(read_measured(HAMMER), hammer_model, lines="windows", line_windows=WINDOWS,
                                    min_coherence=0.9), hammer_model)
    freqs, u = data.complete()
    measured = read_measured(HAMMER)
    rows = np.flatnonzero((measured.frequencies_hz >= 100.0) & (measured.frequencies_hz <= 125.0))
    np.testing.assert_array_equal(freqs, measured.frequencies_hz[rows])
    np.testing.assert_array_equal(u, measured.amplitude[rows])
    assert data.sensors.tolist() == [1, 2, 3, 4, 5, 6]


def test_the_hammer_test_selects_its_two_resonances():
    model = load_model("three_plate")
    d = update_data(read_measured(HAMMER), model, lines="resonances",
                    resonance_widen=1.0, min_coherence=0.9)
    freqs = model.natural_frequencies(ALPHA_ACTUAL, 2)
    assert len(d.selection["windows"]) == 2
    for (lo, hi), f in zip(d.selection["windows"], freqs):
        assert lo < f < hi


@pytest.mark.slow
def test_two_references_at_once_run_through_the_flow(reduced_settings, prefect_harness, tmp_path):
    """MIMO: three responses under the hammer (UFF-style node labels) and three under the combined load (names),
    made with the direct solver at the actual alpha; the run evaluates all six channels per FE run, and the
    intervals stack the two references in one error model. posterior_fe = 0: the Laplace intervals, where the
    stacking is; this reduced run ends far from the optimum, where the linearity check would otherwise sample the
    posterior with 400 FE runs of both references (the sampled path: tests/flows/test_intervals_stage.py)."""
    from tasks.io.measured import MeasuredFRF

    model = load_model("three_plate")
    freqs = np.array([100.0, 106.0, 110.0, 112.0, 114.0, 118.0, 280.0, 287.0, 291.0, 295.0, 300.0])
    responses, references = np.array([1, 3, 5, 0, 2, 4]), np.array([1, 1, 1, 0, 0, 0])
    Z = model.frf_channels(ALPHA_ACTUAL, freqs, responses, references, method="direct")
    measured = MeasuredFRF(freqs, np.arange(1, 7), np.abs(Z), Z, "mimo", responses=("2:+z", "4:+z", "6:+z", "s1",
                           "s3", "s5"), references=("5:+z", "5:+z", "5:+z", None, None, None))
    path = write_measured(tmp_path / "mimo.csv", measured)
    config = UpdateConfig(run_id="mimo", runs_dir=str(tmp_path / "runs"), measured=str(path),
                          **{**reduced_settings, "intervals": True, "posterior_fe": 0})
    summary = update.update_flow(config)
    info = json.loads((tmp_path / "runs" / "mimo" / "manifest.json").read_text())["measured_data"]
    assert [c["excitation"] for c in info["channels"]] == ["hammer"] * 3 + ["combined"] * 3
    assert [c["sensor"] for c in info["channels"]] == ["s2", "s4", "s6", "s1", "s3", "s5"]
    assert "intervals_skipped" not in summary and set(summary["intervals"]) == set(summary["parameters"])
    assert summary["interval_details"]["references"] == 2 and summary["interval_method"] == "laplace"
    assert len(summary["per_sensor_error"]) == 6
    stage = tmp_path / "runs" / "mimo" / "iteration=1" / "stage=fe"
    fe, runs = pd.read_parquet(stage / "responses.parquet"), pd.read_parquet(stage / "runs.parquet")
    first = fe[fe["sample_id"] == fe["sample_id"].min()].sort_values(["frequency_hz", "sensor"])
    alpha = runs.loc[runs["sample_id"] == fe["sample_id"].min(), [f"alpha_{i}" for i in range(1, 7)]].to_numpy()[0]
    expected = model.frf_channels(alpha, freqs, responses, references, method="direct")
    got = (first["real"].to_numpy() + 1j * first["imag"].to_numpy()).reshape(expected.shape)
    assert np.max(np.abs(got - expected) / np.abs(expected)) <= 1e-9  # the FE core's Krylov-vs-direct promise
