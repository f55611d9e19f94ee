"""Local when the nominal model suffices, global when the data say it does not (the default strategy).

Every FE run goes out in *rounds* (:class:`.base.Batch`): a batch whose runs may execute in parallel and
which must finish before the next is chosen. A run returns the complex receptance ``Z`` at the k measured
(frequency, channel) values and, where the batch asks for it, its exact derivative ``dZ`` (k, m) (an
adjoint on the FE model, :mod:`fe_core.solvers.sensitivity`; its cost in FE-run equivalents is
``jacobian_cost``). Cycle k is iteration k of the run folder:

1. **Local phase** (cycle 1, stage ``local``, :func:`.hybrid_phases.local_phase`): Gauss-Newton from the
   nominal model with exact derivatives, one FE run with its Jacobian per round.
2. **Check** (step ``check``, :func:`.hybrid_check.check`): is what is left at the phase's best minimum noise?
3. **Evidence** (issue 28): when cycle 1's check finds structure, the run stops if the local fit's misfit beyond the
   noise is within the model's own error (status "own error", converged: no larger than one mode half a per cent
   off in frequency, :func:`fe_core.closure.evidence.own_error_at`); else the effect library is screened at the nominal
   model and at the local fit (step ``evidence`` of iteration 1, :func:`fe_core.closure.evidence.screen_points`);
   when the first global round's check finds structure too, at its best basin, and the best effect is weighed
   against the best basin found (step ``weigh`` of iteration 2): ``closure`` ends the search for basins (the
   reported point is the FE run where the effect was screened, where the closure starts), ``basins`` goes on.
   A large model's evidence is weighed already after the local phase (``weigh_early``, step ``weigh`` of iteration
   1, against the local fit): its global round is 20 FE runs of a minute or more each.
4. **Global phase** (cycle k > 1, stage ``global``, :func:`.hybrid_phases.global_phase`): space-filling
   points, the MRGP emulator (step ``emulator``), parallel Gauss-Newton runs from its best candidates; its
   best end point is checked again. Another cycle follows while the check finds structure, the last phase did
   not end on the budget, a space-filling round and a Jacobian still fit the budget, and the last cycle found a
   better basin than those before it (``basin_rtol``; else, where the best basin is near, ``basin_near``, the run
   stops with status "basin").

At the end (:meth:`Hybrid.report`) the reported point is the best FE run; when the last check looked at another
point, the check is made at the reported point, so that the stop reason and the convergence speak of it.
Deterministic for a given seed and FE results (so a stored run replays).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .base import Batch, Evaluate, InMemory, Report, Step, StopDecision, run_loop
from .hybrid_check import Check, check
from .hybrid_phases import HybridOptions, Minimum, global_phase, local_phase
from .ledger import BudgetSpent, Ledger

__all__ = ["HybridOptions", "Ledger", "Minimum", "Check", "Hybrid", "HybridResult", "local_phase",
           "check", "global_phase", "hybrid", "BudgetSpent", "stop_reason", "STAGES", "RERUNNABLE",
           "CAP_FACTOR", "NEXT_CYCLE_MARGIN", "LOCAL_STAGE", "GLOBAL_STAGE", "CHECK_STAGE"]

LOCAL_STAGE, GLOBAL_STAGE, CHECK_STAGE, EVIDENCE_STAGE, WEIGH_STAGE = "local", "global", "check", "evidence", "weigh"
#: The stages of a cycle in the run folder.
STAGES = (LOCAL_STAGE, GLOBAL_STAGE, "emulator", CHECK_STAGE, EVIDENCE_STAGE, WEIGH_STAGE)
#: Stages ``rerun`` recomputes; the FE stages read their stored FE runs back where the rerun asks for the same
#: points.
RERUNNABLE = (LOCAL_STAGE, GLOBAL_STAGE, CHECK_STAGE)
#: A budget that follows the evidence: a phase still running when the budget is spent goes on while its rounds
#: improve its best error (:meth:`.ledger.Ledger.admit`), up to this factor times the budget (600 FE-run
#: equivalents for the plain command's 240; docs/guide/closure-far-off.md).
CAP_FACTOR = 2.5
#: Another cycle starts only while its space-filling round and this many FE-run equivalents more (one FE run
#: with its Jacobian at the default cost) fit the budget.
NEXT_CYCLE_MARGIN = 2.5


def _minimum_info(minimum: Minimum) -> dict:
    return {"x": [float(v) for v in minimum.x], "error": float(minimum.error), "status": minimum.status}


def stop_reason(iteration: int, status: str, last_check: dict, reported: tuple | None = None,
                at_best: Check | None = None) -> tuple[str, bool]:
    """(why the run stopped, whether it converged): the last cycle's phase ``status`` and check, or, when the
    reported point (``reported``: (sample id, its cycle, its overall error)) is not the one the last check looked
    at, the check at the reported point (``at_best``)."""
    where = f"cycle {iteration} ({'local' if iteration == 1 else 'global'}): {status}"
    if at_best is None:
        return f"{where}; check: {last_check['reason']}", bool(last_check["at_floor"])
    sid, cycle, error = reported
    return (f"{where}; the reported point, sample {sid} of cycle {cycle} (overall error {error:.4%}): "
            f"{at_best.reason}", bool(at_best.at_floor))


class Hybrid:
    """The strategy (:class:`.base.Strategy`): local phase, check, evidence, global cycles.

    ``data`` is the measured data (:class:`fe_core.inference.frf_data.FRFData`): its kept values, their
    residual, where they sit; the FE runs give the model at its kept values, shape (k,).
    ``screen_model() -> (model or None, why)``: the model the effect screens see through the data's channels
    (:func:`fe_core.closure.evidence.screen_points`; None: no evidence, the cycles go on while the check finds
    structure); ``names``: the parameters; ``memo``: where the steps go.
    """

    def __init__(self, x0: np.ndarray, data, lower: np.ndarray, upper: np.ndarray,
                 options: HybridOptions = HybridOptions(), screen_model=None, names=None, memo=None):
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.x0 = np.clip(np.asarray(x0, float), self.lower, self.upper)
        self.residual = data
        self.options, self.screen_model = options, screen_model
        self.names = list(names) if names is not None else [f"alpha_{i + 1}" for i in range(self.lower.size)]
        self.memo = memo if memo is not None else InMemory()
        self.ledger = Ledger(self.residual, options.max_cost, options.jacobian_cost, cap=options.cap,
                             improve_rounds=options.improve_rounds, improve_rtol=options.improve_rtol)
        self.minima: list[Minimum] = []
        self.checks: list = []  # (best minimum or None, Check) per cycle
        self.check_infos: list[dict] = []  # the check steps' records
        self.phases: dict[int, dict] = {}  # cycle -> its FE stage's record
        self.runs: list = []  # per request: (cycle, x, Z or None, overall error)
        self.evidence = self.decision = None  # the evidence and weigh steps' records
        self.status = "budget"
        self.cycle = 0
        self._done = False
        self._label, self._stage = "local", LOCAL_STAGE
        self._start = (0, 0)  # ledger rounds and extensions before the current phase
        self._phase = local_phase(self.ledger, self.x0, self.lower, self.upper, options)
        self._request = None
        self._advance(lambda: next(self._phase))

    @property
    def iteration(self) -> int:
        return self.cycle + 1

    # -- the phases as one sequence of rounds --------------------------------------------------------
    def _advance(self, step) -> None:
        """Move the current phase on (``step()`` returns its next request); past its end, check and start
        the next phase; stop when the check finds noise, nothing was found or the budget is spent."""
        while True:
            try:
                points, jacobian = step()
            except StopIteration as end:
                found = end.value if isinstance(end.value, list) else [end.value]
                if self._end_of_phase(found):
                    return
                step = lambda: next(self._phase)  # noqa: E731
                continue
            except BudgetSpent:  # the phase could not start (its first rounds did not fit): it ends without minimum
                if self._end_of_phase([]):
                    return
                step = lambda: next(self._phase)  # noqa: E731
                continue
            jacobian = [bool(j) for j in jacobian]
            if not len(points):
                step = lambda: self._phase.send([])  # noqa: E731
                continue
            try:
                self.ledger.admit(jacobian)
            except BudgetSpent as exc:
                step = lambda exc=exc: self._phase.throw(exc)  # noqa: E731
                continue
            self._request = ([np.asarray(x, float).copy() for x in points], jacobian)
            return

    def _end_of_phase(self, found: list) -> bool:
        """Record the phase, check its best minimum, weigh the evidence, start the next cycle or stop. Returns
        True when the strategy is done."""
        k, led = self.iteration, self.ledger
        status = found[0].status if found else "budget"
        errors = [h[2] for h in led.history if h[0] > self._start[0]]
        self.phases[k] = {"status": status, "minima": [_minimum_info(m) for m in found],
                          "extended_rounds": led.extended - self._start[1],
                          "best_error": min(errors or [float("inf")])}
        self.minima += found
        verdict = self.memo.step(k, CHECK_STAGE, lambda: self._check(k, found, status)).info
        self.check_infos.append(verdict)
        self.checks.append((found[0] if found else None,
                            Check(bool(verdict["at_floor"]), verdict["reason"], verdict.get("rms", float("nan")),
                                  _number(verdict.get("sigma")), verdict.get("sigma_source", "none"),
                                  verdict.get("p_chi2", 0.0), verdict.get("noise_model"))))
        if verdict["at_floor"] or not found:
            self.status = ("target" if found and found[0].status == "target" else
                           "floor" if verdict["at_floor"] else "budget")
            return self._finish()
        if k == 1 and verdict.get("minimum") and self.screen_model is not None:
            self.evidence = self.memo.step(k, EVIDENCE_STAGE,
                                           lambda: self._screens(verdict["minimum"]["x"], status)).info
            if (self.evidence.get("own_error") or {}).get("within"):
                self.status = "own error"  # neither a basin nor an effect the closure would accept is left
                return self._finish()
        if (k == 2 or (k == 1 and self.options.weigh_early)) and self.evidence and self.evidence.get("screens"):
            self.decision = self.memo.step(k, WEIGH_STAGE, self._weigh).info
            if self.decision["choice"] == "closure":
                self.status = "effect"
                return self._finish()
        if status == "budget" or led.cost + self.options.space_filling + NEXT_CYCLE_MARGIN >= self.options.max_cost:
            return self._finish()
        if k > 1 and self._no_better_basin(found):
            self.status = "basin"
            return self._finish()
        self.cycle += 1
        led.phase_start = led.rounds
        self._start = (led.rounds, led.extended)
        self._label, self._stage = f"global-{self.cycle}", GLOBAL_STAGE
        self._phase = global_phase(led, self.lower, self.upper, [m.x for m in self.minima], self.options,
                                   self.cycle, self.memo, self.iteration)
        return False

    def _no_better_basin(self, found: list) -> bool:
        """Whether this global cycle's best minimum (``found[0]``) is no better than the best minimum of the cycles
        before it by ``basin_rtol`` (relative overall error), that best being near (``basin_near``)."""
        rtol, near = self.options.basin_rtol, self.options.basin_near
        before = [m.error for m in self.minima[:len(self.minima) - len(found)]]
        if rtol is None or not before or (near is not None and min(before) > near):
            return False
        return found[0].error >= (1.0 - rtol) * min(before)

    def _finish(self) -> bool:
        self._done = True
        return True

    # -- the steps -------------------------------------------------------------------------------------
    def _nearest_run(self, x, cycle: int | None = None) -> int:
        """Request index of the successful FE run (of ``cycle``; None: any) nearest ``x`` (max-norm)."""
        ok = [(i, rx) for i, (c, rx, Z, _) in enumerate(self.runs) if Z is not None and (cycle is None or c == cycle)]
        d = [float(np.max(np.abs(rx - np.asarray(x, float)))) for _, rx in ok]
        return ok[int(np.argmin(d))][0]

    def _check(self, k: int, found: list, status: str) -> Step:
        stage = LOCAL_STAGE if k == 1 else GLOBAL_STAGE
        out = {"stage": stage, "at_floor": False, "reason": f"{stage} stage ended without a minimum ({status})",
               "status": status, "minimum": None}
        if found:
            best = found[0]
            verdict = check(best.Z, self.residual, self.lower.size, self.options)
            out.update({"sample_id": self._nearest_run(best.x, k),
                        "at_floor": bool(verdict.at_floor or best.status == "target"), "reason": verdict.reason,
                        "rms": verdict.rms, "sigma": verdict.sigma if np.isfinite(verdict.sigma) else None,
                        "sigma_source": verdict.sigma_source, "p_chi2": verdict.p_chi2,
                        "noise_model": verdict.noise_model,
                        "minimum": _minimum_info(best), "noise_config": self.options.noise})
        words = "at the floor" if out["at_floor"] else "structure left: global search"
        return Step({CHECK_STAGE: {"at_floor": np.array([out["at_floor"]]), "reason": np.array([out["reason"]])}},
                    out, f"{words} ({out['reason']})")

    def _screens(self, local_x, status: str = "converged") -> Step:
        """The evidence at the local fit: first whether its misfit is the model's own error (when the Gauss-Newton
        run converged; then no screen follows), else the effect screens at the nominal model and at the fit."""
        import time

        from fe_core.closure.evidence import own_error_at, screen_points

        t0 = time.perf_counter()
        model, why = self.screen_model()
        own, fits = None, {}
        if model is not None and status == "converged":
            own, fits["local fit"] = own_error_at(model, self.residual, local_x, self.options.noise,
                                                  self.options.significance)
        screens = [] if model is None or (own is not None and own.within) else screen_points(
            model, self.residual, {"nominal": self.x0, "local fit": np.asarray(local_x, float)}, fits=fits)
        table = {"at": np.array([s.at for s in screens], dtype=object),
                 "effect": np.array([s.effect or "" for s in screens], dtype=object),
                 "location": np.array([s.location or "" for s in screens], dtype=object),
                 **{c: np.array([getattr(s, c) for s in screens], float) for c in ("rss", "rss_alpha", "rss_effect")}}
        note = "; ".join(([own.reason()] if own is not None else []) + [s.describe() for s in screens]
                         + ([why] if why else []))
        return Step({"screens": table}, {"screens": [s.to_dict() for s in screens], "skipped": why,
                                         "own_error": None if own is None else own.to_dict(),
                                         "seconds": time.perf_counter() - t0}, note)

    def _weigh(self) -> Step:
        from fe_core.closure.evidence import Screen, weigh, weigh_round

        found = [c for c in self.check_infos if c.get("sample_id") is not None and c.get("minimum")]
        basins = {int(c["sample_id"]): self.residual.log_rss(self.runs[int(c["sample_id"])][2]) for c in found}
        screens = [Screen.from_dict(s) for s in self.evidence.get("screens", [])]
        model, _ = self.screen_model()
        if found and model is not None:
            best = min(found, key=lambda c: basins[int(c["sample_id"])])
            decision, screens = weigh_round(model, self.residual, screens, best["minimum"]["x"],
                                            basins[int(best["sample_id"])])
        else:  # nothing to screen at: the screens so far against what re-fitting alpha alone leaves
            decision = weigh(screens, float("inf"))
        info = {**decision.to_dict(), "basins": {str(k): v for k, v in basins.items()},
                "screens": [s.to_dict() for s in screens]}
        return Step({WEIGH_STAGE: {"choice": np.array([decision.choice]), "reason": np.array([decision.reason])}},
                    info, f"{decision.choice}: {decision.reason}")

    # -- the strategy interface ------------------------------------------------------------------------
    def propose(self) -> Batch:
        points, jacobian = self._request
        return Batch(np.array(points), tuple(jacobian), self._label, self.iteration, self._stage)

    def update(self, batch: Batch, outcomes: Sequence) -> None:
        first = len(self.ledger.history)
        results = self.ledger.record(list(batch.points), list(batch.jacobian), outcomes, self._label)
        for (_, x, error, _, _), (Z, _) in zip(self.ledger.history[first:], results):
            self.runs.append((self.iteration, x, Z if np.isfinite(error) else None, error))
        self._request = None
        self._advance(lambda: self._phase.send(results))

    def stop(self) -> StopDecision:
        if not self._done:
            return StopDecision(False, False, "continue")
        reason = {"target": "a Gauss-Newton run reached the target", "floor": "the residual is noise",
                  "budget": "the budget is spent or no start was left",
                  "basin": "a global cycle found no better basin than the best found before it",
                  "effect": "a missing effect explains the residual far better than any basin found",
                  "own error": "the misfit beyond the noise is within the model's own error"}[self.status]
        return StopDecision(True, self.status in ("target", "floor", "own error"), reason)

    def stage_info(self, iteration: int, stage: str) -> dict:
        return dict(self.phases.get(iteration, {})) if stage in (LOCAL_STAGE, GLOBAL_STAGE) else {}

    def report(self) -> Report:
        """The run's result: the best FE run, with the stop reason of the last cycle's check (or of a check at the
        reported point); with the evidence for a closure, the FE run where the effect was screened."""
        k = self.iteration
        status, last = self.phases[k]["status"], self.check_infos[-1]
        fields = {} if self.evidence is None else {"evidence": self._evidence_summary()}
        if self.decision is not None and self.decision["choice"] == "closure":
            screen = self.decision["best_screen"]
            sid = self._nearest_run(screen["alpha"])
            reason = (f"cycle {k} ({'local' if k == 1 else 'global'}): {status}; evidence: {self.decision['reason']}; "
                      "the reported point is "
                      f"where the effect was screened ({screen['at']}, sample {sid}): run the closure from it "
                      "(--close-loop, python -m flows.diagnose)")
            return Report(reason, False, [sid], fields, k, intervals=True)
        if self.status == "own error":  # the local fit: converged to what the model can explain
            own = self.evidence["own_error"]
            fields["own_error"] = own
            return Report(f"cycle 1 (local): {status}; check: {last['reason']}; {own['reason']}", True,
                          [int(last["sample_id"])], fields, k, intervals=True)
        ok = [i for i, run in enumerate(self.runs) if run[2] is not None]
        full = [i for i in ok if not self.ledger.reduced[i]]  # a reduced basis's results stand in until confirmed
        ok = full or ok
        if not ok:
            raise ValueError("no successful FE run")
        sid = min(ok, key=lambda i: self.runs[i][3])
        at_best = None
        if last.get("sample_id") != sid:
            # The reported point is not where the last check looked (a later cycle found no better point, or none)
            at_best = check(self.runs[sid][2], self.residual, self.lower.size, self.options)
        reason, converged = stop_reason(k, status, last, (sid, self.runs[sid][0], self.runs[sid][3]), at_best)
        return Report(reason, converged, None, fields, k, intervals=True)

    def _evidence_summary(self) -> dict:
        """``summary.json``'s ``evidence``: the screens and the decision (None when no global round followed)."""
        decision = self.decision
        screens = self.evidence.get("screens", []) if decision is None else decision.get("screens", [])
        screens = [{k: v for k, v in s.items() if k != "seconds"} for s in screens]  # wall time: in the records
        return {"screens": screens, "skipped": self.evidence.get("skipped", ""),
                "choice": None if decision is None else decision["choice"],
                "reason": (self.evidence["own_error"]["reason"] if self.status == "own error" else
                           "no global round with structure followed the screen" if decision is None
                           else decision["reason"]),
                "rss_effect": None if decision is None else decision["rss_effect"],
                "rss_basin": None if decision is None else decision["rss_basin"]}

    def result(self) -> "HybridResult":
        x, error = self.ledger.best()
        led = self.ledger
        return HybridResult(x=x, error=error, status=self.status, evaluations=led.evaluations,
                            jacobians=led.jacobians, rounds=led.rounds, cost=led.cost, minima=self.minima,
                            checks=self.checks, history=led.history, evidence=self.decision)


def _number(v) -> float:
    return float("nan") if v is None else float(v)


@dataclass(frozen=True)
class HybridResult:
    """Outcome of :func:`hybrid`.

    x, error : best point and its overall error (Eq. 6b); status : "target", "floor" (the check found
    noise), "effect" (the evidence: a missing effect, :mod:`fe_core.closure.evidence`), "basin" (a global cycle
    found no better basin) or "budget"; evaluations,
    jacobians, rounds, cost (FE-run equivalents); minima : where Gauss-Newton runs ended; checks : (minimum, Check)
    in order; history : see :class:`Ledger`; evidence : the weigh step's record (None when nothing was weighed).
    """

    x: np.ndarray
    error: float
    status: str
    evaluations: int
    jacobians: int
    rounds: int
    cost: float
    minima: list
    checks: list
    history: list
    evidence: dict | None = None


def hybrid(evaluate: Evaluate, x0: np.ndarray, data, lower: np.ndarray, upper: np.ndarray,
           options: HybridOptions = HybridOptions()) -> HybridResult:
    """Run the whole strategy from ``x0`` (the nominal model); ``evaluate(batch)`` runs one round; ``data`` the
    measured data (:class:`fe_core.inference.frf_data.FRFData`)."""
    strategy = Hybrid(x0, data, lower, upper, options)
    run_loop(strategy, evaluate)
    return strategy.result()
