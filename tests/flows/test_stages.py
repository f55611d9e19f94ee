"""The stages of the paper's loop on small inputs, through the driver without Prefect (:class:`tasks.driver.Driver`):
iteration 1's FE stage and the steps that follow it."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, three_plate
from flows.problem import resolve
from strategies import registry
from tasks.driver import Driver
from tasks.io.measured import read_measured
from tasks.runstore import RunStore
from flows.config import REPO


@pytest.fixture
def measured():
    return read_measured(REPO / "data" / "benchmark" / "measured.csv")


def first_iteration(config, root=None) -> Driver:
    """A driver that has run iteration 1's FE stage (and the steps after it) of ``config``'s run."""
    store = RunStore(root or config.resolve(config.runs_dir) / config.run_id)
    driver = Driver(store, resolve(config), config, registry.get(config.strategy))
    driver.run_stage(driver.first())
    return driver


def run_first_stages(config, measured):
    return first_iteration(config).store


def loop_of(driver):
    """The paper loop of the adaptive strategy (the first part of its sequence)."""
    return driver.strategy.parts[0] if hasattr(driver.strategy, "parts") else driver.strategy


#: data/benchmark/measured.csv was written on one machine and is recomputed here on another:
#: BLAS kernels and summation order differ in the last bits. The direct complex LU is accurate to
#: about 1e-9 relative on the benchmark's smallest amplitudes (fe_core/frf.py, krylov_frf's rtol
#: note; README "Why the FRF is fast"), so that, not round-off on one CPU, is the tolerance.
STORED_VS_FRESH_RTOL = 1e-9


def test_measured_benchmark_file_is_the_model_at_the_actual_alpha(measured):
    Z = three_plate().frf(ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, method="direct")
    np.testing.assert_allclose(measured.amplitude, np.abs(Z), rtol=STORED_VS_FRESH_RTOL)


def test_first_samples_are_uniform_in_the_box_and_seeded(reduced_config, tmp_path):
    first_iteration(reduced_config, tmp_path / "a")
    X = RunStore(tmp_path / "a").read_table(1, "fe", "runs")
    assert len(X) == reduced_config.q and list(X["sample_id"]) == list(range(reduced_config.q))
    cols = [f"alpha_{i}" for i in range(1, 7)]
    assert np.all(X[cols].to_numpy() > -1) and np.all(X[cols].to_numpy() <= 1)
    first_iteration(reduced_config, tmp_path / "b")
    keep = ["sample_id", "round", *cols]
    pd.testing.assert_frame_equal(X[keep], RunStore(tmp_path / "b").read_table(1, "fe", "runs")[keep])


def test_fe_and_error_stages_match_a_direct_computation(reduced_config, measured):
    driver = first_iteration(reduced_config)
    store = driver.store
    samples = store.read_table(1, "fe", "runs")
    errors = samples
    model = three_plate()
    for _, row in samples.iloc[:3].iterrows():
        alpha = row[[f"alpha_{i}" for i in range(1, 7)]].to_numpy(float)
        amp = np.abs(model.frf(alpha, measured.frequencies_hz, method="direct"))
        expected = np.mean(np.abs(amp / measured.amplitude - 1))
        got = errors.loc[errors["sample_id"] == row["sample_id"], "overall_error"].item()
        assert got == pytest.approx(expected, rel=1e-7)
    loop = loop_of(driver)  # what the loop learns from: every successful run, its residual and overall error
    Y = np.array([loop.residual(Z) for Z in loop.Z])
    assert loop.X.shape == (reduced_config.q, 6) and Y.shape == (reduced_config.q, 72)
    np.testing.assert_allclose(np.mean(np.abs(Y), axis=-1), loop.E, rtol=1e-12)  # Eq. 6b
    np.testing.assert_allclose(loop.E, errors["overall_error"], rtol=1e-12)  # the run record's errors


def test_fe_stage_resumes_without_rerunning_finished_samples(reduced_config, measured):
    store = run_first_stages(reduced_config, measured)
    log_lines = (store.root / "fe_evaluations.jsonl").read_text().splitlines()
    assert len(log_lines) == reduced_config.q
    before = store.read_table(1, "fe", "responses")
    # Simulate a crash after three results were written: drop the stage record and four results.
    (store.stage_dir(1, "fe") / "_stage.json").unlink()
    for path in sorted(store.stage_dir(1, "fe").glob("sample=*.parquet"))[3:7]:
        path.unlink()
    assert not store.is_finished(1, "fe")
    assert first_iteration(reduced_config).store.stage_info(1, "fe")["ran_now"] == 4
    pd.testing.assert_frame_equal(before, store.read_table(1, "fe", "responses"))
    # A finished stage is read back, not recomputed (nor written again).
    record_file = (store.stage_dir(1, "fe") / "_stage.json").read_bytes()
    again = first_iteration(reduced_config)
    assert again.fe is None and (1, "fe") in again.closed
    assert (store.stage_dir(1, "fe") / "_stage.json").read_bytes() == record_file
    log = (store.root / "fe_evaluations.jsonl").read_text().splitlines()
    assert len(log) == reduced_config.q + 4


@pytest.mark.parametrize("stage, table", [("fe", "runs"), ("distribution", "distribution")])
def test_a_corrupted_stage_file_is_recomputed(stage, table, reduced_config, measured):
    store = run_first_stages(reduced_config, measured)
    path = store.path(1, stage, table)
    good = store.read_table(1, stage, table)
    path.write_bytes(path.read_bytes()[:100])
    assert not store.is_finished(1, stage)
    first_iteration(reduced_config)
    keep = [c for c in good.columns if c not in ("seconds", "pid")]
    pd.testing.assert_frame_equal(good[keep], store.read_table(1, stage, table)[keep])


def test_failed_fe_run_is_recorded_and_excluded(reduced_config, measured, monkeypatch, tmp_path):
    config = reduced_config.replace(run_id="failing")
    third = Driver(RunStore(tmp_path / "x"), resolve(config), config, registry.get(config.strategy)).first().points[2]
    real_frf = type(three_plate()).frf

    def flaky(self, alpha, freqs, *args, **kwargs):
        if alpha[0] == third[0]:
            raise np.linalg.LinAlgError("singular system")
        return real_frf(self, alpha, freqs, *args, **kwargs)

    monkeypatch.setattr(type(three_plate()), "frf", flaky)
    driver = first_iteration(config)
    store = driver.store
    errors = store.read_table(1, "fe", "runs")
    assert (errors["status"] == "failed").sum() == 1 and errors.loc[2, "status"] == "failed"
    assert "LinAlgError: singular system" in errors.loc[2, "message"]
    loop = loop_of(driver)  # the loop learns from the others only
    assert len(loop.ids) == reduced_config.q - 1 and 2 not in loop.ids and np.all(np.isfinite(loop.Y))
    log = [json.loads(x) for x in (store.root / "fe_evaluations.jsonl").read_text().splitlines()]
    assert sum(entry["status"] == "failed" for entry in log) == 1
