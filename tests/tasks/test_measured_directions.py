"""The direction rule: the file's direction code and the model file's test_direction combine by one product.

sign = sign(file code) x sign(model test_direction). The benchmark's hammer test (SPEC's actual
structure, +z accelerometers) is rewritten with channels 2 and 4 upside down (code -3, values negated, as a
test system exports an inverted accelerometer); read against the benchmark model (test_direction +z)
the data become the original ones. Declaring the inversion also in the model file (test_direction = "-z")
flips twice: the sign is +1 (the rule), and a warning names the channels.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pyuff

from flows.problem import load_model
from tasks.io.measured import read_measured
from tasks.update_data import update_data

REPO = Path(__file__).resolve().parents[2]
HAMMER = REPO / "data" / "benchmark" / "hammer.uff"
UPSIDE_DOWN = (2, 4)
OPTIONS = dict(lines="windows", line_windows=[[100.0, 125.0]], min_coherence=0.9)


def _inverted(path: Path) -> Path:
    sets = pyuff.UFF(str(HAMMER)).read_sets()
    for s in sets:
        if s["type"] == 58 and s["rsp_node"] in UPSIDE_DOWN:
            s["rsp_dir"] = -3
            if s["func_type"] == 4:
                s["data"] = -s["data"]
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite", force_double=True)
    return path


def _model_with_negative_test_direction(folder: Path) -> Path:
    for name in ("model.toml", "three_plate.inp"):
        shutil.copy(REPO / "data" / "benchmark" / name, folder / name)
    toml = folder / "model.toml"
    text = toml.read_text()
    for node in UPSIDE_DOWN:
        old = f'test_node = {node}  # the test\'s node id (UFF58), direction +z'
        assert old in text
        text = text.replace(old, f'test_node = {node}\ntest_direction = "-z"')
    toml.write_text(text)
    return toml


def test_file_code_flips_the_sign(tmp_path):
    model = load_model("three_plate")[0]
    si = update_data(read_measured(HAMMER), model, **OPTIONS)
    flipped = update_data(read_measured(_inverted(tmp_path / "inv.uff")), model, **OPTIONS)
    np.testing.assert_array_equal(flipped.complex_frf, si.complex_frf)
    assert [c["sign"] for c in flipped.channel_info] == [1, -1, 1, -1, 1, 1]
    assert flipped.manifest_entry()["direction_warnings"] == []


def test_both_negative_flip_twice_with_a_warning_naming_the_channels(tmp_path, caplog):
    model = load_model(str(_model_with_negative_test_direction(tmp_path)))[0]
    measured = read_measured(_inverted(tmp_path / "inv.uff"))
    with caplog.at_level(logging.WARNING, logger="tasks.update_data"):
        data = update_data(measured, model, **OPTIONS)
    assert [c["sign"] for c in data.channel_info] == [1] * 6  # (-1) x (-1): the rule, no silent special case
    np.testing.assert_array_equal(data.complex_frf[:, 1], measured.complex_frf[data.selection_lines, 1])
    labels = ["2:-z / 5:+z", "4:-z / 5:+z"]
    assert data.manifest_entry()["direction_warnings"] == labels
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 2 and all("cancel" in w for w in warned)
    assert labels[0] in warned[0] and labels[1] in warned[1]
    printed = [line for line in data.describe() if line.startswith("WARNING")]
    assert len(printed) == 1 and all(label in printed[0] for label in labels)


def test_a_negative_test_direction_alone_is_no_warning(tmp_path):
    """The model file says what the test calls the DOF: -z there and -z in the file match exactly, but a
    +z file against it flips once (no warning)."""
    model = load_model(str(_model_with_negative_test_direction(tmp_path)))[0]
    data = update_data(read_measured(HAMMER), model, **OPTIONS)
    assert [c["sign"] for c in data.channel_info] == [1, -1, 1, -1, 1, 1]
    assert data.manifest_entry()["direction_warnings"] == []
