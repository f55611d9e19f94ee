"""The whole flow: one run under prefect_test_harness, CLI errors, rerun of a stage. (A kill from outside during an
FE stage, then resume: tests/flows/test_kill_anywhere.py, beside the kills at named points and their reference run.)"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from flows import update
from flows.config import UpdateConfig
from tasks.runstore import RunStore

SUMMARY_KEYS = {"parameters", "overall_error", "per_sensor_error", "fe_evaluations", "iterations", "converged",
                "trainer", "wall_seconds"}


@pytest.fixture(scope="module")
def reduced_run(tmp_path_factory, reduced_settings_frozen, prefect_harness):
    """(config, summary) of one reduced run, made once for the module: the flow's test and the rerun's."""
    config = UpdateConfig(run_id="reduced", runs_dir=str(tmp_path_factory.mktemp("update") / "runs"),
                          **dict(reduced_settings_frozen))
    return config, update.update_flow(config)


def test_whole_flow_under_the_test_harness(reduced_run, check_summary):
    reduced_config, summary = reduced_run
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


def test_rerun_of_the_train_stage_writes_a_new_folder_and_leaves_the_original(reduced_run):
    reduced_config, _ = reduced_run
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
