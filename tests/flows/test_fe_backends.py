"""FE runs on a Dask cluster, and lost workers (Dask and loky) in the middle of the FE stage.

Every whole run here is ``python -m flows.update`` in a subprocess with the reduced
settings, compared with one loky run of the same settings: where the FE runs
execute must not change any result (summary.json apart from timings).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from distributed import Client, LocalCluster
from joblib import delayed

from flows import update
from flows.config import FE_BACKENDS, ConfigError, UpdateConfig
from tasks import fe_backends
from tasks.fe_backends import FEBackendError, run_unordered
from tasks.runstore import RunStore

TIMING_KEYS = {"wall_seconds", "run_folder", "run_id"}  # the time and the name of the run
FE_DELAY = "0.3"  # seconds per FE run where a worker is killed: the stage must still be running


def _write_config(path: Path, runs_dir: Path, settings) -> Path:
    lines = [f'runs_dir = "{runs_dir}"'] + [f"{k} = {json.dumps(v)}" for k, v in settings.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def _finish(proc: subprocess.Popen, timeout: float = 300) -> str:
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail(f"the run did not finish in {timeout} s:\n{out}")
    assert proc.returncode == 0, out
    return out


def _strip(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k not in TIMING_KEYS}


def _log(run: Path, stage: str | None = None) -> list[dict]:
    """FE runs made (``evaluated``) as logged in fe_evaluations.jsonl; of one stage if given."""
    path = run / "fe_evaluations.jsonl"
    entries = [json.loads(x) for x in path.read_text().splitlines() if x.strip()] if path.exists() else []
    entries = [e for e in entries if e.get("event", "evaluated") == "evaluated"]
    return entries if stage is None else [e for e in entries if e.get("stage", "fe") == stage]


def _kill_first_fe_worker(proc: subprocess.Popen, run: Path, timeout: float = 120) -> tuple[int, float, int]:
    """SIGKILL the process that made the run's first FE result, as soon as it is logged.

    Returns (killed pid, time of the kill, FE results logged before it).
    """
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        entries = _log(run, "fe")
        if entries:
            pid = int(entries[0]["pid"])
            assert pid != proc.pid, "the FE run was made in the flow's own process, not in a worker"
            os.kill(pid, signal.SIGKILL)
            return pid, time.time(), len(entries)
        time.sleep(0.02)
    out = proc.communicate()[0] if proc.poll() is not None else ""
    pytest.fail(f"no FE result appeared to pick a worker to kill\n{out}")


@pytest.fixture(scope="module")
def work(tmp_path_factory, reduced_settings_frozen) -> dict:
    root = tmp_path_factory.mktemp("fe-backends")
    runs = root / "runs"
    config = _write_config(root / "reduced.toml", runs, reduced_settings_frozen)
    return {"runs": runs, "config": config}


@pytest.fixture(scope="module")
def loky_reference(work, prefect_server, update_launcher) -> dict:
    """summary.json of the reduced run with the default backend (loky)."""
    _finish(update_launcher.start(["--config", str(work["config"]), "--run-id", "loky"], prefect_server))
    return json.loads((work["runs"] / "loky" / "summary.json").read_text())


# -- configuration ------------------------------------------------------------------------------
def test_backend_names_agree_between_config_and_runner():
    assert FE_BACKENDS == fe_backends.FE_BACKENDS


@pytest.mark.parametrize(("changes", "key"), [
    ({"fe_backend": "spark"}, "fe_backend"),
    ({"fe_backend": "dask"}, "dask_address"),
    ({"fe_backend": "dask", "dask_address": ""}, "dask_address"),
])
def test_bad_backend_settings_are_refused_naming_the_key(changes, key):
    with pytest.raises(ConfigError, match=f"key '{key}'"):
        UpdateConfig(**changes)


def test_unreachable_scheduler_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(fe_backends, "CONNECT_TIMEOUT", 1.0)
    address = "tcp://127.0.0.1:9"  # discard port: nothing listens there
    code = update.main(["--fe-backend", "dask", "--dask-address", address, "--runs-dir", str(tmp_path),
                        "--run-id", "nowhere"])
    err = capsys.readouterr().err
    assert code == 2
    assert address in err and "no Dask scheduler answered" in err and "dask scheduler" in err
    assert not (tmp_path / "nowhere").exists()


# -- Dask ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_dask_cluster_gives_the_loky_summary_and_runs_every_fe_run_on_its_workers(work, loky_reference,
                                                                                 prefect_server, update_launcher):
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        workers = set(client.run(os.getpid).values())
        proc = update_launcher.start(["--config", str(work["config"]), "--run-id", "dask", "--fe-backend", "dask",
                                       "--dask-address", cluster.scheduler_address], prefect_server)
        _finish(proc)
        assert set(client.run(os.getpid).values()) == workers  # no worker was replaced meanwhile
    run = work["runs"] / "dask"
    summary = json.loads((run / "summary.json").read_text())
    assert _strip(summary) == _strip(loky_reference)
    store = RunStore(run)
    pids = set()
    for k in range(1, summary["iterations"] + 1):
        pids |= set(store.read_table(k, "fe", "runs")["pid"])
    assert len(workers) == 2 and pids <= workers, f"FE runs made by {pids}, the cluster's workers are {workers}"
    assert proc.pid not in pids
    assert store.read_manifest()["config"]["fe_backend"] == "dask"
    assert len(_log(run)) == summary["fe_evaluations"]


@pytest.mark.slow
def test_killed_dask_worker_mid_stage_its_runs_are_rescheduled_and_the_result_is_the_same(
        work, loky_reference, prefect_server, update_launcher):
    run = work["runs"] / "dask-killed"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      env={"MRGP_FE_DELAY_SECONDS": FE_DELAY}) as cluster, Client(cluster) as client:
        before = set(client.run(os.getpid).values())
        proc = update_launcher.start(["--config", str(work["config"]), "--run-id", "dask-killed",
                                       "--fe-backend", "dask", "--dask-address", cluster.scheduler_address],
                      prefect_server)
        killed, t_kill, logged = _kill_first_fe_worker(proc, run)
        out = _finish(proc)
        client.wait_for_workers(2, timeout=60)
        after = set(client.run(os.getpid).values())
    assert killed in before
    assert logged < 8, "the FE stage of iteration 1 had finished before the kill"
    assert killed not in after and len(after) == 2, "the nanny did not replace the killed worker"
    summary = json.loads((run / "summary.json").read_text())
    assert _strip(summary) == _strip(loky_reference), out
    entries = _log(run)
    ids = [e["sample_id"] for e in entries]
    assert len(ids) == len(set(ids)) == summary["fe_evaluations"], "an FE run was lost or written twice"
    fe_stage = _log(run, "fe")  # (later stages may make FE runs in the flow's process)
    assert not [e for e in fe_stage if e["pid"] == killed and e["unix"] > t_kill + 1.0]
    assert {e["pid"] for e in fe_stage} <= before | after


# -- loky ---------------------------------------------------------------------------------------
@pytest.mark.slow
def test_killed_loky_worker_mid_stage_the_lost_runs_are_submitted_again_and_the_result_is_the_same(
        work, loky_reference, prefect_server, update_launcher):
    run = work["runs"] / "loky-killed"
    proc = update_launcher.start(["--config", str(work["config"]), "--run-id", "loky-killed", "--n-jobs", "2"],
                  {**prefect_server, "MRGP_FE_DELAY_SECONDS": FE_DELAY})
    killed, t_kill, logged = _kill_first_fe_worker(proc, run)
    out = _finish(proc)
    assert logged < 8, "the FE stage of iteration 1 had finished before the kill"
    assert "worker was lost (TerminatedWorkerError" in out and "again (retry 1 of" in out, out
    summary = json.loads((run / "summary.json").read_text())
    assert _strip(summary) == _strip(loky_reference), out
    entries = _log(run)
    ids = [e["sample_id"] for e in entries]
    assert len(ids) == len(set(ids)) == summary["fe_evaluations"], "an FE run was lost or written twice"
    assert not [e for e in _log(run, "fe") if e["pid"] == killed and e["unix"] > t_kill + 1.0]
    # Only the runs of the lost pool were made again: one stage call, no resume needed.
    assert "resumes" not in RunStore(run).read_manifest()


def test_a_call_that_always_kills_its_worker_fails_after_the_bounded_retries():
    messages = []

    class Logger:
        def warning(self, fmt, *args):
            messages.append(fmt % args)

    calls = {0: delayed(os.abort)(), 1: delayed(os.getpid)()}
    with pytest.raises(FEBackendError, match="workers were lost 2 times") as info:
        list(run_unordered(calls, key=lambda r: 1, n_jobs=2, retries=1, label="test", logger=Logger()))
    assert "still missing" in str(info.value) and "run again to resume" in str(info.value)
    assert len(messages) == 1 and "TerminatedWorkerError" in messages[0] and "retry 1 of 1" in messages[0]
