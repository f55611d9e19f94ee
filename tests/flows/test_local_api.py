"""Prefect's temporary API started beside the model's reading (flows/local_api.py): the caller goes on while the
server starts (after a delay: a small model or bad input starts none), ``wait`` returns once it answers, a server
started for a command that stops is stopped, a configured server is left alone, a failed start is left to the
flow's client."""

from __future__ import annotations

import threading

import pytest
from prefect.server.api import server as prefect_server
from prefect.settings import PREFECT_API_URL, temporary_settings

from flows import local_api


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


def test_a_server_started_for_a_command_that_then_stops_is_stopped(monkeypatch, no_api_url):
    fake = _SlowServer()
    stopped = []
    fake.stop = lambda: stopped.append(fake.answering.is_set())
    monkeypatch.setattr(prefect_server, "SubprocessASGIServer", fake)
    handle = local_api.start_early(delay=0.0)
    assert fake.entered.wait(30)
    fake.release.set()
    handle.abandon()
    assert handle.started and stopped == [True]  # stopped once it had started, not left to run


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


def test_the_update_runs_on_the_server_started_beside_its_reading(tmp_path, monkeypatch, no_api_url):
    """The real command, its server started at once beside the benchmark's reading: one server, the one started
    here, and the run converges on it."""
    from prefect.server.api.server import SubprocessASGIServer

    from flows import update

    monkeypatch.setenv("PREFECT_HOME", str(tmp_path / "prefect"))  # the server's database, in its process
    monkeypatch.setattr(local_api, "DELAY", 0.0)
    spawned = []
    spawn = SubprocessASGIServer._run_uvicorn_command
    monkeypatch.setattr(SubprocessASGIServer, "_run_uvicorn_command",
                        lambda self: spawned.append(threading.current_thread().name) or spawn(self))
    try:
        assert update.main(["--runs-dir", str(tmp_path / "runs"), "--run-id", "early", "--no-intervals"]) == 0
    finally:
        from prefect.events.worker import EventsWorker
        from prefect.logging.handlers import APILogWorker

        APILogWorker.drain_all(timeout=10)  # the run's last log lines and events sent before the server stops
        EventsWorker.drain_all(timeout=10)
        SubprocessASGIServer().stop()
    assert spawned == ["prefect-local-api"]
    summary = (tmp_path / "runs" / "early" / "summary.json").read_text()
    assert '"converged": true' in summary
