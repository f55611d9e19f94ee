"""Units through the update: a g/N, a mm/s and an lbf-reference file reach the fit as the SI file's residuals.

The SI file is the benchmark's hammer test (``data/benchmark/hammer.uff``, the SPEC's actual structure,
1 % noise); the others hold the same FRFs in other units (``tests/tasks/test_measured_units.py``'s
``write_variant``), read back to 1e-10 relative: the matched, selected data give the SI residuals. The run of a
g/N file giving the SI file's parameters to 1e-6 (and the unit and its conversion in its manifest) is in
``tests/flows/test_hammer_flow.py``, whose accelerance run is the SI file's. An unknown label exits 2 naming the
dataset and the label, and no run starts.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from flows import update
from flows.config import REPO

_spec = importlib.util.spec_from_file_location("units_helpers", REPO / "tests" / "tasks" / "test_measured_units.py")
_helpers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)
write_variant = _helpers.write_variant

HAMMER = REPO / "data" / "benchmark" / "hammer.uff"
WINDOWS = [[100.0, 125.0]]


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
