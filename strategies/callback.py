"""Any callback optimiser as an ask-tell strategy: its body in a worker thread, each evaluation an ask.

A callback optimiser (``scipy.optimize.least_squares`` with ``fun``/``jac``, ``minimize``, a hand-written
loop) calls the evaluation itself; a strategy (:mod:`.base`) must instead hand each round to its caller and
wait to be told. :class:`CallbackStrategy` joins the two without re-writing the optimiser: it runs
``body(ask)`` in a worker thread, where ``ask(batch)`` hands the :class:`~.base.Batch` to the caller
(:meth:`~CallbackStrategy.propose`) and blocks until the caller tells its outcomes
(:meth:`~CallbackStrategy.update`); the strategy stops when the body returns (its value is
:attr:`~CallbackStrategy.result`). Exactly one of the two threads runs at a time (a handshake through two
queues), so the body needs no locks and sees its outcomes in the order it asked.

A deterministic body (scipy's optimisers are) asks the same batches when told the same outcomes, so a run
under the driver (``tasks/driver.py``) resumes by replay: the driver reads the outcomes of the batches asked
again back from the run folder, and the body goes on from where the stored ones end.

Shutdown: when the caller stops early (its evaluation raised, ``rerun`` reached its stage, an interrupt),
:meth:`~CallbackStrategy.close` tells the waiting body :class:`Stopped` (raised from its ``ask``; a
``BaseException``, so an optimiser's ``except Exception`` does not swallow it) and joins the thread;
:func:`.base.run_loop` and the driver call it. An exception raised in the body is raised again in the caller's
thread by the next :meth:`~CallbackStrategy.stop` or :meth:`~CallbackStrategy.propose`, the thread having ended.
The thread is a daemon: a strategy abandoned without ``close`` does not keep the process alive.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Sequence

from .base import Batch, Report, StopDecision

__all__ = ["CallbackStrategy", "Stopped"]


class Stopped(BaseException):
    """Raised from ``ask`` in the body when the caller closed the strategy."""


_CLOSE = object()  # the caller's message to a waiting body: stop


class CallbackStrategy:
    """``body(ask)`` as an ask-tell strategy (module docstring).

    Parameters
    ----------
    body : callable
        ``body(ask) -> result``, run in a worker thread on the first :meth:`stop` or :meth:`propose`;
        ``ask(batch) -> outcomes`` (one per point of the batch, in order, as the caller told them).
    name : str
        For the thread's name and messages.

    Attributes
    ----------
    result : object
        What the body returned (None until it has).
    asked : int
        Batches asked so far.
    """

    def __init__(self, body: Callable[[Callable[[Batch], Sequence]], object], name: str = "callback"):
        self.body, self.name = body, name
        self.result = None
        self.asked = 0
        self._to_caller: queue.Queue = queue.Queue()
        self._to_body: queue.Queue = queue.Queue()
        self._thread: threading.Thread | None = None
        self._message = None  # ("ask", batch), ("done", result), ("error", exception) or ("closed", None)

    # -- the worker's side ---------------------------------------------------------------------------------------
    def _ask(self, batch: Batch) -> Sequence:
        self._to_caller.put(("ask", batch))
        told = self._to_body.get()
        if told is _CLOSE:
            raise Stopped(f"{self.name}: closed by its caller")
        return told

    def _work(self) -> None:
        try:
            result = self.body(self._ask)
        except Stopped:
            return  # the caller closed us: nobody waits for a message
        except BaseException as exc:  # raised again in the caller's thread
            self._to_caller.put(("error", exc))
            return
        self._to_caller.put(("done", result))

    # -- the caller's side ---------------------------------------------------------------------------------------
    def _next(self):
        """The body's pending message: wait for it (the body runs meanwhile) unless it is there."""
        if self._message is None:
            if self._thread is None:
                self._thread = threading.Thread(target=self._work, name=f"{self.name} body", daemon=True)
                self._thread.start()
            self._message = self._to_caller.get()
            if self._message[0] != "ask":
                self._thread.join()
            if self._message[0] == "done":
                self.result = self._message[1]
        if self._message[0] == "error":
            raise self._message[1]
        return self._message

    def stop(self) -> StopDecision:
        kind, _ = self._next()
        if kind == "ask":
            return StopDecision(False, False, "")
        if kind == "closed":
            return StopDecision(True, False, f"{self.name}: closed before its end")
        return StopDecision(True, self.converged(), self.reason())

    def propose(self) -> Batch:
        kind, batch = self._next()
        if kind != "ask":
            raise RuntimeError(f"{self.name}: asked for a batch after it stopped")
        return batch

    def update(self, batch: Batch, outcomes: Sequence) -> None:
        kind, asked = self._next()
        if kind != "ask" or batch is not asked:
            raise RuntimeError(f"{self.name}: told the outcomes of a batch it is not waiting for")
        outcomes = list(outcomes)
        if len(outcomes) != len(batch):
            raise ValueError(f"{self.name}: {len(outcomes)} outcomes for a batch of {len(batch)}")
        self.asked += 1
        self._message = None
        self._to_body.put(outcomes)

    def close(self) -> None:
        """Stop a body still waiting for outcomes (it gets :class:`Stopped`) and join its thread; harmless
        after the body has ended, or before it started."""
        thread = self._thread
        if thread is None or not thread.is_alive():
            return
        self._to_body.put(_CLOSE)
        thread.join()
        if self._message is None or self._message[0] == "ask":
            self._message = ("closed", None)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the end: subclasses say more ------------------------------------------------------------------------------
    def converged(self) -> bool:
        """Whether the body's result is converged (subclasses: from :attr:`result`)."""
        return True

    def reason(self) -> str:
        return f"{self.name}: finished after {self.asked} batches"

    def report(self) -> Report:
        decision = self.stop()
        return Report(decision.reason, decision.converged)
