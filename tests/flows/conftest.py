"""Fixtures for flow tests: a reduced configuration that runs in seconds."""

from __future__ import annotations

from pathlib import Path

import pytest

from flows.config import UpdateConfig

# 16 FE runs for the MRGP loop, then 7 for the polish (one Jacobian of 6 parameters and one step);
# no intervals (up to 3 exact Jacobians, seconds per run: tests/flows/test_intervals_stage.py turns them on).
# The adaptive strategy with the paper's loop (+ polish): these tests are about its stages. The hybrid default
# (tests/flows/test_hybrid_flow.py) has its own.
REDUCED = dict(q=8, w=400, s=4, z=6, max_iterations=3, max_fe_evaluations=23, polish_max_fe=7, threshold=1e-6,
               n_jobs=1, trainer="gradient", seed=11, intervals=False, strategy="adaptive")


@pytest.fixture
def reduced_config(tmp_path) -> UpdateConfig:
    return UpdateConfig(run_id="reduced", runs_dir=str(tmp_path / "runs"), **REDUCED)


@pytest.fixture
def reduced_settings() -> dict:
    return dict(REDUCED)


@pytest.fixture(scope="session")
def reduced_settings_frozen():
    """REDUCED, read-only, for module- and session-scoped fixtures (e.g. one reference run per module)."""
    from types import MappingProxyType

    return MappingProxyType(dict(REDUCED))


@pytest.fixture(scope="session")
def prefect_harness():
    """One Prefect test server for the whole session (Prefect's documented pattern).

    Each ``prefect_test_harness()`` starts a server and a database of its own, 5-20 s on a
    busy 2-core machine; the flow tests share one instead of starting one per module.

    The flows run here without Prefect's flow-run heartbeats (``PREFECT_FLOWS_HEARTBEAT_FREQUENCY``, 180 s by
    default; an environment variable cannot turn them off, a settings context can): each flow run's heartbeat
    thread sleeps in steps of 1 s and the flow run waits for it at its end, about 0.5 s per flow and subflow run
    (a reduced update is 4: ~2 s of ~9 s), for an event no test reads (the zombie detection of deployments).

    The server runs without the services that record the events of task runs, persist events and evaluate
    automations' triggers (the harness passes its settings to the server's process): they took half of its CPU,
    1.0 of 2.0 s per reduced update (measured on 812e15c), for tables no test reads here. The UI test
    (tests/flows/test_prefect_ui.py) starts a server of its own, with every service.
    """
    from prefect.settings import (PREFECT_API_URL, PREFECT_FLOWS_HEARTBEAT_FREQUENCY,
                                  PREFECT_SERVER_SERVICES_EVENT_PERSISTER_ENABLED,
                                  PREFECT_SERVER_SERVICES_TASK_RUN_RECORDER_ENABLED,
                                  PREFECT_SERVER_SERVICES_TRIGGERS_ENABLED, temporary_settings)
    from prefect.testing.utilities import prefect_test_harness

    quiet = {PREFECT_SERVER_SERVICES_TASK_RUN_RECORDER_ENABLED: False,
             PREFECT_SERVER_SERVICES_EVENT_PERSISTER_ENABLED: False, PREFECT_SERVER_SERVICES_TRIGGERS_ENABLED: False}
    with temporary_settings(updates=quiet), prefect_test_harness(server_startup_timeout=120), \
            temporary_settings(updates={PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        yield PREFECT_API_URL.value()


@pytest.fixture(scope="session")
def prefect_server(prefect_harness, tmp_path_factory):
    """The environment for flow subprocesses (``python -m flows.update``), pointing at the session's server.

    Each subprocess otherwise starts (and waits for) its own temporary server, about 6 s;
    with ``PREFECT_API_URL`` set it only imports and runs.
    """
    home = tmp_path_factory.mktemp("prefect-home")
    return {"PREFECT_HOME": str(home), "PREFECT_API_URL": prefect_harness, "DO_NOT_TRACK": "1"}


class ForkedUpdate:
    """``python -m flows.update`` forked from tests/flows/update_zygote.py, with the parts of ``subprocess.Popen``
    the tests use (pid, poll, wait, communicate, returncode; stdout and stderr together, as text)."""

    def __init__(self, zygote: "UpdateLauncher", pid: int, out: Path):
        self._zygote, self.pid, self._out, self.returncode = zygote, pid, out, None

    def poll(self):
        if self.returncode is None:
            self.returncode = self._zygote.request({"poll": self.pid})["status"]
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        import subprocess
        import time

        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired("flows.update", timeout)
            time.sleep(0.02)
        return self.returncode

    def communicate(self, timeout: float | None = None) -> tuple[str, None]:
        self.wait(timeout)
        return self._out.read_text(errors="replace"), None


class UpdateLauncher:
    """Starts ``python -m flows.update`` runs, each forked from one warm process (tests/flows/update_zygote.py)
    that imported everything once: about 4.5 s of CPU less per run. Prefect reads its settings when it is
    imported, so a run's environment may add variables but not change a ``PREFECT_*`` one."""

    def __init__(self, env: dict, folder: Path):
        import os
        import subprocess
        import sys
        import threading

        from flows.config import REPO

        self._env, self._folder, self._count, self._lock = {**os.environ, **env}, folder, 0, threading.Lock()
        self._proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name("update_zygote.py"))], cwd=REPO,
                                      env=self._env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def request(self, message: dict) -> dict:
        import json

        with self._lock:
            self._proc.stdin.write(json.dumps(message) + "\n")
            self._proc.stdin.flush()
            line = self._proc.stdout.readline()
        if not line:
            raise RuntimeError(f"tests/flows/update_zygote.py ended (exit code {self._proc.poll()})")
        return json.loads(line)

    def start(self, args: list[str], env: dict):
        """A run of ``python -m flows.update args`` with ``env`` on top of the session's environment."""
        changed = sorted(k for k, v in env.items() if k.startswith("PREFECT_") and self._env.get(k) != v)
        if changed:
            raise ValueError(f"{', '.join(changed)}: Prefect read these when the warm process imported it")
        self._count += 1
        out = self._folder / f"update-{self._count}.log"
        return ForkedUpdate(self, self.request({"run": list(args), "env": dict(env), "out": str(out)})["pid"], out)

    def close(self) -> None:
        self._proc.stdin.close()
        self._proc.wait(timeout=30)


@pytest.fixture(scope="session")
def update_launcher(prefect_server, tmp_path_factory):
    """``update_launcher.start(args, env)``: ``python -m flows.update args`` in a session of its own (see
    UpdateLauncher), for the tests that start many runs."""
    launcher = UpdateLauncher(prefect_server, tmp_path_factory.mktemp("update-logs"))
    yield launcher
    launcher.close()


@pytest.fixture
def two_iterations(prefect_harness):
    """Run a reduced config for two iterations (12 FE runs, no polish); returns (run store, parameter columns)
    after checking the counts and that the nominal model is the first sample (the loops that start from it)."""
    import numpy as np

    from flows import update
    from tasks.record import parameter_columns
    from tasks.runstore import RunStore

    def run(config):
        config = config.replace(polish=False, max_iterations=2, max_fe_evaluations=12)
        summary = update.update_flow(config)
        store = RunStore(config.resolve(config.runs_dir) / config.run_id)
        assert summary["iterations"] == 2 and summary["fe_evaluations"] == 12
        first = store.read_table(1, "fe", "runs")
        cols = parameter_columns(first)
        assert np.allclose(first[cols].to_numpy()[0], 0.0)  # the nominal model is one of the first samples
        return store, cols

    return run


@pytest.fixture(scope="session")
def in_memory_fe():
    """``in_memory_fe(problem)``: the FE runs of a strategy's batches in this process, as the flow's FE stage
    makes them (an FRF, with its exact Jacobian where asked at the flow's cost), for the in-memory drivers
    (``run_loop``) that the flow tests compare with the flow's own runs."""
    from fe_core.solvers.sensitivity import frf_jacobian
    from strategies.base import Outcome
    from tasks.fe_runs import JACOBIAN_COST

    def evaluator(problem):
        line, channel = problem.data.cells

        def evaluate(batch):
            out = []
            for x, jac in zip(batch.points, batch.jacobian):
                if jac:
                    Z, dZ = frf_jacobian(problem.model, x, problem.freqs_hz, channels=problem.channels)
                    out.append(Outcome(Z[line, channel], dZ[line, channel], JACOBIAN_COST))
                else:
                    Z = problem.model.parameter_frf(x, problem.freqs_hz, problem.channels)
                    out.append(Outcome(Z[line, channel]))
            return out

        return evaluate

    return evaluator


@pytest.fixture(scope="session")
def check_summary():
    """``check_summary(summary)``: assert that a run's summary (a dict, or a run folder) has the one shape of
    ``tasks/io/summary.schema.json`` (JSON Schema draft 2020-12, validated by jsonschema), and what a schema
    cannot say: ``intervals`` and ``covariance`` cover exactly the parameters, in their order."""
    import json
    from pathlib import Path

    import jsonschema

    from tasks.io.summary import SCHEMA_PATH

    schema = json.loads(SCHEMA_PATH.read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)

    def check(summary):
        if isinstance(summary, (str, Path)):
            summary = json.loads((Path(summary) / "summary.json").read_text())
        errors = sorted(validator.iter_errors(summary), key=lambda e: list(e.absolute_path))
        assert not errors, "\n".join(f"{'/'.join(map(str, e.absolute_path)) or '<top>'}: {e.message}"
                                     for e in errors)
        for s in [summary] + summary.get("runs", []):
            names = list(s["parameters"])
            if "intervals" in s:
                assert list(s["intervals"]) == names, (list(s["intervals"]), names)
                assert [len(row) for row in s["covariance"]] == [len(names)] * len(names)
        return summary

    return check
