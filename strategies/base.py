"""One interface for the search strategies, in emukit's shape: propose, evaluate, update, stop.

A strategy proposes a :class:`Batch` of parameter points (a *round*: FE runs that may go in parallel and
must all finish before the next round is chosen), the caller evaluates them on the FE model, the strategy
takes the results in (:meth:`Strategy.update`) and says whether to stop (:meth:`Strategy.stop`). The
strategy never runs the FE model itself, so the same object runs in memory (:func:`run_loop`, the tests and
benchmarks) and under the run's driver (``tasks/driver.py``), which stores every batch's FE runs in the run
record and, on resume, replays the strategy through them.

Besides its batches a strategy may have named *steps* whose results are worth keeping (the paper loop's
MRGP training, the hybrid's checks and evidence screens): it computes them through a :class:`Memo`,
``memo.step(iteration, name, compute)``. In memory (:class:`InMemory`) a memo is a dict; under the driver
every step is a stage of the run folder (``iteration=<k>/stage=<name>/``: its tables and its record), read
back on resume instead of computed again, and what ``rerun`` recomputes. A strategy decides from the step's
returned result only (not from what ``compute`` returned), so a step read back leads where the original did.

When it stops, :meth:`report` says why (:class:`Report`). :class:`Context` is what a strategy is built from
(:mod:`.registry`: one entry per strategy, with its options dataclasses and its rerunnable steps).

An evaluation result is an :class:`Outcome`: the complex receptance ``Z`` at the k measured values, its
derivative ``dZ`` (k, m) where the batch asked for it, the run's cost in FE-run equivalents, and (for the
paper loop's modal emulation) the run's lowest modes. Plain tuples ``(Z, dZ[, cost])`` are accepted too.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

import numpy as np

__all__ = ["Batch", "Outcome", "StopDecision", "Strategy", "Evaluate", "run_loop", "Report", "report_of", "Step",
           "Memo", "InMemory", "Context", "jsonable", "close_strategy"]


@dataclass(frozen=True)
class Batch:
    """One round of FE runs.

    Attributes
    ----------
    points : ndarray, shape (b, m)
        Parameter vectors.
    jacobian : tuple of bool, length b
        Whether each run must also give its exact derivative.
    label : str
        The strategy's name for the round (``"iteration-3"``, ``"local"``, ``"global-2"``).
    iteration, stage : int, str
        Where the driver records the round's FE runs: ``iteration=<iteration>/stage=<stage>/`` of the run
        folder (consecutive rounds of one stage share its record; a strategy never returns to a stage).
    modes : bool
        The runs also give their lowest modes (:attr:`Outcome.modes`; the paper loop's modal emulation).
    """

    points: np.ndarray
    jacobian: tuple
    label: str = ""
    iteration: int = 1
    stage: str = "fe"
    modes: bool = False

    def __len__(self) -> int:
        return len(self.points)


class Outcome(NamedTuple):
    """One FE run's result: ``Z`` (k,) complex (the modal strategies, :mod:`.modal_fit`, :mod:`.modal_paper`: the
    weighted residual's real values); ``dZ`` (k, m) or None; ``cost`` in FE-run equivalents (None: 1, or the
    strategy's Jacobian cost with a derivative); ``modes`` = (omega2 (r,), participation (r, n))
    when the run gave its lowest modes; ``at`` (m,): where the evaluation ended when it moved from the point
    asked (local steps from it, as the closure's emulated search takes), None: at the point asked; ``reduced``:
    the result came from a large model's reduced basis, not a full-order run (:mod:`fe_core.solvers.reduced_basis`:
    asked again at the same point, the run is made at full order)."""

    Z: np.ndarray
    dZ: np.ndarray | None = None
    cost: float | None = None
    modes: tuple | None = None
    at: np.ndarray | None = None
    reduced: bool = False


@dataclass(frozen=True)
class StopDecision:
    """Whether the loop stops, whether it converged, and why."""

    stop: bool
    converged: bool
    reason: str


class Strategy(Protocol):
    """What every search strategy implements (the caller evaluates)."""

    def propose(self) -> Batch:
        """The next round of FE runs; called only while :meth:`stop` says go on."""

    def update(self, batch: Batch, outcomes: Sequence) -> None:
        """Take the results of ``batch`` in (one :class:`Outcome` or tuple per point, in order)."""

    def stop(self) -> StopDecision:
        """Whether to stop now, and why."""


@dataclass(frozen=True)
class Report:
    """Why a strategy stopped, for the run's summary.

    stop_reason, converged : in words, and whether the result is at the target or the noise;
    candidates : the FE runs the reported result is chosen from, by request index (the driver's sample ids:
        0, 1, ... in the order the strategy asked for them), or None: all of them;
    fields : further ``summary.json`` fields (``"polish"``, ``"evidence"``);
    iterations : the run's iterations (None: the last batch's);
    intervals : the strategy ends with a local least-squares fit, so the 95 % intervals apply to its result.
    """

    stop_reason: str
    converged: bool
    candidates: list | None = None
    fields: dict = field(default_factory=dict)
    iterations: int | None = None
    intervals: bool = False


def report_of(strategy) -> Report:
    """``strategy.report()``, or a report from its last stop decision when it has none."""
    if hasattr(strategy, "report"):
        return strategy.report()
    decision = strategy.stop()
    return Report(decision.reason, decision.converged)


def jsonable(obj):
    """``obj`` as it comes back from a JSON file (numpy scalars and arrays to numbers and lists, tuples to lists):
    a step's info is the same object whether it was just computed or read back."""
    def default(o):
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        raise TypeError(f"not JSON serialisable: {type(o).__name__}")

    return json.loads(json.dumps(obj, default=default))


@dataclass(frozen=True)
class Step:
    """A named step's result: ``tables`` (table name -> {column: 1-D array}) and ``info`` (a JSON-able dict);
    ``note``: one line for the run's log when it was computed (not kept)."""

    tables: dict
    info: dict
    note: str = ""

    def table(self, name: str) -> dict:
        return self.tables[name]


class Memo(Protocol):
    """Where a strategy's named steps are computed, kept and read back."""

    def step(self, iteration: int, name: str, compute: Callable[[], Step]) -> Step:
        """The step ``name`` of ``iteration``: ``compute()`` the first time, its kept result after."""


class InMemory:
    """A memo in memory (:class:`Memo`): ``steps[(iteration, name)]``, each result as it would be read back
    from a run folder (info through JSON, table columns as arrays)."""

    def __init__(self):
        self.steps: dict[tuple[int, str], Step] = {}

    def step(self, iteration: int, name: str, compute: Callable[[], Step]) -> Step:
        key = (int(iteration), name)
        if key not in self.steps:
            done = compute()
            self.steps[key] = Step({t: {c: np.asarray(v).copy() for c, v in cols.items()}
                                    for t, cols in done.tables.items()}, jsonable(done.info))
        return self.steps[key]


@dataclass
class Context:
    """What a strategy is built from (:mod:`.registry`): the run's problem as plain arrays and callables.

    names : parameter names (the run record's columns); lower, upper : the search box (m,); solver_box :
    (low, high), the box of local solvers and of the nominal model; nominal : (m,); residual : the measured data
    (:class:`fe_core.inference.frf_data.FRFData`): ``residual(Z) -> r`` of the receptance at the k kept values,
    where they sit, their statistics; jacobian_cost : FE-run equivalents of a run with its Jacobian;
    modal_layout : the emulated modes' layout (``() -> ModalLayout``; None without modes); screen_model :
    ``() -> (model or None, why)``, the model the effect screens see through the data's channels
    (:func:`fe_core.closure.evidence.screen_points`); memo : where the steps go (:class:`Memo`); large : the
    model is large (an FE run takes a minute or more at its size, ``tasks.fe_runs.is_large``).
    """

    names: list
    lower: np.ndarray
    upper: np.ndarray
    solver_box: tuple
    nominal: np.ndarray
    residual: object
    jacobian_cost: float = 2.5
    modal_layout: Callable | None = None
    screen_model: Callable | None = None
    memo: object = field(default_factory=InMemory)
    large: bool = False

    @property
    def m(self) -> int:
        return len(self.names)


#: ``evaluate(batch) -> [Outcome, ...]``: the caller's FE runs of one round.
Evaluate = Callable[[Batch], Sequence]


def run_loop(strategy: Strategy, evaluate: Evaluate) -> StopDecision:
    """Propose, evaluate, update until the strategy stops; returns its last decision. A strategy with a
    ``close()`` (one running a callback optimiser in a thread, :mod:`.callback`) is closed however the loop ends."""
    try:
        while True:
            decision = strategy.stop()
            if decision.stop:
                return decision
            batch = strategy.propose()
            strategy.update(batch, evaluate(batch))
    finally:
        close_strategy(strategy)


def close_strategy(strategy) -> None:
    """``strategy.close()`` when it has one (:class:`.callback.CallbackStrategy`: its worker thread ended)."""
    close = getattr(strategy, "close", None)
    if close is not None:
        close()
