"""The one driver (tasks/driver.py, flows/drive.py), shown on the registry's smallest strategy, the coordinate
search of docs/architecture.md: its batches stored as the run record, a kill at a batch resumed with no FE run
made twice, its stages rerun through the same driver.

The cantilever of data/examples/cantilever_matrices (702 DOFs, about 10 ms per FE run), its measured data; five
rounds of the search (9 + 4 x 8 = 41 FE runs).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from flows import update
from flows.config import REPO, UpdateConfig
from tasks.fe_runs import read_fe_log
from tasks.runstore import RunStore

SETTINGS = dict(strategy="coordinate", model="data/examples/cantilever_matrices/model.toml",
                measured="data/examples/cantilever_matrices/measured.csv", max_fe_evaluations=41, n_jobs=1,
                intervals=False, coordinate_step=0.2)
TIMING_KEYS = {"wall_seconds", "run_folder", "run_id"}  # the time and the name of the run


def _run(args, env) -> subprocess.CompletedProcess:
    proc = subprocess.Popen([sys.executable, "-m", "flows.update", *args], cwd=REPO, env={**os.environ, **env},
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    out, _ = proc.communicate(timeout=300)
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    return subprocess.CompletedProcess(args, proc.returncode, out)


def _tables(root: Path) -> dict[str, pd.DataFrame]:
    return {str(p.relative_to(root)): pd.read_parquet(p).drop(columns=["seconds", "pid"], errors="ignore")
            for p in sorted(root.glob("iteration=*/stage=*/*.parquet")) if "sample=" not in p.name}


@pytest.fixture(scope="module")
def reference(tmp_path_factory, prefect_server) -> tuple[Path, Path]:
    """(config file, run folder) of one uninterrupted run of the coordinate search."""
    tmp = tmp_path_factory.mktemp("driver")
    cfg = tmp / "coordinate.toml"
    cfg.write_text("\n".join([f'runs_dir = "{tmp / "runs"}"'] + [f"{k} = {json.dumps(v)}" for k, v in
                                                                SETTINGS.items()]) + "\n")
    proc = _run(["--config", str(cfg), "--run-id", "reference"], prefect_server)
    assert proc.returncode == 0, proc.stdout[-3000:]
    return cfg, tmp / "runs" / "reference"


def test_the_strategys_batches_are_the_run_record(reference, in_memory_fe):
    """The run record holds every batch the strategy asked for, in its rounds, and its steps; the same strategy
    in memory (run_loop, FE runs made here) asks for the same points and reports the same point."""
    from flows.rerun import run_problem
    from strategies import registry
    from strategies.base import InMemory, run_loop
    from tasks import record
    from tasks.context import context

    _, root = reference
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


@pytest.mark.slow
def test_killed_at_a_batch_it_resumes_by_replay_with_no_fe_run_made_twice(reference, prefect_server):
    cfg, ref = reference
    victim = ref.parent / "victim"
    killed = _run(["--config", str(cfg), "--run-id", "victim"],
                  {**prefect_server, "MRGP_KILL_AT": "fe-result-written/iteration=3/sample=*@3"})
    assert killed.returncode == -signal.SIGKILL, killed.stdout[-3000:]
    assert not (victim / "summary.json").exists() and RunStore(victim).is_finished(2, "move")
    resumed = _run(["--config", str(cfg), "--run-id", "victim"], prefect_server)
    assert resumed.returncode == 0, resumed.stdout[-3000:]
    assert "FE runs read back from the run folder" in resumed.stdout and "finished earlier, read back" in resumed.stdout
    got, want = (json.loads((r / "summary.json").read_text()) for r in (victim, ref))
    assert {k: v for k, v in got.items() if k not in TIMING_KEYS} == {
        k: v for k, v in want.items() if k not in TIMING_KEYS}
    got_tables, want_tables = _tables(victim), _tables(ref)
    assert got_tables.keys() == want_tables.keys()
    for name, df in want_tables.items():
        pd.testing.assert_frame_equal(got_tables[name], df, obj=name)
    log = read_fe_log(victim)
    per_sample = Counter(e["sample_id"] for e in log if e["event"] in ("evaluated", "recovered"))
    assert max(per_sample.values()) == 1 and len(per_sample) == got["fe_evaluations"]
    assert [e["sample_id"] for e in log if e["event"] == "recovered"] == [19]  # 9 + 8 in rounds 1-2, the 3rd of 3


def test_its_stages_rerun_through_the_driver_beside_the_originals(reference):
    _, root = reference
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
