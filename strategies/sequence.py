"""Strategies one after another, as one strategy: the ``adaptive`` strategy is the paper's loop, then the polish.

``Sequence(first, then, titles=("MRGP loop", "polish"))`` runs ``first`` until it stops, then ``then(first)``
(a strategy built from where the first ended, e.g. the polish from the loop's best FE run; None: nothing
follows) until that stops. Its report joins theirs: the reasons, each under its title; converged when either
part converged (each judges the run's best error so far); the candidates of both (None: all); the summary
fields of both; the intervals when the last part ends at a least-squares point.
"""

from __future__ import annotations

from collections.abc import Callable

from .base import Batch, Report, StopDecision, report_of

__all__ = ["Sequence"]


class Sequence:
    """``first``, then the strategies ``then`` build, one after another (:mod:`.base`)."""

    def __init__(self, first, *then: Callable, titles: tuple = ()):
        self.parts = [first]
        self._then = list(then)
        self.titles = tuple(titles)

    @property
    def current(self):
        return self.parts[-1]

    def stop(self) -> StopDecision:
        decision = self.current.stop()
        while decision.stop and self._then:
            following = self._then.pop(0)(self.current)
            if following is None:
                break
            self.parts.append(following)
            decision = following.stop()
        return decision

    def propose(self) -> Batch:
        return self.current.propose()

    def update(self, batch: Batch, outcomes) -> None:
        self.current.update(batch, outcomes)

    def stage_info(self, iteration: int, stage: str) -> dict:
        out = {}
        for part in self.parts:
            if hasattr(part, "stage_info"):
                out.update(part.stage_info(iteration, stage))
        return out

    def report(self) -> Report:
        reports = [report_of(p) for p in self.parts]
        if len(reports) == 1:
            return reports[0]
        titles = list(self.titles) + [""] * len(reports)
        reason = "; ".join(f"{t}: {r.stop_reason}" if t else r.stop_reason for t, r in zip(titles, reports))
        candidates = None if any(r.candidates is None for r in reports) else sorted(
            {c for r in reports for c in r.candidates})
        fields = {}
        for r in reports:
            fields.update(r.fields)
        iterations = max((r.iterations for r in reports if r.iterations is not None), default=None)
        return Report(reason, any(r.converged for r in reports), candidates, fields, iterations,
                      reports[-1].intervals)
