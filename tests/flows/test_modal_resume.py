"""The modal update as a Prefect flow: its stages are stored in the run folder; the same command again reads
them back (no FE run: every eigen-solve is made to fail), and changed inputs or settings are refused (exit 2)."""

from __future__ import annotations

import json

import pytest

from flows import update
from tasks.runstore import RunStore

pytestmark = pytest.mark.usefixtures("prefect_harness")

MODEL = "data/examples/modal/model.toml"
STAGES = ("identifiable", "correlation_before", "fit", "correlation_after", "closure")


def test_a_second_call_reads_the_stages_back_and_changed_inputs_are_refused(tmp_path, monkeypatch, capsys):
    measured = tmp_path / "modes.uff"
    measured.write_bytes(open("data/examples/modal/modes.uff", "rb").read())
    argv = ["--model", MODEL, "--measured", str(measured), "--runs-dir", str(tmp_path / "runs"), "--run-id", "r",
            "--starts", "1", "--frequency-sigma", "0.002", "--shape-sigma", "0.02"]
    assert update.main(argv) == 0
    root = tmp_path / "runs" / "r"
    first = json.loads((root / "summary.json").read_text())
    store = RunStore(root)
    assert all(store.is_finished(1, stage) for stage in STAGES)
    runs = (root / "modal_runs.jsonl").read_text()
    assert len(runs.splitlines()) == first["fe_runs"] > 0
    # the clean benchmark data (0.2 % / 2 % noise, stated): the closure finds noise and names no effect
    assert first["closure"]["verdict"] == "noise" and first["closure"]["chosen"] is None
    assert not first["closure"]["before"]["structured"]

    def no_fe_run(*args, **kwargs):
        raise AssertionError("an FE run (eigen-solve) on resume")

    import fe_core.modal_update.residual as residual
    import fe_core.solvers.modal as solver

    monkeypatch.setattr(residual, "eigenmodes", no_fe_run)
    monkeypatch.setattr(solver, "eigenmodes", no_fe_run)
    assert update.main(argv) == 0
    again = json.loads((root / "summary.json").read_text())
    assert again["parameters"] == first["parameters"] and again["closure"] == first["closure"]
    assert (root / "modal_runs.jsonl").read_text() == runs
    assert "resumed" in json.loads((root / "manifest.json").read_text())
    assert "Closure on the modal residual: noise" in (root / "report.html").read_text()
    capsys.readouterr()

    measured.write_text(measured.read_text().replace("measured modes", "measured modez", 1))  # other content
    assert update.main(argv) == 2
    err = capsys.readouterr().err
    assert "the measured file" in err and "SHA-256 differs" in err and "manifest.json" in err
    measured.write_bytes(open("data/examples/modal/modes.uff", "rb").read())
    assert update.main(argv[:-1] + ["0.03"]) == 2
    err = capsys.readouterr().err
    assert "setting sigma_s (0.02 then, 0.03 now)" in err
