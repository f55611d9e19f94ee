"""Fixtures for flow tests: a reduced configuration that runs in seconds."""

from __future__ import annotations

import pytest

from flows.config import UpdateConfig

# 16 FE runs for the MRGP loop, then 7 for the polish (one Jacobian of 6 parameters and one step).
REDUCED = dict(q=8, w=400, s=4, z=6, max_iterations=3, max_fe_evaluations=23, polish_max_fe=7, threshold=1e-6,
               n_jobs=1, trainer="gradient", seed=11)


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
def prefect_server(tmp_path_factory):
    """One local Prefect server for the tests that start many flow subprocesses.

    Each ``python -m flows.update`` otherwise starts (and waits for) its own
    temporary server, about 6 s; with ``PREFECT_API_URL`` pointing here a
    subprocess only imports and runs. Yields the environment to pass to them.
    """
    import os
    import signal
    import socket
    import subprocess
    import sys
    import time
    import urllib.request

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    home = tmp_path_factory.mktemp("prefect-home")
    env = {**os.environ, "PREFECT_HOME": str(home), "DO_NOT_TRACK": "1", "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
           "PREFECT_SERVER_UI_ENABLED": "false"}
    log = open(home / "server.log", "w")
    server = subprocess.Popen([sys.executable, "-m", "prefect", "server", "start", "--host", "127.0.0.1",
                               "--port", str(port)], env=env, stdout=log, stderr=subprocess.STDOUT,
                              start_new_session=True)
    url = f"http://127.0.0.1:{port}/api"
    try:
        deadline = time.time() + 90
        while True:
            try:
                urllib.request.urlopen(url + "/health", timeout=2).read()
                break
            except OSError:
                if server.poll() is not None or time.time() > deadline:
                    raise RuntimeError(f"the Prefect server did not start: {(home / 'server.log').read_text()}")
                time.sleep(0.3)
        yield {"PREFECT_HOME": str(home), "PREFECT_API_URL": url, "DO_NOT_TRACK": "1"}
    finally:
        try:
            os.killpg(server.pid, signal.SIGTERM)
            server.wait(timeout=20)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            try:
                os.killpg(server.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            server.wait(timeout=20)
        log.close()
