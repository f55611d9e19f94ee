"""Prefect's temporary local API started while a command reads its model (:func:`start_early`).

With no Prefect server configured (no ``PREFECT_API_URL``), Prefect starts a temporary local API, a uvicorn
process of its own, when the first flow begins, and the flow waits for it to answer: 5-10 s on these machines,
27 s measured in the 500k-DOF update (docs/results/scaling.md), none of it needed by the model's reading,
assembly and memory preflight that come before the flow (54 s and 60 s there). :func:`start_early` starts it in a
thread beside that work when the work lasts longer than :data:`DELAY` (a small model is read in well under a
second, and bad input is refused as fast: no server is started for either); :meth:`EarlyAPI.wait` is called
before the flow, which then finds it answering (Prefect's ``SubprocessASGIServer`` is one per process and starts
once), and :meth:`EarlyAPI.abandon` when the command stops before its flow.

A server that fails to start here is started again, and its error raised, by the flow's own client, as before.
"""

from __future__ import annotations

import contextvars
import threading

__all__ = ["DELAY", "EarlyAPI", "start_early"]

#: Seconds the model's reading may take before the server is started beside it.
DELAY = 1.0


class EarlyAPI:
    """The temporary API's start, in a thread, after ``delay`` seconds unless :meth:`wait` or :meth:`abandon`
    comes first (``enabled`` False: a server is configured, nothing to start). The thread imports Prefect's server
    module too (1-2 s), so that is spent beside the reading as well, and runs in a copy of the caller's context
    (Prefect's settings, e.g. a ``temporary_settings`` block, are context variables)."""

    def __init__(self, enabled: bool, delay: float = DELAY):
        self._server = None   # Prefect's SubprocessASGIServer, when its start began here
        self._lock = threading.Lock()
        self._state = "waiting" if enabled else "cancelled"  # -> "starting" or "cancelled"
        self._abandoned = False
        self._cancel = threading.Event()
        self.error: Exception | None = None
        self._thread: threading.Thread | None = None
        if enabled:
            self._thread = threading.Thread(target=contextvars.copy_context().run, args=(self._run, delay),
                                            name="prefect-local-api", daemon=True)
            self._thread.start()

    @property
    def started(self) -> bool:
        """Whether the server's start began here (the model's reading outlasted the delay, no server ran)."""
        return self._server is not None

    def _run(self, delay: float) -> None:
        if self._cancel.wait(delay):
            return
        try:
            from prefect.server.api.server import SubprocessASGIServer
        except Exception as exc:  # noqa: BLE001 (the flow's client imports it again and raises)
            self.error = exc
            return
        with self._lock:
            if self._state != "waiting":   # waited for or abandoned during the import: the flow starts it
                return
            self._state = "starting"
            server = SubprocessASGIServer()   # the process's one instance
            if server.running:
                return
            self._server = server
        try:
            server.start()
        except Exception as exc:  # noqa: BLE001 (the flow's client starts it again and raises)
            self.error = exc
        with self._lock:
            if self._abandoned:   # the command stopped while the server started
                server.stop()

    def _settle(self) -> bool:
        """No start from now on unless one began; returns whether one did."""
        with self._lock:
            if self._state == "waiting":
                self._state = "cancelled"
        self._cancel.set()
        return self._state == "starting"

    def wait(self) -> None:
        """Return once a start begun here has ended, answering or failed (a failure is left to the flow's client);
        at once when none began (the flow starts the server as it always did)."""
        self._settle()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def abandon(self) -> None:
        """The command stops before its flow (bad input, a run in use, an interrupt): a server started here is
        stopped, at once if it answers, else by the thread when its start ends (at the process's exit by Prefect's
        own handler); the caller does not wait for it."""
        self._settle()
        with self._lock:
            self._abandoned = True
            thread_done = self._thread is None or not self._thread.is_alive()
            server = self._server
        if server is not None and thread_done:
            server.stop()


def start_early(delay: float | None = None) -> EarlyAPI:
    """Prefect's temporary local API started in a thread after ``delay`` seconds (:data:`DELAY`) when no server is
    configured, Prefect may start one (``PREFECT_SERVER_EPHEMERAL_ENABLED``, as its client asks) and none runs in
    the process; returns its handle.

    Between this call and :meth:`EarlyAPI.wait` the caller must not use a Prefect client (the server counts as
    started from the thread's first step, before it answers)."""
    from prefect.settings import PREFECT_API_URL, PREFECT_SERVER_EPHEMERAL_ENABLED

    enabled = not PREFECT_API_URL.value() and bool(PREFECT_SERVER_EPHEMERAL_ENABLED.value())
    return EarlyAPI(enabled, DELAY if delay is None else delay)
