"""A warm ``python -m flows.update`` for the flow tests that start many (kills, resumes, FE backends).

Each ``python -m flows.update`` spends 4-5 s of CPU importing Prefect, pandas, scipy and the repository before
it runs anything; the kill tests start dozens. This process imports all that once, then forks one child per
request, and the child runs the module as ``__main__`` exactly as ``python -m flows.update`` would (under a
settings context without flow-run heartbeats, as tests/flows/conftest.py's server runs flows): its own
session, its arguments, its environment on top of this process's, stdout and stderr into a file, Python's exit handlers
run at its end as the interpreter runs them, its exit code (or the signal that killed it) reported. Nothing
has started a thread here when it forks.

Requests and replies are JSON lines on stdin/stdout (tests/flows/conftest.py's ``UpdateLauncher`` is the
client): ``{"run": [args], "env": {..}, "out": path}`` -> ``{"pid": pid}``; ``{"poll": pid}`` ->
``{"status": None | exit code, negative for a signal}``.
"""

from __future__ import annotations

import atexit
import json
import os
import runpy
import sys
import threading
import traceback

sys.path[0] = os.getcwd()  # as ``python -m`` has it: the repository (the cwd), not this file's folder

import flows.environment  # noqa: E402, F401  (the environment Prefect is imported in, as the command sets it)
import flows.update  # noqa: E402, F401  (everything a run imports, once)
from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings  # noqa: E402

from tasks.problem import read_model_ref  # noqa: E402

# The benchmark's model, which most runs here update, read and assembled once (0.8 s): each fork finds it in
# the process's models by its file's checksum, as a second run in one process does; a changed file is read again.
read_model_ref("three_plate")


def _child(args: list[str], env: dict, out: str) -> None:
    os.setsid()
    fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.close(null)
    os.environ.update(env)
    sys.argv = ["flows.update", *args]
    code = 0
    try:
        with temporary_settings(updates={PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
            runpy.run_module("flows.update", run_name="__main__", alter_sys=True)
    except SystemExit as stop:
        if stop.code is None or isinstance(stop.code, int):
            code = stop.code or 0
        else:
            print(stop.code, file=sys.stderr)
            code = 1
    except BaseException:  # noqa: BLE001  (as the interpreter would: the traceback, exit code 1)
        traceback.print_exc()
        code = 1
    try:  # the interpreter's own end: threading's exit callbacks (loky's executor) and threads joined, then atexit
        threading._shutdown()
        atexit._run_exitfuncs()
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def main() -> None:
    for line in sys.stdin:
        request = json.loads(line)
        if "run" in request:
            sys.stdout.flush()
            sys.stderr.flush()
            pid = os.fork()
            if pid == 0:
                _child(request["run"], request.get("env", {}), request["out"])
            reply = {"pid": pid}
        else:
            pid, status = os.waitpid(request["poll"], os.WNOHANG)
            reply = {"status": None if pid == 0 else os.waitstatus_to_exitcode(status)}
        print(json.dumps(reply), flush=True)


if __name__ == "__main__":
    main()
