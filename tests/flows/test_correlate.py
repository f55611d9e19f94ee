"""python -m flows.correlate: the benchmark's modal example against its model, and bad input (exit 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fe_core.benchmark import ALPHA_ACTUAL
from flows import correlate
from tasks.io.measured.modes import read_modes, write_csv, write_uff55

MODEL = "data/examples/modal/model.toml"
EMA = "data/examples/modal/modes.uff"
OMA = "data/examples/modal/modes_oma.csv"


def test_correlation_at_the_actual_parameters_pairs_every_mode(tmp_path, capsys):
    # at the actual alpha every mode pairs in order with a MAC near 1 (the measured shapes carry 2 % noise at
    # 18 DOFs: 1 - MAC ~ 0.02^2 = 4e-4 each, far above 0.99) and the frequencies differ by the noise only
    # (0.2 %: within 4 sigma)
    theta = ",".join(str(v) for v in ALPHA_ACTUAL)
    assert correlate.main(["--model", MODEL, "--measured", EMA, f"--parameters={theta}", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "correlation.json").read_text())
    assert [p["model"] for p in result["pairs"]] == [f"model mode {k}" for k in range(1, 7)]
    assert min(p["mac"] for p in result["pairs"]) > 0.99
    assert all(abs(p["difference"]) < 4 * 0.002 for p in result["pairs"])
    # data from a twice finer mesh: it is softer, the benchmark mesh's frequencies lie above it by up to 1.5 %
    finer = correlate.run_correlation(MODEL, "data/examples/modal/modes_finer_mesh.uff", ALPHA_ACTUAL,
                                      out=tmp_path / "finer")
    assert all(-0.008 < p["difference"] < 0.015 for p in finer["pairs"])
    assert sum(p["difference"] > 0.003 for p in finer["pairs"]) >= 3
    assert (tmp_path / "mac.png").stat().st_size > 1000 and (tmp_path / "shapes.png").stat().st_size > 1000
    assert set(result["comac"]) == {f"{n}:+z" for n in range(101, 119)}
    assert "model mode 6" in capsys.readouterr().out


def test_oma_file_with_a_missing_mode_pairs_the_rest(tmp_path):
    result = correlate.run_correlation(MODEL, OMA, out=tmp_path)
    assert [p["test"] for p in result["pairs"]] == ["mode 1", "mode 2", "mode 3", "mode 4", "mode 6"]
    assert [p["model"] for p in result["pairs"]][-1] == "model mode 6"  # the 5th model mode is left over
    assert result["unpaired_test"] == []


def test_an_unpaired_mode_is_named(tmp_path):
    m = read_modes(EMA)
    rng = np.random.default_rng(0)
    m.shapes[2] = rng.normal(size=m.shapes.shape[1])  # mode 3 replaced by noise: no model mode resembles it
    path = write_csv(tmp_path / "m.csv", m)
    result = correlate.run_correlation(MODEL, str(path), threshold=0.8, out=tmp_path)
    assert result["unpaired_test"] == ["mode 3"]
    assert result["messages"][0].startswith("mode 3: unpaired; its best model mode is")


@pytest.mark.parametrize("case, message", [
    ("node", r"dataset 4: test node 999 \(999:\+z\) is not in the model"),
    ("band", r"dataset 4 \(mode 1\): frequency 50000 Hz is above the model's band"),
])
def test_bad_input_exits_2_naming_the_dataset(tmp_path, capsys, case, message):
    m = read_modes(EMA)
    if case == "node":
        m.dofs[0] = "999:+z"
    else:
        m.frequencies_hz[0] = 50000.0
    path = write_uff55(tmp_path / "bad.uff", m)
    assert correlate.main(["--model", MODEL, "--measured", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "bad.uff" in err
    import re

    assert re.search(message, err), err
    assert not (tmp_path / "o").exists()
