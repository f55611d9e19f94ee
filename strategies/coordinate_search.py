"""A coordinate (compass) search: the smallest complete strategy, the example of docs/guide/architecture.md.

Round k (iteration k of the run folder, stage ``fe``) evaluates the centre's 2 m neighbours ``x +- step e_i``
(the first round the centre too); the best of them becomes the centre if it is better, else the step halves
(the step ``move``, kept through the memo). It stops at ``polish_target``, when the step is below 1e-6 or when
the next round would exceed ``max_fe_evaluations``. No derivatives, no emulator: a baseline, not a method.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import Batch, Report, Step, StopDecision
from .options import setting, uses

__all__ = ["CoordinateOptions", "CoordinateSearch", "build", "STAGES"]

STAGES = ("fe", "move")


@dataclass(frozen=True)
class CoordinateOptions:
    step: float = setting(0.25, key="coordinate_step", help="first step of the coordinate strategy (halved "
                          "after every round that finds no better point)")
    max_fe: int = uses("max_fe_evaluations", 240)
    target: float = uses("polish_target", 1e-4)


class CoordinateSearch:
    def __init__(self, x0, residual, lower, upper, options: CoordinateOptions, memo):
        self.x, self.residual, self.options, self.memo = np.asarray(x0, float), residual, options, memo
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.step, self.error, self.k, self.n, self.best = options.step, np.inf, 0, 0, None

    def _points(self) -> np.ndarray:
        moves = np.vstack([np.eye(self.x.size), -np.eye(self.x.size)]) * self.step
        around = np.clip(self.x + moves, self.lower, self.upper)
        return around if self.k else np.vstack([self.x, around])

    def propose(self) -> Batch:
        return Batch(self._points(), (False,) * len(self._points()), f"iteration-{self.k + 1}", self.k + 1)

    def update(self, batch: Batch, outcomes) -> None:
        self.k += 1
        errors = [self.residual.error(np.asarray(o[0])) for o in outcomes]
        i = int(np.argmin(errors))

        def move() -> Step:
            better = errors[i] < self.error
            x, step = (batch.points[i], self.step) if better else (self.x, self.step / 2)
            return Step({"move": {"x": np.asarray(x, float)}}, {"error": min(errors[i], self.error), "step": step,
                                                                  "sample_id": self.n + i if better else self.best})
        done = self.memo.step(self.k, "move", move)
        self.x, self.step = np.asarray(done.table("move")["x"], float), done.info["step"]
        self.error, self.best, self.n = done.info["error"], done.info["sample_id"], self.n + len(batch)

    def stop(self) -> StopDecision:
        if self.error <= self.options.target:
            return StopDecision(True, True, f"overall error {self.error:.3e} <= target {self.options.target:.1e}")
        if self.step < 1e-6 or self.n + len(self._points()) > self.options.max_fe:
            return StopDecision(True, False, f"step {self.step:.2g}, {self.n} FE runs: the search has stalled "
                                             "or its budget is spent")
        return StopDecision(False, False, "continue")

    def report(self) -> Report:
        decision = self.stop()
        return Report(decision.reason, decision.converged, [self.best])


def build(context, options: CoordinateOptions) -> CoordinateSearch:
    """The search from the nominal model inside the solver's box (:mod:`.registry`)."""
    return CoordinateSearch(context.nominal, context.residual, *context.solver_box, options, context.memo)
