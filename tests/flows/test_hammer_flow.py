"""The benchmark's hammer test through the update flow: FRF kinds do not matter, the run records its data.

A reduced version of ``python -m benchmarks.hammer_kinds``: ``data/benchmark/hammer.uff``
written again as accelerance, mobility and receptance, a band around the first
resonance, the reduced budget of ``tests/flows/conftest.py``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flows import update
from flows.config import REPO, UpdateConfig
from flows.diagnose import DiagnoseError, closure_measurements
from fe_core.benchmark import ALPHA_ACTUAL
from tasks.io.measured import read_measured, write_measured
from tasks.stages import load_model
from tasks.update_data import update_data

HAMMER = REPO / "data" / "benchmark" / "hammer.uff"
#: The issue's target: the same parameters from every kind of the same data.
SAME_TOL = 1e-6
WINDOWS = [[100.0, 125.0]]


@pytest.fixture(scope="module")
def kinds(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("kinds")
    measured = read_measured(HAMMER)
    return {kind: write_measured(folder / f"{kind}.uff", measured, kind=kind)
            for kind in ("accelerance", "mobility", "receptance")}


@pytest.mark.slow
def test_accelerance_mobility_and_receptance_give_the_same_parameters(kinds, reduced_settings, prefect_harness,
                                                                      tmp_path):
    summaries = {}
    for kind, path in kinds.items():
        config = UpdateConfig(run_id=kind, runs_dir=str(tmp_path / "runs"), measured=str(path), lines="windows",
                              line_windows=WINDOWS, **reduced_settings)
        summaries[kind] = update.update_flow(config)
    reference = np.array(list(summaries["accelerance"]["parameters"].values()))
    for kind, summary in summaries.items():
        alpha = np.array(list(summary["parameters"].values()))
        np.testing.assert_allclose(alpha, reference, rtol=0, atol=SAME_TOL, err_msg=kind)
        assert summary["fe_evaluations"] == summaries["accelerance"]["fe_evaluations"]
    # What the run recorded about its data: the conversion, the channels, the selection, the table.
    root = tmp_path / "runs" / "mobility"
    info = json.loads((root / "manifest.json").read_text())["measured_data"]
    assert any("from mobility to receptance" in note for note in info["notes"])
    assert [c["excitation"] for c in info["channels"]] == ["hammer"] * 6
    assert [c["sensor"] for c in info["channels"]] == [f"s{j}" for j in range(1, 7)]
    assert info["residual"] == "complex" and info["selection"]["mode"] == "windows"
    table = pd.read_parquet(root / "measured.parquet")
    used = table[table["used"]]
    assert used["frequency_hz"].between(*WINDOWS[0]).all()
    assert info["values"] == 2 * len(used) == 2 * info["selection"]["values_kept"]


def test_the_closure_takes_the_hammer_test_only_as_the_models_default_excitation(tmp_path):
    with pytest.raises(DiagnoseError, match="excitation = \"hammer\""):
        closure_measurements(HAMMER, "three_plate", {"lines": "windows", "line_windows": WINDOWS})
    for name in ("model.toml", "three_plate.inp"):
        shutil.copy(REPO / "data" / "benchmark" / name, tmp_path / name)
    toml = tmp_path / "model.toml"
    toml.write_text(toml.read_text().replace('excitation = "combined"', 'excitation = "hammer"'))
    freqs, sensors, u = closure_measurements(HAMMER, str(toml), {"lines": "windows", "line_windows": WINDOWS,
                                                                 "min_coherence": 0.9})
    measured = read_measured(HAMMER)
    rows = np.flatnonzero((measured.frequencies_hz >= 100.0) & (measured.frequencies_hz <= 125.0))
    np.testing.assert_array_equal(freqs, measured.frequencies_hz[rows])
    np.testing.assert_array_equal(u, measured.amplitude[rows])
    assert sensors.tolist() == [1, 2, 3, 4, 5, 6]


def test_the_hammer_test_selects_its_two_resonances():
    model = load_model("three_plate")
    d = update_data(read_measured(HAMMER), model, lines="resonances",
                    resonance_widen=1.0, min_coherence=0.9)
    freqs = model.natural_frequencies(ALPHA_ACTUAL, 2)
    assert len(d.selection["windows"]) == 2
    for (lo, hi), f in zip(d.selection["windows"], freqs):
        assert lo < f < hi
