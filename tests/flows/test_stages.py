"""Each stage's logic on small inputs, through ``task.fn`` (no Prefect run)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, three_plate
from flows.problem import resolve
from tasks import paper
from tasks.io.measured import read_measured
from tasks.runstore import RunStore
from flows.config import REPO


@pytest.fixture
def measured():
    return read_measured(REPO / "data" / "benchmark" / "measured.csv")


def run_first_stages(config, measured):
    root = str(RunStore(config.resolve(config.runs_dir) / config.run_id).root)
    problem = resolve(config)
    paper.samples_task.fn(root, problem, config, 1)
    paper.fe_task.fn(root, problem, config, 1)
    paper.errors_task.fn(root, problem, config, 1)
    return RunStore(root)


#: data/benchmark/measured.csv was written on one machine and is recomputed here on another:
#: BLAS kernels and summation order differ in the last bits. The direct complex LU is accurate to
#: about 1e-9 relative on the benchmark's smallest amplitudes (fe_core/frf.py, krylov_frf's rtol
#: note; README "Why the FRF is fast"), so that, not round-off on one CPU, is the tolerance.
STORED_VS_FRESH_RTOL = 1e-9


def test_measured_benchmark_file_is_the_model_at_the_actual_alpha(measured):
    Z = three_plate().frf(ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ, method="direct")
    np.testing.assert_allclose(measured.amplitude, np.abs(Z), rtol=STORED_VS_FRESH_RTOL)


def test_first_samples_are_uniform_in_the_box_and_seeded(reduced_config, tmp_path):
    root = str(tmp_path / "a")
    paper.samples_task.fn(root, resolve(reduced_config), reduced_config, 1)
    X = RunStore(root).read_table(1, "samples")
    assert len(X) == reduced_config.q and list(X["sample_id"]) == list(range(reduced_config.q))
    cols = [f"alpha_{i}" for i in range(1, 7)]
    assert np.all(X[cols].to_numpy() > -1) and np.all(X[cols].to_numpy() <= 1)
    paper.samples_task.fn(str(tmp_path / "b"), resolve(reduced_config), reduced_config, 1)
    pd.testing.assert_frame_equal(X, RunStore(tmp_path / "b").read_table(1, "samples"))


def test_fe_and_error_stages_match_a_direct_computation(reduced_config, measured):
    store = run_first_stages(reduced_config, measured)
    samples = store.read_table(1, "samples")
    errors = store.read_table(1, "errors", "errors")
    model = three_plate()
    for _, row in samples.iloc[:3].iterrows():
        alpha = row[[f"alpha_{i}" for i in range(1, 7)]].to_numpy(float)
        amp = np.abs(model.frf(alpha, measured.frequencies_hz, method="direct"))
        expected = np.mean(np.abs(amp / measured.amplitude - 1))
        got = errors.loc[errors["sample_id"] == row["sample_id"], "overall_error"].item()
        assert got == pytest.approx(expected, rel=1e-7)
    ids, X, Y, E = paper.training_data(store, 1)
    assert X.shape == (reduced_config.q, 6) and Y.shape == (reduced_config.q, 72)
    np.testing.assert_allclose(np.mean(np.abs(Y), axis=-1), E)  # Eq. 6b


def test_fe_stage_resumes_without_rerunning_finished_samples(reduced_config, measured):
    store = run_first_stages(reduced_config, measured)
    log_lines = (store.root / "fe_evaluations.jsonl").read_text().splitlines()
    assert len(log_lines) == reduced_config.q
    before = store.read_table(1, "fe", "responses")
    # Simulate a crash after three results were written: drop the stage record and four results.
    (store.stage_dir(1, "fe") / "_stage.json").unlink()
    for path in sorted(store.stage_dir(1, "fe").glob("sample=*.parquet"))[3:7]:
        path.unlink()
    ran = paper.fe_task.fn(str(store.root), resolve(reduced_config), reduced_config, 1)
    assert ran == 4
    pd.testing.assert_frame_equal(before, store.read_table(1, "fe", "responses"))
    # A finished stage is read back, not recomputed.
    assert paper.fe_task.fn(str(store.root), resolve(reduced_config), reduced_config, 1) == 0


def test_a_corrupted_stage_file_is_recomputed(reduced_config, measured):
    store = run_first_stages(reduced_config, measured)
    path = store.path(1, "errors", "errors")
    good = store.read_table(1, "errors", "errors")
    path.write_bytes(path.read_bytes()[:100])
    assert not store.is_finished(1, "errors")
    paper.errors_task.fn(str(store.root), resolve(reduced_config), reduced_config, 1)
    pd.testing.assert_frame_equal(good, store.read_table(1, "errors", "errors"))


def test_failed_fe_run_is_recorded_and_excluded(reduced_config, measured, monkeypatch):
    store = RunStore(reduced_config.resolve(reduced_config.runs_dir) / "failing")
    root = str(store.root)
    paper.samples_task.fn(root, resolve(reduced_config), reduced_config, 1)
    real_frf = type(three_plate()).frf

    def flaky(self, alpha, freqs, *args, **kwargs):
        if alpha[0] == store.read_table(1, "samples")["alpha_1"].iloc[2]:
            raise np.linalg.LinAlgError("singular system")
        return real_frf(self, alpha, freqs, *args, **kwargs)

    monkeypatch.setattr(type(three_plate()), "frf", flaky)
    paper.fe_task.fn(root, resolve(reduced_config), reduced_config, 1)
    info = paper.errors_task.fn(root, resolve(reduced_config), reduced_config, 1)
    assert info["failed"] == 1
    errors = store.read_table(1, "errors", "errors")
    assert (errors["status"] == "failed").sum() == 1
    ids, X, Y, E = paper.training_data(store, 1)
    assert len(ids) == reduced_config.q - 1 and np.all(np.isfinite(Y))
    log = [json.loads(x) for x in (store.root / "fe_evaluations.jsonl").read_text().splitlines()]
    assert sum(entry["status"] == "failed" for entry in log) == 1
