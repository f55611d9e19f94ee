"""The Prefect UI shows an updating run: a real ``prefect server start``, a reduced run
against it, and the run's pages opened in headless Chromium.

Needs Debian's ``chromium`` and ``chromium-driver`` (``.ci/run`` installs them);
nothing is downloaded at run time. Screenshots go to the test's tmp folder, and
also to ``$MRGP_UI_SCREENSHOT_DIR`` when set (that is how ``docs/figures/prefect-ui-*.png``
were made).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from flows.config import REPO

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
RUN_ID = "ui"


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    """Terminate the process group of ``proc`` (started with a new session), then kill it."""
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    except ProcessLookupError:
        pass


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """``prefect server start`` with the UI on a free port; yields (base URL, client environment)."""
    port = _free_port()
    home = tmp_path_factory.mktemp("prefect-ui-home")
    base = f"http://127.0.0.1:{port}"
    env = {
        **os.environ,
        "PREFECT_HOME": str(home),
        "DO_NOT_TRACK": "1",
        "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
        "PREFECT_CLOUD_ENABLE_ORCHESTRATION_TELEMETRY": "false",
        # The UI asks the API at this address; --port alone leaves the UI on 4200.
        "PREFECT_UI_API_URL": f"{base}/api",
        "PREFECT_SERVER_UI_SHOW_PROMOTIONAL_CONTENT": "false",
    }
    env.pop("PREFECT_API_URL", None)
    log = open(home / "server.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "prefect", "server", "start", "--host", "127.0.0.1",
                             "--port", str(port)], env=env, stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        deadline = time.time() + 120
        while True:
            try:
                urllib.request.urlopen(f"{base}/api/health", timeout=2).read()
                break
            except OSError:
                if proc.poll() is not None or time.time() > deadline:
                    pytest.fail(f"prefect server start did not answer on {base}:\n{(home / 'server.log').read_text()}")
                time.sleep(0.3)
        client_env = {**env, "PREFECT_API_URL": f"{base}/api"}
        yield base, client_env
    finally:
        _stop(proc)
        log.close()
    assert proc.poll() is not None, "the Prefect server is still running"


def _api(base: str, path: str, body: dict) -> list[dict]:
    req = urllib.request.Request(f"{base}/api{path}", data=json.dumps(body).encode(),
                                 headers={"content-type": "application/json"})
    with urllib.request.urlopen(req, timeout=10) as resp:
        return json.load(resp)


@pytest.fixture(scope="module")
def finished_run(server, tmp_path_factory, reduced_settings_frozen) -> dict:
    """A reduced update sent to the server; its summary and the flow-run records from the API."""
    base, env = server
    root = tmp_path_factory.mktemp("ui-run")
    cfg = root / "reduced.toml"
    cfg.write_text("\n".join([f'runs_dir = "{root / "runs"}"']
                             + [f"{k} = {json.dumps(v)}" for k, v in reduced_settings_frozen.items()]) + "\n")
    proc = subprocess.run([sys.executable, "-m", "flows.update", "--config", str(cfg), "--run-id", RUN_ID],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((root / "runs" / RUN_ID / "summary.json").read_text())
    parents = _api(base, "/flow_runs/filter", {"flow_runs": {"name": {"any_": [f"update-{RUN_ID}"]}}})
    assert len(parents) == 1, parents
    parent = parents[0]
    subflows = _api(base, "/flow_runs/filter", {"flow_runs": {"parent_flow_run_id": {"any_": [parent["id"]]}}})
    iterations = {r["name"]: r for r in subflows if re.fullmatch(r"iteration-\d+", r["name"])}
    return {"summary": summary, "parent": parent, "iterations": iterations,
            "output": proc.stdout + proc.stderr}


@pytest.fixture
def browser():
    missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not p.exists()]
    if missing:
        pytest.fail(f"{', '.join(missing)} not found: the Prefect UI test needs Debian's Chromium "
                    "(apt-get install -y chromium chromium-driver; .ci/run installs them)")
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = str(CHROMIUM)
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--window-size=1600,1000", "--no-first-run", "--disable-extensions"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)
    try:
        yield driver
    finally:
        driver.quit()


def _wait_for_text(driver, texts: list[str], timeout: float = 45) -> str:
    """Poll the rendered page (a JS single-page app) until every text is shown; returns the page text."""
    from selenium.webdriver.common.by import By

    deadline = time.time() + timeout
    body = ""
    while time.time() < deadline:
        try:
            body = driver.find_element(By.TAG_NAME, "body").text
        except Exception:  # the page is being replaced
            body = ""
        if all(t in body for t in texts):
            return body
        time.sleep(0.25)
    missing = [t for t in texts if t not in body]
    raise AssertionError(f"{driver.current_url}: not shown after {timeout} s: {missing}\npage text:\n{body[:3000]}")


def _screenshot(driver, tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    assert driver.save_screenshot(str(path)), f"no screenshot written to {path}"
    assert path.stat().st_size > 10_000 and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    extra = os.environ.get("MRGP_UI_SCREENSHOT_DIR")
    if extra:
        shutil.copy(path, Path(extra) / name)
    return path


@pytest.mark.slow
def test_the_prefect_ui_shows_the_run_its_iterations_their_tasks_and_logs(server, finished_run, browser,
                                                                        tmp_path):
    from selenium.webdriver.common.by import By

    base, _ = server
    summary, parent, iterations = finished_run["summary"], finished_run["parent"], finished_run["iterations"]
    n = summary["iterations"]
    assert sorted(iterations) == sorted(f"iteration-{k}" for k in range(1, n + 1))
    assert parent["state_type"] == "COMPLETED"
    page = f"{base}/runs/flow-run/{parent['id']}"
    assert page in finished_run["output"], "the run's log does not link to the page tested here"

    # The run's page: name, state, flow; then its per-iteration subflow runs.
    browser.get(page)
    _wait_for_text(browser, [f"update-{RUN_ID}", "Completed", "mrgp-update", "Subflow Runs"])
    time.sleep(1.5)  # let the timeline graph (a canvas) draw before the screenshot
    _screenshot(browser, tmp_path, "prefect-ui-run.png")
    browser.find_element(By.ID, "subflow-runs").click()
    _wait_for_text(browser, [f"{n} Flow runs", *iterations])

    # One iteration's page: its task runs by name with their states, and the FE stage's log lines.
    k = 2 if n >= 2 else 1
    sub = iterations[f"iteration-{k}"]
    tasks = _api(base, "/task_runs/filter", {"flow_runs": {"id": {"any_": [sub["id"]]}}})
    names = sorted(t["name"] for t in tasks)
    assert {f"iteration-{k}-fe", f"iteration-{k}-distribution", f"iteration-{k}-train"} <= set(names), names
    assert all(t["state_type"] == "COMPLETED" for t in tasks)
    browser.get(f"{base}/runs/flow-run/{sub['id']}")
    fe_done = f"iteration {k}, stage fe: "
    _wait_for_text(browser, [f"iteration-{k}", f"update-{RUN_ID}", f"{len(tasks)} Task runs", fe_done])
    browser.find_element(By.ID, "task-runs").click()
    text = _wait_for_text(browser, [f"({len(tasks)} Completed)", *names])
    for name in names:  # each task is listed with its state
        assert re.search(rf"^{re.escape(name)}\nCompleted$", text, re.M), name
    time.sleep(1.5)
    shot = _screenshot(browser, tmp_path, "prefect-ui-iteration.png")
    assert shot.exists()


@pytest.mark.slow
def test_the_prefect_ui_shows_a_run_of_the_default_strategy_its_cycles_and_their_stages(server, browser, tmp_path):
    """The default (hybrid) strategy in the UI: its cycle subflows, each with its FE stage and check, and the
    FE stage's log lines (the cantilever example: a local cycle, then its check)."""
    base, env = server
    proc = subprocess.run([sys.executable, "-m", "flows.update", "--model", "data/examples/cantilever_matrices/"
                           "model.toml", "--measured", "data/examples/cantilever_matrices/measured.csv",
                           "--run-id", "ui-hybrid", "--runs-dir", str(tmp_path / "runs"),
                           "--n-jobs", "1", "--no-intervals"],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    parent, = _api(base, "/flow_runs/filter", {"flow_runs": {"name": {"any_": ["update-ui-hybrid"]}}})
    cycles = _api(base, "/flow_runs/filter", {"flow_runs": {"parent_flow_run_id": {"any_": [parent["id"]]}}})
    assert parent["state_type"] == "COMPLETED" and [c["name"] for c in cycles] == ["cycle-1"]
    tasks = _api(base, "/task_runs/filter", {"flow_runs": {"id": {"any_": [cycles[0]["id"]]}}})
    assert sorted(t["name"] for t in tasks) == ["iteration-1-check", "iteration-1-local"]
    browser.get(f"{base}/runs/flow-run/{cycles[0]['id']}")
    _wait_for_text(browser, ["cycle-1", "update-ui-hybrid", "2 Task runs", "iteration 1, stage local: 1/1 FE runs done",
                             "iteration 1, stage check:"])


def test_the_modal_update_is_in_the_api_with_one_task_run_per_computed_stage(server, tmp_path):
    """``python -m flows.update`` on identified modes (the modal flow, tests/flows/test_modal_resume.py) as the UI
    sees it: the flow run completed, one task run per stage it computed."""
    base, env = server
    proc = subprocess.run([sys.executable, "-m", "flows.update", "--model", "data/examples/modal/model.toml",
                           "--measured", "data/examples/modal/modes.uff", "--runs-dir", str(tmp_path / "runs"),
                           "--run-id", "modal-ui", "--starts", "1", "--frequency-sigma", "0.002",
                           "--shape-sigma", "0.02"], cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    flow_runs = _api(base, "/flow_runs/filter", {"flow_runs": {"name": {"any_": ["modal-modal-ui"]}}})
    assert [f["state_type"] for f in flow_runs] == ["COMPLETED"]
    want = sorted(["correlation_before", "fit", "correlation_after", "closure"])
    deadline = time.time() + 30  # the server records task runs from their events, in batches
    while True:
        tasks = _api(base, "/task_runs/filter", {"flow_runs": {"id": {"any_": [flow_runs[0]["id"]]}}})
        if sorted(t["name"] for t in tasks) == want or time.time() > deadline:
            break
        time.sleep(0.5)
    assert sorted(t["name"] for t in tasks) == want
