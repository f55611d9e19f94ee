"""The modal update as a Prefect flow: its stages are stored in the run folder; the same command again reads
them back (no FE run: every eigen-solve is made to fail), and changed inputs or settings are refused (exit 2)."""

from __future__ import annotations

import json

import pytest

from flows import update
from tasks.runstore import RunStore


MODEL = "data/examples/modal/model.toml"
STAGES = ("identifiable", "correlation_before", "fit", "correlation_after", "closure")


def _api(url: str, path: str, body: dict) -> list:
    import httpx

    response = httpx.post(f"{url}{path}", json=body, timeout=30)
    response.raise_for_status()
    return response.json()


def test_a_second_call_reads_the_stages_back_and_changed_inputs_are_refused(tmp_path, monkeypatch, capsys,
                                                                           prefect_harness, check_summary):
    measured = tmp_path / "modes.uff"
    measured.write_bytes(open("data/examples/modal/modes.uff", "rb").read())
    argv = ["--model", MODEL, "--measured", str(measured), "--runs-dir", str(tmp_path / "runs"), "--run-id", "resumed",
            "--starts", "1", "--frequency-sigma", "0.002", "--shape-sigma", "0.02"]
    assert update.main(argv) == 0
    root = tmp_path / "runs" / "resumed"
    first = check_summary(root)  # the one shape, with the closure on the modal residual
    store = RunStore(root)
    assert all(store.is_finished(1, stage) for stage in STAGES)
    runs = (root / "modal_runs.jsonl").read_text()
    # the run in Prefect's API: the flow run (its task runs, one per computed stage, are shown by a server that
    # records them: tests/flows/test_prefect_ui.py; the session's server here does not record task runs)
    flow_runs = _api(prefect_harness, "/flow_runs/filter", {"flow_runs": {"name": {"any_": ["modal-resumed"]}}})
    assert [f["state_type"] for f in flow_runs] == ["COMPLETED"]
    # every eigen-solve is recorded: the update's, and the closure's own when its screen needs one (on some CPUs the
    # closure's point is not bit for bit a fitted run's, and it solves once more)
    assert len(runs.splitlines()) == first["fe_evaluations"] + first["closure"].get("fe_runs", 0)
    assert first["fe_evaluations"] > 0
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
    # an interrupted run (the closure's record missing): only the closure is computed again, the fit read back
    monkeypatch.undo()
    import tasks.modal_fit

    def no_fit(*args, **kwargs):
        raise AssertionError("the fit again on resume")

    monkeypatch.setattr(tasks.modal_fit, "run_fit", no_fit)
    (root / "iteration=1" / "stage=closure" / "_stage.json").unlink()
    assert update.main(argv) == 0
    assert json.loads((root / "summary.json").read_text())["closure"]["verdict"] == "noise"
    assert store.is_finished(1, "closure")
