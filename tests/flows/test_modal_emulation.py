"""The paper loop's default emulation (``emulate = "modes"``) through the flow: its stages. (On the benchmark, at the
paper's size: tests/flows/test_modal_emulation_paper.py, a file of its own so that the two CI workers share it out.)"""

from __future__ import annotations

import numpy as np

from flows import update
from mrgp_core.modal_outputs import BAND_FACTOR
from flows.rerun import run_problem as resolve
from strategies import modal_emulation
from strategies.emulation import length_scales
from tasks.context import modal_training_set
from tasks.runstore import RunStore


def test_fe_runs_carry_the_modes_and_predict_adds_gauss_newton_points(reduced_config, two_iterations):
    config = reduced_config.replace(emulate="modes")
    store, cols = two_iterations(config)
    first = store.read_table(1, "fe", "runs")
    fe = store.read_table(1, "fe", "responses")
    model = resolve(config).model
    nominal = model.natural_frequencies(np.zeros(6), 6)
    n = int(np.sum(nominal < BAND_FACTOR * fe["frequency_hz"].max())) + 1
    assert n == 3 and [c for c in fe.columns if c.startswith("omega2_")] == ["omega2_1", "omega2_2", "omega2_3"]
    assert store.stage_info(1, "fe")["modes"] == store.stage_info(2, "fe")["modes"] == 3  # one count per run
    row = fe[fe["sample_id"] == first["sample_id"].iloc[0]]
    np.testing.assert_allclose(np.sqrt(row["omega2_1"].iloc[0]) / (2 * np.pi), nominal[0], rtol=1e-9)
    hyper = store.read_table(1, "train", "hyperparameters")
    assert sum(hyper["name"].str.startswith("length_scale_")) == 6  # one length scale per parameter
    cand = store.read_table(1, "predict", "candidates")
    assert config.w < len(cand) <= config.w + 2 * modal_emulation.GN_STARTS  # the Gauss-Newton end points
    assert np.all(np.isfinite(cand["predicted_error"]))
    problem = resolve(config)
    low, high = problem.lower, problem.upper
    assert np.all(cand[cols].to_numpy() >= low - 1e-12) and np.all(cand[cols].to_numpy() <= high + 1e-12)
    # a rerun of the predict stage from its stored inputs predicts what the run did
    out = update.rerun_stage(store.root, 1, "predict")
    again = store.read_table(1, out.name.split("=", 1)[1], "candidates")
    np.testing.assert_allclose(again["predicted_error"], cand["predicted_error"], rtol=1e-8)


def test_with_reduced_outputs_the_modes_keep_an_mrgp_of_their_own(reduced_config, prefect_harness):
    """A reduced basis of all 165 standardised outputs loses the modes to the 144 remainder values; the modes'
    own MRGP interpolates them."""
    import mrgp_core

    # 20 first runs: with the reduced config's 8 a basis of rank 7 still holds everything (measured: one basis
    # of all outputs misses a training run's frequency by 16 Hz at 20 runs, 2e-6 Hz at 8)
    config = reduced_config.replace(emulate="modes", outputs="reduced", polish=False, max_iterations=2, q=20,
                                    max_fe_evaluations=24)
    update.update_flow(config)
    store = RunStore(config.resolve(config.runs_dir) / config.run_id)
    info = store.stage_info(1, "train")
    assert info["modal"] == {"modes": 3, "outputs": 165, "modes_separate": True} and info["outputs"] == "full"
    problem = resolve(config)
    X, Y, _, lay = modal_training_set(store, problem, 1)
    hp = store.read_table(1, "train", "hyperparameters")
    hyper = dict(zip(hp["name"], hp["value"]))
    h = mrgp_core.Hyperparameters(length_scale=length_scales(hyper), nugget=float(hyper["nugget"]))
    mean = modal_emulation.Emulator(X, Y, lay, h, modal_emulation.separate_modes(config.outputs, lay)).mean(X)
    hz = np.sqrt(mean[:, :3]) / (2 * np.pi)
    np.testing.assert_allclose(hz, np.sqrt(Y[:, :3]) / (2 * np.pi), atol=0.5)  # Hz, at the training runs


def test_a_run_made_before_the_emulate_key_resumes_and_reruns_as_it_was_made(reduced_config, prefect_harness):
    import json

    import pytest

    from flows.config import ConfigError

    config = reduced_config.replace(emulate="errors", polish=False, max_iterations=2, max_fe_evaluations=12)
    update.update_flow(config)
    root = config.resolve(config.runs_dir) / config.run_id
    manifest = json.loads((root / "manifest.json").read_text())
    del manifest["config"]["emulate"]  # as written before the key existed
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ConfigError, match="emulate"):  # today's default would emulate the modes: refused
        update.update_flow(config.replace(emulate="modes"))
    assert update.update_flow(config)["fe_evaluations"] == 12  # resumed with what it was made with
    out = update.rerun_stage(root, 1, "train")  # the rerun emulates what the run did
    assert RunStore(root).stage_info(1, out.name.split("=", 1)[1])["n_train"] == 8
