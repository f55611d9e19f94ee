"""python -m flows.update on measured modes: the benchmark at 18 test nodes (EMA, and OMA with unscaled
shapes and mode 5 missing) recovers the SPEC's actual alpha inside its 95 % intervals; bad input exits 2.

The data (data/examples/modal, ``python -m benchmarks.make.modal_example``): the frequencies of the SPEC's
independent implementation (expected.json) and the SPEC mesh's shapes at the actual alpha, 0.2 % frequency
and 2 % shape noise. The coverage over 20 noisy sets is ``python -m benchmarks.modal_coverage``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fe_core.benchmark import ALPHA_ACTUAL
from flows import update
from tasks.io.measured.modes import read_modes, write_uff55

pytestmark = pytest.mark.usefixtures("prefect_harness")  # the modal update is a Prefect flow

MODEL = "data/examples/modal/model.toml"
TRUE = "--true-parameters=" + ",".join(str(v) for v in ALPHA_ACTUAL)


def _run(tmp_path, measured, *extra):
    argv = ["--model", MODEL, "--measured", measured, "--runs-dir", str(tmp_path), "--run-id", "r", "--starts", "1",
            "--frequency-sigma", "0.002", "--shape-sigma", "0.02", "--no-closure", TRUE, *extra]
    assert update.main(argv) == 0
    return json.loads((tmp_path / "r" / "summary.json").read_text())


@pytest.mark.parametrize("measured", ["data/examples/modal/modes.uff", "data/examples/modal/modes_oma.csv"])
def test_modal_update_recovers_the_actual_alpha_within_its_intervals(tmp_path, measured, check_summary):
    s = _run(tmp_path, measured)
    check_summary(s)  # the one shape of every run (tasks/io/summary.schema.json)
    assert s["kind"] == "modal" and s["converged"] and s["run_folder"] == str(tmp_path / "r")
    # the shape from before the schema (parameters as {value, sd, lower95, upper95}) is refused
    old = {**s, "parameters": {n: {"value": v, **s["intervals"][n]} for n, v in s["parameters"].items()}}
    with pytest.raises(AssertionError, match=r"parameters/alpha_1: \{.*\} is not of type 'number'"):
        check_summary(old)
    assert all(s["intervals_contain_truth"].values()), s["parameters"]
    sd = np.array([s["intervals"][n]["sd"] for n in s["parameters"]])
    # the figure for 6 modes at 18 nodes with these noise levels: sd 0.004 - 0.023 (OMA: a little wider)
    assert 0.002 < sd.min() and sd.max() < 0.03
    assert s["fe_evaluations"] >= s["jacobians"] - 1 > 0
    lines = (tmp_path / "r" / "modal_runs.jsonl").read_text().splitlines()
    assert len(lines) == s["fe_evaluations"]
    for name in ("mac_before.png", "mac_after.png", "shapes_after.png", "correlation_before.json", "report.html",
                 "correlation_after.json"):
        assert (tmp_path / "r" / name).exists()
    report = (tmp_path / "r" / "report.html").read_text()
    assert 'src="mac_after.png"' in report and "alpha_6" in report and "OUTSIDE" not in report
    if measured.endswith(".csv"):  # OMA: mode 5 left out of the file is named
        assert "missing from the measured modes: mode 5" in report
        assert s["missing_mode_numbers"] == ["mode 5"]
        assert [p["test"] for p in s["paired_modes"]] == ["mode 1", "mode 2", "mode 3", "mode 4", "mode 6"]
        assert any("shapes make up" in n for n in s["notes"])


@pytest.mark.parametrize("case, message", [
    ("few", r"2 paired mode\(s\) for 6 parameters: fewer paired modes than parameters, and the frequencies cannot "
            r"determine alpha_\d, alpha_\d, alpha_\d, alpha_\d \(not identifiable\)"),
    ("static", r"dataset 4: dataset 55 of analysis type 1 \(static\) is not a mode"),
    ("buckling", r"dataset 4: dataset 55 of analysis type 6 \(buckling\) is not a mode"),
    ("nonfinite", r"dataset 6 \(mode 3\): the shape is not finite at node 1\d\d"),
    ("node", r"dataset 4: test node 999 \(999:\+z\) is not in the model"),
    ("band", r"dataset 9 \(mode 6\): frequency 9000 Hz is above the model's band"),
])
def test_bad_modal_input_exits_2(tmp_path, capsys, case, message):
    import re

    m = read_modes("data/examples/modal/modes.uff")
    if case == "few":
        m.frequencies_hz, m.damping, m.shapes = m.frequencies_hz[:2], m.damping[:2], m.shapes[:2]
        m.names, m.places = m.names[:2], m.places[:2]
    if case == "node":
        m.dofs[0] = "999:+z"
    if case == "band":
        m.frequencies_hz[5] = 9000.0
    path = write_uff55(tmp_path / "bad.uff", m)
    lines = path.read_text().splitlines()
    starts = [i for i, line in enumerate(lines) if line.strip() == "55"]  # datasets 4..9: modes 1..6
    if case in ("static", "buckling"):
        k = starts[0] + 6  # record 6 after the five ID lines
        lines[k] = lines[k][:10] + f"{1 if case == 'static' else 6:10d}" + lines[k][20:]
    if case == "nonfinite":
        k = starts[2] + 10  # mode 3: records 6-8, then the first node's number and its values
        lines[k] = "          nan" + lines[k][13:]
    path.write_text("\n".join(lines) + "\n")
    extra = ["--no-shapes"] if case == "few" else []
    argv = ["--model", MODEL, "--measured", str(path), "--runs-dir", str(tmp_path / "runs"), "--run-id", "r", *extra]
    assert update.main(argv) == 2
    err = capsys.readouterr().err
    assert "bad.uff" in err and re.search(message, err), err
    assert not (tmp_path / "runs").exists()
