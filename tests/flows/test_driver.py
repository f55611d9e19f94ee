"""The one driver (tasks/driver.py, flows/drive.py), shown on the registry's smallest strategy, the coordinate
search of docs/architecture.md: its batches stored as the run record, its stages rerun through the same driver.

The cantilever of data/examples/cantilever_matrices (702 DOFs, about 10 ms per FE run), its measured data; five
rounds of the search (9 + 4 x 8 = 41 FE runs).

A kill at a batch and its resume by replay go through the same driver for every strategy; they are shown where
the replay differs: tests/flows/test_kill_anywhere.py (single-round FE stages and steps, as here: a kill between an
FE result and its log line, at every record write, from outside; the polish's own replay) and
tests/flows/test_hybrid_flow.py (FE stages of several rounds, with Jacobians). A kill of this strategy at its
third batch repeated the first of these.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flows import update
from flows.config import UpdateConfig
from tasks.fe_runs import read_fe_log
from tasks.runstore import RunStore

SETTINGS = dict(strategy="coordinate", model="data/examples/cantilever_matrices/model.toml",
                measured="data/examples/cantilever_matrices/measured.csv", max_fe_evaluations=41, n_jobs=1,
                intervals=False, coordinate_step=0.2)


@pytest.fixture(scope="module")
def reference(tmp_path_factory, prefect_harness) -> Path:
    """The run folder of one run of the coordinate search, made in this process."""
    runs = tmp_path_factory.mktemp("driver") / "runs"
    summary = update.update_flow(UpdateConfig(run_id="reference", runs_dir=str(runs), **SETTINGS))
    assert summary["fe_evaluations"] == 41
    return runs / "reference"


def test_the_strategys_batches_are_the_run_record(reference, in_memory_fe):
    """The run record holds every batch the strategy asked for, in its rounds, and its steps; the same strategy
    in memory (run_loop, FE runs made here) asks for the same points and reports the same point."""
    from flows.rerun import run_problem
    from strategies import registry
    from strategies.base import InMemory, run_loop
    from tasks import record
    from tasks.context import context

    root = reference
    summary = json.loads((root / "summary.json").read_text())
    store = RunStore(root)
    config = UpdateConfig(**{**SETTINGS, "run_id": "reference"})
    problem = run_problem(config)
    memo = InMemory()
    strategy = registry.get("coordinate").make(context(problem, memo), config)
    batches = []
    evaluate = in_memory_fe(problem)
    run_loop(strategy, lambda batch: batches.append(batch) or evaluate(batch))
    runs = record.fe_runs(store)
    assert len(runs) == summary["fe_evaluations"] == sum(len(b) for b in batches) == 41
    assert summary["iterations"] == len(batches) == 5 and list(runs["iteration"].unique()) == [1, 2, 3, 4, 5]
    for k, batch in enumerate(batches, start=1):
        stored = runs[runs["iteration"] == k]
        assert set(stored["stage"]) == {"fe"} and set(stored["round"]) == {1}
        np.testing.assert_array_equal(stored[problem.names].to_numpy(), batch.points)
        move = store.read_table(k, "move", "move")["x"].to_numpy()
        np.testing.assert_array_equal(move, memo.steps[(k, "move")].table("move")["x"])
    assert summary["best_sample_id"] == strategy.report().candidates[0]
    assert summary["stop_reason"] == strategy.report().stop_reason
    assert summary["overall_error"] < runs.loc[runs["sample_id"] == 0, "overall_error"].item()  # it moved


def test_its_stages_rerun_through_the_driver_beside_the_originals(reference):
    root = reference
    store = RunStore(root)
    log = read_fe_log(root)
    out = update.rerun_stage(root, 2, "move")  # a step: replayed up to it, computed again
    assert out.parent == store.stage_dir(2, "move").parent and out.name.startswith("stage=move.rerun-")
    name = out.name.split("=", 1)[1]
    pd.testing.assert_frame_equal(store.read_table(2, name, "move"), store.read_table(2, "move", "move"))
    out = update.rerun_stage(root, 3, "fe")  # an FE stage: its stored FE runs borrowed where the points agree
    name = out.name.split("=", 1)[1]
    keep = ["sample_id", "round", "jacobian", "status", "overall_error", "alpha_1", "alpha_2", "alpha_3", "alpha_4"]
    pd.testing.assert_frame_equal(store.read_table(3, name, "runs")[keep], store.read_table(3, "fe", "runs")[keep])
    assert read_fe_log(root) == log  # no FE run made, nothing logged
    with pytest.raises(update.ConfigError, match="cannot be rerun"):
        update.rerun_stage(root, 2, "train")


def test_a_run_folder_of_the_earlier_layout_is_refused_on_resume(tmp_path, capsys):
    """Run folders made before the one driver (record_version 2: other stages, no step digests) are not replayed."""
    from flows.run import write_manifest

    runs = tmp_path / "runs"
    store = RunStore(runs / "old")
    write_manifest(store, update.load_config(None, runs_dir=str(runs), run_id="old"))
    manifest = store.read_manifest()
    assert manifest["record_version"] == 3
    store.write_manifest({**manifest, "record_version": 2})
    assert update.main(["--run-id", "old", "--runs-dir", str(runs)]) == 2
    err = capsys.readouterr().err
    assert f"{store.manifest_path}: run 'old' was made by an earlier version of this tool" in err
