"""The whole flow: one run under prefect_test_harness, CLI errors, kill-and-resume, rerun of a stage."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from flows import update
from flows.config import REPO
from tasks.runstore import RunStore

SUMMARY_KEYS = {"parameters", "overall_error", "per_sensor_error", "fe_evaluations", "iterations", "converged",
                "trainer", "wall_seconds"}
TIMING_KEYS = {"wall_seconds", "run_folder", "run_id"}  # the time and the name of the run


def write_reduced_config(path: Path, runs_dir: Path, settings: dict) -> Path:
    lines = [f'runs_dir = "{runs_dir}"'] + [f"{k} = {json.dumps(v)}" for k, v in settings.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_whole_flow_under_the_test_harness(reduced_config, prefect_harness, check_summary):
    summary = update.update_flow(reduced_config)
    assert SUMMARY_KEYS <= set(summary)
    store = RunStore(Path(reduced_config.runs_dir) / "reduced")
    on_disk = json.loads((store.root / "summary.json").read_text())
    assert on_disk == summary
    check_summary(on_disk)  # the one shape (tasks/io/summary.schema.json)
    assert on_disk["kind"] == "frf" and on_disk["run_id"] == "reduced" and "intervals" not in on_disk
    # q = 8, then s = 4 per iteration, 3 iterations: 16 FE runs for the loop, then at most 7 for the polish.
    polish = store.read_table(3, "polish", "runs")
    assert summary["iterations"] == 3
    assert summary["fe_evaluations"] == 16 + len(polish) == 16 + summary["polish"]["n"] <= 23
    assert summary["polish"]["error_after"] <= summary["polish"]["error_before"]
    for k in (1, 2):
        for stage in ("fe", "distribution", "train", "predict", "select"):
            assert store.is_finished(k, stage), (k, stage)
    manifest = store.read_manifest()
    assert manifest["config"]["seed"] == reduced_config.seed and "numpy" in manifest["versions"]
    # The reported parameters are the best FE-evaluated sample.
    best = min([store.read_table(k, "fe", "runs")["overall_error"].min() for k in (1, 2, 3)]
               + [polish["overall_error"].min()])
    assert summary["overall_error"] == pytest.approx(best)


def _run_cli(args, env_extra=None, **kwargs):
    env = {**os.environ, **(env_extra or {})}
    return subprocess.Popen([sys.executable, "-m", "flows.update", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True, **kwargs)


def _strip(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k not in TIMING_KEYS}


@pytest.mark.slow
def test_sigkill_during_fe_stage_of_iteration_2_then_resume_gives_the_same_summary(tmp_path, reduced_settings,
                                                                                   prefect_server):
    runs = tmp_path / "runs"
    cfg = write_reduced_config(tmp_path / "reduced.toml", runs, reduced_settings)
    env = prefect_server  # the session's server: no temporary server per subprocess

    ref = _run_cli(["--config", str(cfg), "--run-id", "reference"], env)
    out, _ = ref.communicate(timeout=300)
    assert ref.returncode == 0, out

    victim = _run_cli(["--config", str(cfg), "--run-id", "victim"], {**env, "MRGP_FE_DELAY_SECONDS": "0.4"})
    log_path = runs / "victim" / "fe_evaluations.jsonl"
    deadline = time.time() + 240
    killed_after = None
    while time.time() < deadline and victim.poll() is None:
        if log_path.exists():
            entries = [json.loads(x) for x in log_path.read_text().splitlines() if x.strip()]
            in_iteration_2 = [e for e in entries if e["iteration"] == 2]
            if in_iteration_2:
                os.killpg(victim.pid, signal.SIGKILL)
                killed_after = len(in_iteration_2)
                break
        time.sleep(0.05)
    victim.communicate(timeout=60)
    assert killed_after is not None, "the run ended before the FE stage of iteration 2 could be interrupted"
    assert killed_after < 4, "the FE stage had already finished when the kill arrived"
    assert not (runs / "victim" / "summary.json").exists()
    assert not RunStore(runs / "victim").is_finished(2, "fe")

    resumed = _run_cli(["--config", str(cfg), "--run-id", "victim"], env)
    out, _ = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, out

    reference = json.loads((runs / "reference" / "summary.json").read_text())
    again = json.loads((runs / "victim" / "summary.json").read_text())
    assert _strip(again) == _strip(reference)
    entries = [json.loads(x) for x in log_path.read_text().splitlines()]
    ids = [e["sample_id"] for e in entries]
    assert len(ids) == len(set(ids)) == again["fe_evaluations"], "an FE sample was evaluated twice or lost"
    assert "resumes" in RunStore(runs / "victim").read_manifest()


def test_rerun_of_the_train_stage_writes_a_new_folder_and_leaves_the_original(reduced_config, prefect_harness):
    update.update_flow(reduced_config.replace(max_iterations=2, max_fe_evaluations=19))
    root = Path(reduced_config.runs_dir) / "reduced"
    store = RunStore(root)
    original = (store.stage_dir(1, "train") / "hyperparameters.parquet").read_bytes()
    out = update.rerun_stage(root, 1, "train", trainer="pso")
    assert out.name.startswith("stage=train.rerun-pso-")
    assert (out / "hyperparameters.parquet").exists() and (out / "_stage.json").exists()
    assert json.loads((out / "_stage.json").read_text())["info"]["trainer"] == "pso"
    assert (store.stage_dir(1, "train") / "hyperparameters.parquet").read_bytes() == original


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--trainer", "nope"], "invalid choice"),
        (["-q", "0"], "key 'q'"),
        (["--measured", "no/such/file.csv"], "no/such/file.csv"),
    ],
)
def test_bad_command_line_input_exits_2_and_names_the_problem(args, needle, tmp_path, capsys):
    with pytest.raises(SystemExit) if "invalid choice" in needle else _nullcontext():
        code = update.main([*args, "--runs-dir", str(tmp_path)])
        assert code == 2
    err = capsys.readouterr().err
    assert needle in err
    assert not any(tmp_path.iterdir())


class _nullcontext:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_bad_config_file_is_refused_naming_file_and_key(tmp_path, capsys):
    cfg = tmp_path / "bad.toml"
    cfg.write_text('trainr = "sao"\n')
    assert update.main(["--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert str(cfg) in err and "trainr" in err


def test_help_explains_every_option(capsys):
    with pytest.raises(SystemExit):
        update.main(["--help"])
    text = capsys.readouterr().out
    for flag in ("--config", "--measured", "--run-id", "--trainer", "--seed", "--n-jobs", "--strategy", "--repeats"):
        assert flag in text
