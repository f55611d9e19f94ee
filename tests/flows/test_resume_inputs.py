"""A resumed or rerun run never reads back results computed from other inputs (issue 33): a changed measured file,
model file, noise setting or line selection exits 2 naming what changed, and writes nothing."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest

from flows import update
from flows.config import REPO
from tasks.io.measured import MeasuredFRF, read_measured, write_measured

SETTINGS = ["--n-jobs", "1", "--no-intervals"]


def _snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def finished(tmp_path_factory, prefect_harness):
    """One finished default run on copies of the benchmark's model and measured files."""
    folder = tmp_path_factory.mktemp("resume-inputs")
    for name in ("model.toml", "three_plate.inp", "measured.csv"):
        shutil.copy(REPO / "data" / "benchmark" / name, folder / name)
    args = ["--model", str(folder / "model.toml"), "--measured", str(folder / "measured.csv"),
            "--runs-dir", str(folder / "runs"), "--run-id", "x", *SETTINGS]
    assert update.main(args) == 0
    return folder, args


def _resume_refused(folder: Path, args: list[str], capsys, *needles: str) -> str:
    root = folder / "runs" / "x"
    before = _snapshot(root)
    assert update.main(args) == 2
    err = capsys.readouterr().err
    for needle in (*needles, "manifest.json", "--run-id"):
        assert needle in err, (needle, err)
    assert _snapshot(root) == before  # nothing written: no summary, no stage, no resume entry
    return err


def test_resuming_with_the_same_inputs_reads_the_run_back(finished, capsys):
    folder, args = finished
    assert update.main(args) == 0
    assert "overall error: 0.0000%" in capsys.readouterr().out


def test_a_measured_file_replaced_by_another_tests_data_is_refused(finished, capsys, tmp_path):
    folder, args = finished
    path = folder / "measured.csv"
    original = path.read_bytes()
    other = read_measured(path)
    try:
        write_measured(path, MeasuredFRF(frequencies_hz=other.frequencies_hz, sensors=other.sensors,
                                         amplitude=other.amplitude * 1.05, source="another test"))
        _resume_refused(folder, args, capsys, f"the measured file {path}", "content changed")
        with pytest.raises(update.ConfigError, match="the measured file .* content changed"):
            update.rerun_stage(folder / "runs" / "x", 1, "check", noise=0.01)
    finally:
        path.write_bytes(original)


def test_an_edited_model_file_is_refused(finished, capsys):
    folder, args = finished
    path = folder / "model.toml"
    original = path.read_text()
    try:
        path.write_text(original.replace("a = 0.01", "a = 0.02"))
        _resume_refused(folder, args, capsys, f"the model file and the files it refers to {path}", "content changed")
    finally:
        path.write_text(original)


@pytest.mark.parametrize(("extra", "needle"), [
    (["--noise", "0.01"], "setting noise (None then, 0.01 now)"),
    (["--lines", "windows", "--line-windows", "100-120"], "setting line_windows"),
])
def test_another_noise_or_line_selection_is_refused(finished, capsys, extra, needle):
    folder, args = finished
    err = _resume_refused(folder, args + extra, capsys, needle)
    if "noise" in needle:
        assert "rerun --run-id x --stage check --noise" in err  # how to see the check with another noise
