"""The ``outputs`` key: full MRGP, reduced output basis, or auto (reduced above k = 200 responses)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from flows import update
from flows.config import ConfigError, UpdateConfig, load_config
from flows.run import write_manifest
from strategies.emulation import AUTO_REDUCED_ABOVE, reduced_outputs
from tasks.runstore import RunStore

TIMING_KEYS = {"wall_seconds", "run_folder", "run_id"}  # the time and the name of the run


def _strip(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k not in TIMING_KEYS}


def test_auto_switches_to_the_reduced_basis_only_above_the_threshold():
    k = AUTO_REDUCED_ABOVE
    assert not reduced_outputs("auto", 72) and not reduced_outputs("auto", k)
    assert reduced_outputs("auto", k + 1) and reduced_outputs("reduced", 72)
    assert not reduced_outputs("full", 10 * k)


@pytest.mark.slow
def test_reduced_run_records_the_rank_and_resumes_to_the_same_summary(reduced_config, prefect_harness):
    # the residual emulation: all 72 residuals in the reduced basis (the modal emulation keeps its modes out of
    # it: tests/flows/test_modal_emulation.py)
    config = reduced_config.replace(outputs="reduced", emulate="errors")
    summary = update.update_flow(config)
    store = RunStore(Path(config.runs_dir) / "reduced")
    assert store.read_manifest()["config"]["outputs"] == "reduced"
    for it in (1, 2):  # the last iteration (3) stops before training: the polish follows
        info = store.stage_info(it, "train")
        n_train = info["n_train"]
        assert info["outputs"] == "reduced" and info["n_responses"] == 72
        # r: at least one direction, at most n - 1 (the rank of the centred training responses).
        assert 1 <= info["components"] <= n_train - 1
        assert 0.0 < info["captured"] <= 1.0
        # Fewer than 99.9 % only when capped at n - 1.
        assert info["captured"] >= 0.999 or info["components"] == n_train - 1
    predicted = store.read_table(2, "predict", "candidates")["predicted_error"].to_numpy()

    # Lose everything after iteration 2's train stage; the resume must rebuild the same reduced model
    # (stored hyper-parameters + the basis of the same training data) and arrive at the same summary.
    shutil.rmtree(store.root / "iteration=3")
    for stage in ("predict", "select"):
        shutil.rmtree(store.stage_dir(2, stage))
    (store.root / "summary.json").unlink()
    again = update.update_flow(config)
    np.testing.assert_allclose(store.read_table(2, "predict", "candidates")["predicted_error"].to_numpy(),
                               predicted, rtol=1e-8)
    assert again["fe_evaluations"] == summary["fe_evaluations"]
    assert again["iterations"] == summary["iterations"]
    assert again["parameters"] == pytest.approx(summary["parameters"], rel=1e-8, abs=1e-10)
    assert again["overall_error"] == pytest.approx(summary["overall_error"], rel=1e-8)
    assert "resumes" in store.read_manifest()


@pytest.mark.slow
def test_auto_at_the_benchmarks_72_responses_is_the_full_mrgp(reduced_config, prefect_harness):
    config = reduced_config
    full = update.update_flow(config.replace(run_id="full", outputs="full"))
    auto = update.update_flow(config.replace(run_id="auto"))
    assert config.outputs == "auto"  # the default
    assert _strip(auto) == _strip(full)
    store = RunStore(Path(config.runs_dir) / "auto")
    assert [store.stage_info(it, "train")["outputs"] for it in (1, 2)] == ["full", "full"]
    full_pred = RunStore(Path(config.runs_dir) / "full").read_table(2, "predict", "candidates")
    assert store.read_table(2, "predict", "candidates").equals(full_pred)


def test_bad_outputs_value_is_refused_naming_the_key(tmp_path, capsys):
    with pytest.raises(ConfigError, match="key 'outputs'"):
        UpdateConfig(outputs="half")
    cfg = tmp_path / "bad.toml"
    cfg.write_text('outputs = "pca"\n')
    assert update.main(["--config", str(cfg), "--runs-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert str(cfg) in err and "'outputs'" in err and "full, reduced, auto" in err
    assert not any(tmp_path.glob("runs*")) and not any(p.is_dir() for p in tmp_path.iterdir())
    with pytest.raises(SystemExit) as exc:
        update.main(["--outputs", "pca", "--runs-dir", str(tmp_path)])
    assert exc.value.code == 2
    assert "--outputs" in capsys.readouterr().err


def test_outputs_from_toml_and_command_line(tmp_path):
    cfg = tmp_path / "o.toml"
    cfg.write_text('outputs = "reduced"\n')
    assert load_config(cfg).outputs == "reduced"
    assert load_config(cfg, outputs="full").outputs == "full"
    assert load_config().outputs == "auto"


def test_a_run_started_before_the_key_existed_resumes(reduced_config, tmp_path):
    """Manifests written before ``outputs`` existed lack the key; such runs used the full MRGP (k = 72: auto)."""
    store = RunStore(Path(reduced_config.runs_dir) / "reduced")
    write_manifest(store, reduced_config)
    manifest = store.read_manifest()
    del manifest["config"]["outputs"]
    store.write_manifest(manifest)
    write_manifest(store, reduced_config)  # no ConfigError
    assert "resumes" in store.read_manifest()
