"""Units through the update: a g/N, a mm/s and an lbf-reference file give the SI file's parameters.

The SI file is the benchmark's hammer test (``data/benchmark/hammer.uff``, the SPEC's actual structure,
1 % noise); the others hold the same FRFs in other units (``tests/tasks/test_measured_units.py``'s
``write_variant``), read back to 1e-10 relative, so the reduced run (``tests/flows/conftest.py``) must give
the same parameters to ``SAME_TOL``, as ``tests/flows/test_hammer_flow.py`` asks of the FRF kinds. The run
records the unit and its conversion in the manifest. An unknown label exits 2 naming the dataset and the
label, and no run starts.
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from flows import update
from flows.config import REPO, UpdateConfig

_spec = importlib.util.spec_from_file_location("units_helpers", REPO / "tests" / "tasks" / "test_measured_units.py")
_helpers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)
write_variant = _helpers.write_variant

HAMMER = REPO / "data" / "benchmark" / "hammer.uff"
SAME_TOL = 1e-6
WINDOWS = [[100.0, 125.0]]


@pytest.mark.slow
def test_g_mm_per_s_and_lbf_files_give_the_si_parameters(reduced_settings, prefect_harness, tmp_path):
    """Two runs (SI, g/N: ~20 s each on a busy machine); the mm/s and lbf files reach the fit as the same
    residual vectors (next test), which with the same deterministic run gives the same parameters."""
    files = {"si": HAMMER, "g": write_variant(tmp_path / "g.uff", "g")}
    summaries = {}
    for name, path in files.items():
        config = UpdateConfig(run_id=name, runs_dir=str(tmp_path / "runs"), measured=str(path), lines="windows",
                              line_windows=WINDOWS, **reduced_settings)
        summaries[name] = update.update_flow(config)
    reference = np.array(list(summaries["si"]["parameters"].values()))
    assert np.max(np.abs(reference)) > 0.01  # the run moved: equal parameters are not the start point
    for name, summary in summaries.items():
        alpha = np.array(list(summary["parameters"].values()))
        np.testing.assert_allclose(alpha, reference, rtol=0, atol=SAME_TOL, err_msg=name)
    info = json.loads((tmp_path / "runs" / "g" / "manifest.json").read_text())["measured_data"]
    assert [c["unit"] for c in info["channels"]] == ["g/N"] * 6
    assert any(note.startswith("unit g/N (accelerance) in 6 dataset(s)") and "x 9.80665" in note
               for note in info["notes"])


@pytest.mark.parametrize("unit, denominator", [("mm/s", "N"), ("m/s^2", "lbf"), ("g", "lbf"), ("in/s", "kN")])
def test_other_units_reach_the_fit_as_the_si_residuals(tmp_path, unit, denominator):
    """What the update fits (the matched, selected data and their residuals at a model FRF) is the SI file's."""
    from flows.problem import load_model
    from tasks.io.measured import read_measured
    from tasks.update_data import update_data

    model = load_model("three_plate")[0]
    options = dict(lines="windows", line_windows=WINDOWS, min_coherence=0.9)
    si = update_data(read_measured(HAMMER), model, **options)
    other = update_data(read_measured(write_variant(tmp_path / "v.uff", unit, denominator=denominator)), model,
                        **options)
    assert other.channel_info[0]["unit"] == f"{unit}/{denominator}"
    np.testing.assert_array_equal(other.mask, si.mask)
    Z = model.frf_channels(np.zeros(6), si.frequencies_hz, si.responses, si.references)
    np.testing.assert_allclose(other.residuals(Z), si.residuals(Z), rtol=0, atol=1e-9)


def test_unknown_label_exits_2_naming_dataset_and_label(tmp_path, capsys):
    path = write_variant(tmp_path / "bad.uff", "g", label="gee")
    code = update.main(["--run-id", "bad", "--runs-dir", str(tmp_path / "runs"), "--measured", str(path)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert str(path) in err and "dataset 2" in err and "'gee'" in err
    assert "Traceback" not in err
    assert not (tmp_path / "runs" / "bad").exists()
