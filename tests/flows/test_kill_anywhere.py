"""Kill anywhere: SIGKILL the flow at many named points, resume each time, and get the same run.

One run (``victim``) is killed in turn at every point of ``KILL_POINTS`` (the
polish's among them, in the order the run passes them), each time by
``MRGP_KILL_AT`` (see ``tasks/faults.py``: the process sends itself SIGKILL
there) and then started again with the same ``--run-id``; after the last kill
it runs to the end. One uninterrupted run (``reference``) of the
same settings, shared by the tests of the module, is the yardstick. Then:

* both ``summary.json`` are equal apart from timings and the run's id and folder;
* every Parquet table of every stage is equal (apart from FE timing columns);
* ``fe_evaluations.jsonl`` holds exactly one FE run per sample, for every
  sample: none evaluated twice, none lost (an FE run whose result the kill
  stopped before it reached the disk is run again: its first run left no
  result, so it is not counted twice);
* no temporary file and no lock file is left behind.
"""

from __future__ import annotations

import json
import os
import signal
import time
from collections import Counter
from pathlib import Path

import pandas as pd
import pytest

from tasks.fe_runs import read_fe_log
from tasks.runstore import RunStore

TIMING_KEYS = {"wall_seconds", "run_folder", "run_id"}  # the time and the name of the run

#: (point pattern for MRGP_KILL_AT, what it interrupts), in the order the run passes them, each a distinct place in
#: the code: tasks/runstore.py's atomic write and stage record, tasks/fe_runs.py's FE result and its log line, the
#: driver's step and FE-stage records, the summary. Every step's tables go through one write (tasks/driver.py): a
#: kill in iteration 2's select.parquet write repeated predict's point (every later resume replays iteration 1).
#: The reduced run has 3 iterations: samples 0-7 in iteration 1, 8-11 in iteration 2, 12-15 in iteration 3 (which
#: stops after its FE runs), then the polish (stage=polish of iteration 3) with FE runs 16-22, then the summary. An
#: iteration's FE stage is recorded when the strategy moves on: after the steps its results lead to
#: (distribution .. select).
KILL_POINTS = [
    ("before-rename:*/iteration=1/stage=fe/sample=000003.parquet", "inside fe: FE result written, not renamed"),
    ("fe-result-written/iteration=1/sample=5", "inside fe: FE result on disk, log line not written"),
    ("before-rename:*/iteration=1/stage=distribution/_stage.json", "inside distribution: record half-written"),
    ("tables-written/iteration=1/stage=train", "inside train: hyper-parameters written, record not"),
    ("before-rename:*/iteration=1/stage=predict/candidates.parquet", "inside predict: during the Parquet write"),
    ("stage-finished/iteration=1/stage=select", "after select, before the FE stage's record"),
    ("tables-written/iteration=1/stage=fe", "the FE stage's tables written, its record not"),
    # Inside the polish. These were a chain of their own, whose first process computed iterations 1-3 again
    # (about 40 s of the suite); in this chain the processes before them replay those iterations from disk.
    ("before-rename:*/iteration=3/stage=polish/sample=000018.parquet", "inside polish: an FE result's write"),
    ("polish-result-written/iteration=3/sample=20", "inside polish: an FE result written, not yet logged"),
    ("tables-written/iteration=3/stage=polish", "inside polish: tables written, record not"),
    ("before-rename:*/summary.json", "during the summary write, after the polish"),
]


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory, reduced_settings_frozen, prefect_server, update_launcher) -> tuple[Path, Path]:
    """(config file, run folder) of one uninterrupted reduced run, shared by the tests of this module."""
    tmp = tmp_path_factory.mktemp("kill-anywhere")
    cfg = _config(tmp, tmp / "runs", dict(reduced_settings_frozen))
    proc = update_launcher.start(["--config", str(cfg), "--run-id", "reference"], prefect_server)
    out = _finish(proc)
    assert proc.returncode == 0, out[-3000:]
    return cfg, tmp / "runs" / "reference"


def _config(tmp_path: Path, runs: Path, settings: dict) -> Path:
    path = tmp_path / "reduced.toml"
    path.write_text("\n".join([f'runs_dir = "{runs}"'] + [f"{k} = {json.dumps(v)}" for k, v in settings.items()]))
    return path


def _finish(proc) -> str:
    out, _ = proc.communicate(timeout=300)
    try:  # anything the killed process left in its session (nothing expected: n_jobs = 1)
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    return out


def _tables(root: Path) -> dict[str, pd.DataFrame]:
    out = {}
    for path in sorted(root.glob("iteration=*/stage=*/*.parquet")):
        if "sample=" in path.name:
            continue
        df = pd.read_parquet(path).drop(columns=["seconds", "pid"], errors="ignore")
        out[str(path.relative_to(root))] = df
    return out


def _kill_chain(command, cfg: Path, victim: Path, points, env) -> str:
    """Kill the run at each point in turn, then let it finish; returns the last run's output."""
    for point, what in points:
        proc = command.start(["--config", str(cfg), "--run-id", victim.name], {**env, "MRGP_KILL_AT": point})
        out = _finish(proc)
        assert proc.returncode == -signal.SIGKILL, f"not killed at {point} ({what}):\n{out[-3000:]}"
        if point.startswith("before-rename:"):  # the kill came between the write and the rename
            name = point.rsplit("/", 1)[1]
            assert list(victim.rglob(f".{name}.*.tmp")), f"no temporary {name} left at {point}"
        assert point == points[-1][0] or not (victim / "summary.json").exists()
    proc = command.start(["--config", str(cfg), "--run-id", victim.name], env)
    out = _finish(proc)
    assert proc.returncode == 0, out[-3000:]
    assert "stale lock" in out  # the killed run's lock was detected and taken over
    return out


def _assert_same_run(victim: Path, ref_root: Path, recovered: list[int]) -> None:
    got = json.loads((victim / "summary.json").read_text())
    want = json.loads((ref_root / "summary.json").read_text())
    assert {k: v for k, v in got.items() if k not in TIMING_KEYS} == {
        k: v for k, v in want.items() if k not in TIMING_KEYS}

    got_tables, want_tables = _tables(victim), _tables(ref_root)
    assert got_tables.keys() == want_tables.keys()
    for name, df in want_tables.items():
        pd.testing.assert_frame_equal(got_tables[name], df, obj=name)

    log = read_fe_log(victim)
    runs_per_sample = Counter((e["iteration"], e["sample_id"]) for e in log if e["event"] in ("evaluated", "recovered"))
    assert not [e for e in log if e["event"] == "discarded"]
    assert max(runs_per_sample.values()) == 1, "an FE sample was evaluated twice"
    store = RunStore(victim)
    expected = {(k, int(sid)) for k in (1, 2, 3) for sid in store.read_table(k, "fe", "runs")["sample_id"]}
    expected |= {(3, int(sid)) for sid in store.read_table(3, "polish", "runs")["sample_id"]}
    assert set(runs_per_sample) == expected, "an FE sample was lost"
    assert len(expected) == got["fe_evaluations"] == 16 + got["polish"]["n"]
    # A kill between an FE result and its log line is repaired from the result on disk.
    assert [e["sample_id"] for e in log if e["event"] == "recovered"] == recovered
    assert not list(victim.rglob("*.tmp")) and not (victim / "run.lock").exists()


@pytest.mark.slow
def test_kill_at_every_point_then_resume_gives_the_uninterrupted_run(reference_run, prefect_server, update_launcher):
    cfg, ref_root = reference_run
    victim = ref_root.parent / "victim"
    _kill_chain(update_launcher, cfg, victim, KILL_POINTS, prefect_server)
    assert 16 + json.loads((victim / "summary.json").read_text())["polish"]["n"] > 20  # 18, 20 inside the polish
    # Sample 5 of iteration 1 and sample 20 of the polish: each killed between its result and its log line.
    _assert_same_run(victim, ref_root, recovered=[5, 20])
    assert len(RunStore(victim).read_manifest()["resumes"]) == len(KILL_POINTS)


@pytest.mark.slow
def test_sigkill_from_outside_during_the_fe_stage_of_iteration_2_then_resume_gives_the_same_run(reference_run,
                                                                                                prefect_server,
                                                                                                update_launcher):
    """A kill at no named point: the process group killed from outside while an FE run of iteration 2 is under way
    (each slowed by 0.4 s, so that the kill lands inside the stage), then resumed: the same summary, each sample
    evaluated once."""
    cfg, ref_root = reference_run
    victim_root = ref_root.parent / "victim-outside"
    victim = update_launcher.start(["--config", str(cfg), "--run-id", victim_root.name],
                    {**prefect_server, "MRGP_FE_DELAY_SECONDS": "0.4"})
    log_path = victim_root / "fe_evaluations.jsonl"
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
    assert not (victim_root / "summary.json").exists()
    assert not RunStore(victim_root).is_finished(2, "fe")

    resumed = update_launcher.start(["--config", str(cfg), "--run-id", victim_root.name], prefect_server)
    out = _finish(resumed)
    assert resumed.returncode == 0, out[-3000:]

    reference = json.loads((ref_root / "summary.json").read_text())
    again = json.loads((victim_root / "summary.json").read_text())
    assert {k: v for k, v in again.items() if k not in TIMING_KEYS} == {
        k: v for k, v in reference.items() if k not in TIMING_KEYS}
    entries = [json.loads(x) for x in log_path.read_text().splitlines()]
    ids = [e["sample_id"] for e in entries]
    assert len(ids) == len(set(ids)) == again["fe_evaluations"], "an FE sample was evaluated twice or lost"
    assert "resumes" in RunStore(victim_root).read_manifest()
