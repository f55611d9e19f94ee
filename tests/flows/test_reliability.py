"""Reliability: corrupt files, concurrent runs, full or read-only disks, numerical faults.

(Interruptions: ``test_kill_anywhere.py``; bad input: ``test_bad_input.py``.)
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import mrgp_core
from fe_core.benchmark import ALPHA_ACTUAL, three_plate
from flows import update
from flows.config import REPO
from flows.problem import resolve
from flows.run import write_manifest
from strategies import registry
from strategies.emulation import merge_duplicates, train_mrgp
from tasks import record
from tasks.driver import Driver
from tasks.fe_runs import read_fe_log
from tasks.io.measured import read_measured
from tasks.runlock import LOCK_NAME, RunLock, RunLockedError
from tasks.runstore import CorruptFileError, RunStore

MEASURED = REPO / "data" / "benchmark" / "measured.csv"


@pytest.fixture
def measured():
    return read_measured(MEASURED)


def first_stages(config, measured=None) -> RunStore:
    """The run folder after iteration 1's FE stage and the steps after it (the driver without Prefect)."""
    store = RunStore(config.resolve(config.runs_dir) / config.run_id)
    driver = Driver(store, resolve(config), config, registry.get(config.strategy))
    driver.run_stage(driver.first())
    return store


def _snapshot(root: Path) -> dict[str, str]:
    if not root.exists():
        return {}
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


# -- corrupt or partial files ------------------------------------------------------------------------


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])


def _wrong_schema(path: Path) -> None:
    pq.write_table(pa.table({"sample_id": [1, 2], "something": ["a", "b"]}), path)


@pytest.mark.parametrize(("damage", "why"), [(_truncate, "truncated or not a Parquet file"),
                                             (_wrong_schema, "wrong schema")])
def test_a_damaged_stage_file_is_never_read_and_its_stage_is_recomputed(
        damage, why, reduced_config, measured, caplog):
    store = first_stages(reduced_config, measured)
    path = store.path(1, "train", "hyperparameters")
    good = store.read_table(1, "train", "hyperparameters")
    damage(path)
    with pytest.raises(CorruptFileError, match=f"{path}: {why}"):
        store.read_table(1, "train", "hyperparameters")  # every read-back is checked, not only the resume
    from tasks.driver import StoredMemo

    with pytest.raises(CorruptFileError, match=str(path)):
        StoredMemo(store)._read(1, "train")  # the driver's read-back of a step too
    with caplog.at_level(logging.WARNING):
        assert not store.is_finished(1, "train")
    assert f"{path}: {why}" in caplog.text and "will be recomputed" in caplog.text
    first_stages(reduced_config)  # the resumed strategy computes the step again
    pd.testing.assert_frame_equal(good, store.read_table(1, "train", "hyperparameters"))


def test_a_stage_record_written_half_is_a_stage_not_finished(reduced_config, measured):
    store = first_stages(reduced_config, measured)
    stage_record = store.stage_dir(1, "distribution") / "_stage.json"
    stage_record.write_text(stage_record.read_text()[:20])
    assert not store.is_finished(1, "distribution")
    with pytest.raises(CorruptFileError, match="not part of a finished stage"):
        store.read_table(1, "distribution", "distribution")


def test_damaged_fe_results_are_set_aside_logged_and_evaluated_again(reduced_config, measured, caplog):
    store = first_stages(reduced_config, measured)
    before = store.read_table(1, "fe", "responses")
    (store.stage_dir(1, "fe") / "_stage.json").unlink()  # as if the run had stopped inside the FE stage
    truncated, other_alpha, wrong_schema = (store.sample_path(1, i) for i in (2, 4, 6))
    _truncate(truncated)
    df = pd.read_parquet(other_alpha)
    df["alpha_3"] += 0.25  # a valid file, but for other parameters than sample 4's
    df.to_parquet(other_alpha)
    _wrong_schema(wrong_schema)
    with caplog.at_level(logging.WARNING):
        first_stages(reduced_config)
    assert store.stage_info(1, "fe")["ran_now"] == 3
    for path, why in ((truncated, "unreadable"), (other_alpha, "computed for other parameters"), (wrong_schema, "wrong schema")):
        assert f"FE result {path}: {why}" in caplog.text
        assert len(list(path.parent.glob(path.name + ".corrupt-*"))) == 1  # kept for inspection
    pd.testing.assert_frame_equal(before, store.read_table(1, "fe", "responses"))
    log = read_fe_log(store.root)
    discarded = {e["sample_id"]: e["reason"] for e in log if e["event"] == "discarded"}
    assert sorted(discarded) == [2, 4, 6] and "other parameters" in discarded[4]
    evaluated = [e["sample_id"] for e in log if e["event"] == "evaluated"]
    # Each damaged sample ran once more after its result was set aside; no other sample ran again.
    assert sorted(evaluated) == sorted(list(range(reduced_config.q)) + [2, 4, 6])


def test_a_recomputed_stage_that_changed_invalidates_the_stages_built_on_it(tmp_path):
    store = RunStore(tmp_path / "run")
    order = ("a", "b", "c")
    for k in (1, 2):
        for stage in order:
            store.write_table(k, stage, stage, pd.DataFrame({"x": [k]}))
            assert store.finish(k, stage, [stage]) is False  # first time: nothing replaced
    (store.root / "summary.json").write_text("{}")
    store.write_table(1, "b", "b", pd.DataFrame({"x": [1]}))
    assert store.finish(1, "b", ["b"]) is False  # same content again: nothing is stale
    store.write_table(1, "b", "b", pd.DataFrame({"x": [99]}))
    assert store.finish(1, "b", ["b"]) is True
    removed = store.invalidate_after(1, "b", order)
    assert sorted(p.parent.name for p in removed) == ["stage=a", "stage=b", "stage=c", "stage=c"]
    assert store.is_finished(1, "a") and store.is_finished(1, "b")
    assert not any(store.is_finished(k, s) for k, s in ((1, "c"), (2, "a"), (2, "b"), (2, "c")))
    assert not (store.root / "summary.json").exists()


def test_temporary_files_of_a_killed_writer_are_removed_under_the_lock(tmp_path):
    store = RunStore(tmp_path / "run")
    store.write_table(1, "a", "a", pd.DataFrame({"x": [1]}))
    stale = store.stage_dir(1, "a") / ".a.parquet.abc123.tmp"
    stale.write_bytes(b"half")
    assert store.remove_temporaries() == [stale] and not stale.exists()
    assert store.path(1, "a", "a").exists()


# -- concurrent use --------------------------------------------------------------------------------

HOLDER = """
import sys, time
from tasks.runlock import RunLock
RunLock(sys.argv[1]).acquire()
print("locked", flush=True)
time.sleep(120)
"""


@contextmanager
def lock_held_by_another_process(root: Path):
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(root)], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=30)


def test_a_second_process_on_the_same_run_is_refused_naming_the_owner(tmp_path, capsys):
    runs = tmp_path / "runs"
    root = runs / "shared"
    with lock_held_by_another_process(root) as owner:
        with pytest.raises(RunLockedError) as info:
            RunLock(root).acquire()
        assert f"in use by pid {owner.pid} on host {socket.gethostname()}" in str(info.value)
        before = _snapshot(root)
        assert update.main(["--run-id", "shared", "--runs-dir", str(runs)]) == 2
        err = capsys.readouterr().err
        assert f"{root / LOCK_NAME}: run 'shared' is in use by pid {owner.pid}" in err
        assert _snapshot(root) == before  # the refused process wrote nothing


def test_a_lock_left_by_a_killed_process_is_stale_and_taken_over(tmp_path, caplog):
    root = tmp_path / "run"
    with lock_held_by_another_process(root) as owner:
        os.kill(owner.pid, signal.SIGKILL)
        owner.wait(timeout=30)
    record = json.loads((root / LOCK_NAME).read_text())
    assert record["pid"] == owner.pid  # the dead owner's record is still there
    with caplog.at_level(logging.WARNING):
        lock = RunLock(root).acquire()
    try:
        assert lock.stale_owner["pid"] == owner.pid
        assert f"stale lock of pid {owner.pid}" in caplog.text
        assert json.loads((root / LOCK_NAME).read_text())["pid"] == os.getpid()
        RunLock(root).acquire().release()  # re-entrant within one process
        assert (root / LOCK_NAME).exists()
    finally:
        lock.release()
    assert not (root / LOCK_NAME).exists()


# -- disk full, read-only run folder -------------------------------------------------------------------


@contextmanager
def read_only(path: Path):
    """Make ``path`` unwritable for real: permission bits, or for root (who ignores them) the immutable flag."""
    if os.geteuid() != 0:
        path.chmod(0o555)
        try:
            yield
        finally:
            path.chmod(0o755)
        return
    chattr = shutil.which("chattr")
    if chattr is None or subprocess.run([chattr, "+i", str(path)], capture_output=True).returncode != 0:
        pytest.skip("running as root on a filesystem without the immutable flag: cannot make a folder read-only")
    try:
        yield
    finally:
        subprocess.run([chattr, "-i", str(path)], check=True)


def test_a_read_only_runs_folder_is_refused_before_any_work(tmp_path, capsys):
    runs = tmp_path / "runs"
    runs.mkdir()
    with read_only(runs):
        assert update.main(["--run-id", "new", "--runs-dir", str(runs)]) == 2
    err = capsys.readouterr().err
    assert f"error: {runs}: cannot write into the runs folder" in err and "nothing was computed" in err
    assert "Traceback" not in err and not (runs / "new").exists()


def test_a_read_only_run_folder_is_refused_on_resume(tmp_path, capsys):
    runs = tmp_path / "runs"
    root = runs / "old"
    config = update.load_config(None, runs_dir=str(runs), run_id="old", true_parameters=list(ALPHA_ACTUAL))
    write_manifest(RunStore(root), config)
    before = _snapshot(root)
    with read_only(root):
        assert update.main(["--run-id", "old", "--runs-dir", str(runs)]) == 2
    err = capsys.readouterr().err
    assert f"error: {root}: cannot write into the run folder" in err
    assert _snapshot(root) == before


def test_too_little_free_space_is_refused_before_any_work(tmp_path, capsys):
    runs = tmp_path / "runs"
    free_mb = shutil.disk_usage(tmp_path).free / 1e6
    cfg = tmp_path / "c.toml"
    cfg.write_text(f"min_free_mb = {free_mb * 1000:.0f}\n")  # the real free space, a thousand times over
    assert update.main(["--config", str(cfg), "--run-id", "big", "--runs-dir", str(runs)]) == 2
    err = capsys.readouterr().err
    assert f"error: {runs}: " in err and "MB free, the run needs at least" in err and "min_free_mb" in err
    assert not (runs / "big").exists()


def test_the_default_space_requirement_follows_the_run_size(tmp_path, capsys, monkeypatch):
    from flows import preflight

    runs = tmp_path / "runs"
    small = update.load_config(None, runs_dir=str(runs), run_id="x", w=100, q=10, max_fe_evaluations=20, polish_max_fe=2)
    big = small.replace(w=100_000, max_fe_evaluations=2000)
    assert preflight.expected_output_mb(big, 72, 6) > 20 * preflight.expected_output_mb(small, 72, 6)
    need_mb = 2 * preflight.expected_output_mb(update.load_config(None), 72, 6)
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(preflight.shutil, "disk_usage",
                        lambda p: usage._replace(free=int(0.5 * need_mb * 1e6)))
    assert update.main(["--run-id", "default", "--runs-dir", str(runs)]) == 2
    assert f"the run needs at least {need_mb:.0f} MB" in capsys.readouterr().err
    assert not (runs / "default").exists()


# -- numerical faults -----------------------------------------------------------------------------------


def test_duplicated_samples_are_merged_so_the_mrgp_is_fitted_as_without_them(rng):
    X = rng.uniform(-1, 1, (30, 6))
    W = rng.normal(size=(6, 72))
    Y = np.sin(X @ W * 0.8) + 0.3 * (X @ W * 0.8) ** 2
    Xd = np.vstack([X, X[:5], X[5:8] + 1e-13])
    Yd = np.vstack([Y, Y[:5], Y[5:8]])
    Xm, Ym = merge_duplicates(Xd, Yd)
    assert Xm.shape == X.shape
    np.testing.assert_allclose(Xm, X, atol=1e-12)
    np.testing.assert_allclose(Ym, Y)
    alone = mrgp_core.fit(X, Y, "gradient", rng=np.random.default_rng(1)).hyperparameters
    hyper, _ = train_mrgp(Xd, Yd, "gradient", np.random.default_rng(1), None)
    assert hyper["length_scale_1"] == pytest.approx(float(np.atleast_1d(alone.length_scale)[0]), rel=1e-6)
    # Without the merge the duplicates make Sigma singular but for its jitter, and the likelihood
    # drives the length scale towards zero (the MRGP degenerates to its trend): the fault being fixed.
    raw = mrgp_core.fit(Xd, Yd, "gradient", rng=np.random.default_rng(1)).hyperparameters
    assert float(np.atleast_1d(raw.length_scale)[0]) < 1e-3 * hyper["length_scale_1"]


def test_the_flow_goes_on_through_duplicates_failed_fe_runs_and_constant_responses(
        reduced_config, measured, monkeypatch, prefect_server):
    """End to end: iteration 1 holds an exact and a near duplicate, a sample at the domain edge
    (alpha_2 = -1: zero stiffness, the model refuses it), one whose FE solve fails (singular
    system), and one response that is the same for every sample."""
    from prefect.settings import PREFECT_API_URL, temporary_settings

    config = reduced_config.replace(run_id="faults", max_fe_evaluations=30, q=14)  # iterations 1 (14 runs), 2, 3
    store = RunStore(config.resolve(config.runs_dir) / config.run_id)
    rng = np.random.default_rng(5)
    X = rng.uniform(-0.9, 1.0, (14, 6))
    X[1] = X[0]
    X[2] = X[0] + 1e-13
    X[3, 1] = -1.0
    singular = X[4].copy()
    import strategies.paper

    monkeypatch.setattr(strategies.paper, "first_samples", lambda *args: X.copy())  # the loop's first batch

    cls = type(three_plate())
    real_frf = cls.frf

    def faulty_frf(self, alpha, freqs, *args, **kwargs):
        if np.array_equal(np.asarray(alpha, float), singular):
            raise np.linalg.LinAlgError("singular matrix in the factorisation of K")
        Z = real_frf(self, alpha, freqs, *args, **kwargs)
        Z[0, 0] = 2e-6 + 1e-6j  # sensor 1 at the first frequency: the same for every sample
        return Z

    monkeypatch.setattr(cls, "frf", faulty_frf)
    with temporary_settings({PREFECT_API_URL: prefect_server["PREFECT_API_URL"]}):
        summary = update.update_flow(config)

    runs = store.read_table(1, "fe", "runs").set_index("sample_id")
    np.testing.assert_array_equal(runs[[f"alpha_{i}" for i in range(1, 7)]].to_numpy(), X)
    assert list(runs.index[runs["status"] != "ok"]) == [3, 4]
    messages = runs["message"]
    assert "alpha_2 = -1.0 is outside the valid domain" in messages[3]
    assert "LinAlgError: singular matrix" in messages[4]
    log = read_fe_log(store.root)
    assert sorted(e["sample_id"] for e in log if e.get("status") == "failed") == [3, 4]
    assert summary["iterations"] == 3
    every = record.fe_runs(store, 3)
    ok = every[(every["status"] == "ok") & (every["stage"] == "fe")]
    assert 3 not in set(ok["sample_id"]) and 4 not in set(ok["sample_id"])
    data = resolve(config).data
    p, n = data.amplitude.shape
    Yt = np.array([data.residuals(record.grid(record.responses(store, 3, [sid]), p, n, 6)[0])
                   for sid in ok["sample_id"]])
    assert np.all(np.isfinite(Yt))
    assert np.ptp(Yt[:, 0]) == 0.0  # the constant response reached the loop's training data
    hyper = store.read_table(1, "train", "hyperparameters").set_index("name")["value"]
    assert hyper["length_scale_1"] > 1e-3  # not collapsed by the duplicates
    assert np.isfinite(summary["overall_error"]) and summary["fe_evaluations"] >= 14
    assert summary["best_sample_id"] not in (3, 4)
