"""Prefect's temporary API started beside the model's reading (flows/local_api.py): the caller goes on while the
server starts (after a delay: a small model or bad input starts none), ``wait`` returns once it answers, a server
started for a command that stops is stopped (without waiting for it), a configured server is left alone, a failed
start is left to the flow's client; the real command in a process of its own runs on the server started so."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from prefect.server.api import server as prefect_server
from prefect.settings import PREFECT_API_URL, temporary_settings

from flows import local_api

REPO = Path(__file__).resolve().parents[2]


class _SlowServer:
    """Stands in for ``SubprocessASGIServer``: its start records the thread it runs on (``entered``), then answers
    once ``release`` is set (or fails, with ``fail``)."""

    def __init__(self, fail: bool = False):
        self.fail = fail
        self.running = False
        self.threads: list[str] = []
        self.entered, self.release, self.answering = threading.Event(), threading.Event(), threading.Event()

    def __call__(self):  # SubprocessASGIServer() returns the one instance of the process
        return self

    def start(self):
        self.threads.append(threading.current_thread().name)
        self.running = True
        self.entered.set()
        assert self.release.wait(30)
        if self.fail:
            self.running = False
            raise RuntimeError("Timed out while attempting to connect to ephemeral Prefect API server.")
        self.answering.set()


@pytest.fixture
def no_api_url():
    with temporary_settings(updates={PREFECT_API_URL: ""}):
        yield


def test_a_long_reading_has_the_server_started_beside_it_and_wait_returns_once_it_answers(monkeypatch, no_api_url):
    fake = _SlowServer()
    monkeypatch.setattr(prefect_server, "SubprocessASGIServer", fake)
    handle = local_api.start_early(delay=0.0)  # returns while the start is under way (else this would block)
    assert fake.entered.wait(30)  # the start has begun beside the caller (the model is read meanwhile)
    assert handle.started and fake.threads == ["prefect-local-api"] and not fake.answering.is_set()
    releaser = threading.Timer(0.2, fake.release.set)
    releaser.start()
    handle.wait()
    assert fake.answering.is_set() and handle.error is None  # wait returned once the server answered
    handle.wait()  # a second wait returns at once
    again = local_api.start_early(delay=0.0)
    again._thread.join(30)  # let it look before a wait could cancel it
    again.wait()
    assert not again.started and fake.threads == ["prefect-local-api"]  # running already: not started twice


def test_a_short_reading_or_bad_input_starts_no_server(monkeypatch, no_api_url):
    fake = _SlowServer()
    monkeypatch.setattr(prefect_server, "SubprocessASGIServer", fake)
    handle = local_api.start_early(delay=30.0)
    handle.wait()  # the model was read within the delay: the flow starts the server as it always did
    assert not handle.started
    handle = local_api.start_early(delay=30.0)
    handle.abandon()  # refused before the flow
    assert not handle.started and fake.threads == [] and not fake.entered.wait(0.3)


def test_a_server_started_for_a_command_that_then_stops_is_stopped_without_waiting_for_it(monkeypatch, no_api_url):
    fake = _SlowServer()
    stops = []
    fake.stop = lambda: stops.append(fake.answering.is_set())
    monkeypatch.setattr(prefect_server, "SubprocessASGIServer", fake)
    handle = local_api.start_early(delay=0.0)
    assert fake.entered.wait(30)
    handle.abandon()  # returns at once: the error is printed, the start is still under way
    assert handle.started and stops == []
    fake.release.set()
    handle._thread.join(30)
    assert stops == [True]  # stopped by the thread once its start had ended
    fake.running = False  # a second command whose server answers before it stops: stopped at once
    handle = local_api.start_early(delay=0.0)
    handle._thread.join(30)
    handle.abandon()
    assert handle.started and stops == [True, True]


def test_a_configured_server_is_left_alone(monkeypatch):
    fake = _SlowServer()
    monkeypatch.setattr(prefect_server, "SubprocessASGIServer", fake)
    with temporary_settings(updates={PREFECT_API_URL: "http://127.0.0.1:4200/api"}):
        handle = local_api.start_early(delay=0.0)
    handle.wait()
    assert not handle.started and fake.threads == [] and not fake.entered.wait(0.3)


def test_a_failed_start_is_kept_and_left_to_the_flows_client(monkeypatch, no_api_url):
    fake = _SlowServer(fail=True)
    monkeypatch.setattr(prefect_server, "SubprocessASGIServer", fake)
    handle = local_api.start_early(delay=0.0)
    assert fake.entered.wait(30)
    fake.release.set()
    handle.wait()
    assert isinstance(handle.error, RuntimeError) and not fake.running  # Prefect's client starts it again


_EARLY_UPDATE = """
import sys, threading
from prefect.server.api.server import SubprocessASGIServer
from flows import local_api, update
local_api.DELAY = 0.0
spawned = []
spawn = SubprocessASGIServer._run_uvicorn_command
SubprocessASGIServer._run_uvicorn_command = lambda self: spawned.append(threading.current_thread().name) or spawn(self)
code = update.main(sys.argv[1:])
print("spawned by", spawned, "exit", code)
"""


@pytest.mark.slow
def test_the_update_runs_on_the_server_started_beside_its_reading(tmp_path):
    """The real command in a process of its own (no Prefect server configured), its server started at once beside
    the benchmark's reading: one server, the one started there, and the run converges on it."""
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    env.update(PREFECT_HOME=str(tmp_path / "prefect"), PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, "-c", _EARLY_UPDATE, "--runs-dir", str(tmp_path / "runs"), "--run-id",
                           "early", "--no-intervals"], cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert "spawned by ['prefect-local-api'] exit 0" in done.stdout, done.stdout[-2000:] + done.stderr[-2000:]
    assert done.returncode == 0
    summary = (tmp_path / "runs" / "early" / "summary.json").read_text()
    assert '"converged": true' in summary
