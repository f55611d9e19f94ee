"""One interface for the search strategies, in emukit's shape: propose, evaluate, update, stop.

A strategy proposes a :class:`Batch` of parameter points (a *round*: FE runs that may go in parallel and
must all finish before the next round is chosen), the caller evaluates them on the FE model, the strategy
takes the results in (:meth:`Strategy.update`) and says whether to stop (:meth:`Strategy.stop`). The
strategy never runs the FE model itself, so the same object runs in memory (:func:`run_loop`, the tests and
benchmarks) and under the flow, where every round's FE runs are stored and replayed on resume.

The strategies: :class:`strategies.paper.PaperLoop` (the paper's adaptive MRGP loop, Table 2)
and :class:`strategies.hybrid.Hybrid` (the default: Gauss-Newton with exact Jacobians from the
nominal model, global rounds with the MRGP emulator when the residual is not noise).

An evaluation result is an :class:`Outcome`: the complex receptance ``Z`` at the k measured values, its
derivative ``dZ`` (k, m) where the batch asked for it, the run's cost in FE-run equivalents, and (for the
paper loop's modal emulation) the run's lowest modes. Plain tuples ``(Z, dZ[, cost])`` are accepted too.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

__all__ = ["Batch", "Outcome", "StopDecision", "Strategy", "Evaluate", "run_loop"]


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
    """

    points: np.ndarray
    jacobian: tuple
    label: str = ""

    def __len__(self) -> int:
        return len(self.points)


class Outcome(NamedTuple):
    """One FE run's result: ``Z`` (k,) complex; ``dZ`` (k, m) or None; ``cost`` in FE-run equivalents (None:
    1, or the strategy's Jacobian cost with a derivative); ``modes`` = (omega2 (r,), participation (r, n))
    when the run gave its lowest modes."""

    Z: np.ndarray
    dZ: np.ndarray | None = None
    cost: float | None = None
    modes: tuple | None = None


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


#: ``evaluate(batch) -> [Outcome, ...]``: the caller's FE runs of one round.
Evaluate = Callable[[Batch], Sequence]


def run_loop(strategy: Strategy, evaluate: Evaluate) -> StopDecision:
    """Propose, evaluate, update until the strategy stops; returns its last decision."""
    while True:
        decision = strategy.stop()
        if decision.stop:
            return decision
        batch = strategy.propose()
        strategy.update(batch, evaluate(batch))
