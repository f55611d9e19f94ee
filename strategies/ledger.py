"""Counting the FE runs of a strategy's rounds against its budget.

A phase of a strategy (:mod:`.hybrid_phases`) is a generator: it yields a request ``(points, jacobian)``
for one round and receives the round's results ``[(Z, dZ or None), ...]``. :class:`.hybrid.Hybrid` admits
every round against the budget first (else :class:`BudgetSpent` is thrown into the phase, which may end on it
or let it through), then records it in the :class:`Ledger`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np


__all__ = ["BudgetSpent", "Ledger"]


class BudgetSpent(Exception):
    """The next round would exceed the budget."""


@dataclass
class Ledger:
    """Counts every FE run, Jacobian and round of a search.

    ``history`` holds ``(round, x, error, with_jacobian, phase)`` in evaluation order; ``responses`` the
    ``(x, Z)`` of every successful FE run (the global phase's emulator learns from them).

    A budget that follows the evidence: past ``max_cost`` a round is still admitted, up to ``cap`` (None: no
    extension), while the current phase's rounds still improve, i.e. the best error of the phase's last
    ``improve_rounds`` rounds is at least ``improve_rtol`` (relative) below the best before them
    (:meth:`improving`). ``phase_start`` is the round after which the current phase began; ``extended`` counts
    the rounds admitted past ``max_cost``.
    """

    residual: object  # the measured data (fe_core.inference.frf_data.FRFData): residual(Z), error(Z)
    max_cost: float
    jacobian_cost: float
    evaluations: int = 0
    jacobians: int = 0
    rounds: int = 0
    spent: float = 0.0
    history: list = field(default_factory=list)
    responses: list = field(default_factory=list)
    cap: float | None = None
    improve_rounds: int = 2
    improve_rtol: float = 0.05
    phase_start: int = 0
    extended: int = 0
    reduced: list = field(default_factory=list)  # per history entry: the result came from a reduced basis

    @property
    def cost(self) -> float:
        """FE-run equivalents spent (as the runs reported them)."""
        return self.spent

    def round_cost(self, jacobian: Sequence[bool]) -> float:
        return sum(self.jacobian_cost if j else 1.0 for j in jacobian)

    def admit(self, jacobian: Sequence[bool]) -> None:
        """Raise :class:`BudgetSpent` when a round of these runs would exceed the budget (past ``max_cost``: the
        cap, or a phase whose rounds no longer improve)."""
        after = self.cost + self.round_cost(jacobian)
        if after <= self.max_cost + 1e-9:
            return
        if self.cap is None or after > self.cap + 1e-9 or not self.improving():
            raise BudgetSpent
        self.extended += 1

    def improving(self) -> bool:
        """The current phase's last ``improve_rounds`` rounds lowered its best error by at least ``improve_rtol``
        (relative) against its best before them (False with fewer rounds than that plus one)."""
        rows = [(r, e) for r, _, e, _, _ in self.history if r > self.phase_start]
        if not rows:
            return False
        last = max(r for r, _ in rows)
        before = [e for r, e in rows if r <= last - self.improve_rounds]
        recent = [e for r, e in rows if r > last - self.improve_rounds]
        if not before or not recent:
            return False
        old, new = min(before), min(recent)
        return bool(np.isfinite(old) and new < (1.0 - self.improve_rtol) * old)

    def record(self, points: Sequence, jacobian: Sequence[bool], results: Sequence,
               phase: str) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """Count one evaluated round; returns ``[(Z, dZ or None), ...]``. A result is ``(Z, dZ[, cost])``:
        ``cost`` in FE-run equivalents, by default 1 or ``jacobian_cost`` with a derivative."""
        self.rounds += 1
        out = []
        for x, j, result in zip(points, jacobian, results):
            Z, dZ = result[0], result[1]
            Z = np.asarray(Z, complex).ravel()
            cost = result[2] if len(result) > 2 else None
            self.evaluations += 1
            self.jacobians += int(j)
            self.spent += float(cost) if cost is not None else (self.jacobian_cost if j else 1.0)
            ok = bool(np.all(np.isfinite(Z)))
            error = self.residual.error(Z) if ok else np.inf
            self.history.append((self.rounds, np.asarray(x, float).copy(), error, j, phase))
            self.reduced.append(bool(getattr(result, "reduced", False)))
            if ok:
                self.responses.append((np.asarray(x, float).copy(), Z))
            out.append((Z, None if dZ is None else np.asarray(dZ, complex)))
        return out

    def best(self) -> tuple[np.ndarray, float]:
        """The best result's point and error; a full-order one when there is any (a reduced basis's result is
        a stand-in until a full-order run confirms it)."""
        errors = np.array([h[2] for h in self.history], float)
        if any(self.reduced) and not all(self.reduced):
            errors = np.where(self.reduced, np.inf, errors)
        i = int(np.argmin(errors))
        return self.history[i][1], self.history[i][2]
