"""The modal update's Gauss-Newton fit under the one driver: each start's evaluations a stored stage.

:func:`run_fit` runs :class:`strategies.modal_fit.ModalFitStrategy` with :class:`tasks.driver.Driver`; its FE
stages are ``fit-start-<k>`` of ``iteration=1`` (the fit's start k; the final evaluation at the best end point
goes with the last start), run and stored by :class:`ModalFitEvaluations`: per evaluation the point, whether
the Jacobian was asked, the eigen-solves and Jacobians it cost, the pairing it found and the swaps it tracked
(table ``evaluations``), and the residual vector with its Jacobian (table ``residuals``, long: one row per
residual entry). A resumed run builds the strategy again; every evaluation it asks for again (the same point,
the same Jacobian flag, in the same order: scipy is deterministic) is read back (no eigen-solve), the first
that differs and all after it in that stage are computed. The FE runs computed go to ``modal_runs.jsonl``
labelled with their stage. The fit's own stage (``fit``, :func:`tasks.modal_stages.fit_task`) records the result.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from strategies.base import Outcome
from strategies.modal_fit import ModalFitStrategy, stage_of
from tasks import modal
from tasks.runstore import RunStore

__all__ = ["ModalFitEvaluations", "run_fit", "fit_stage"]

ITERATION = 1


def fit_stage(start: int) -> str:
    """The run folder's stage of the fit's start ``start``'s evaluations."""
    return f"fit-{stage_of(start)}"


class _Evaluation:
    """One evaluation of the modal residual: the point, Jacobian asked, r (n,), J (n, p) or None, the
    eigen-solves and Jacobians it cost, its pairing (JSON-able dict) and the swaps it tracked."""

    __slots__ = ("x", "jacobian", "r", "J", "solves", "jacobians", "pairing", "swaps")

    def __init__(self, x, jacobian, r, J, solves, jacobians, pairing, swaps):
        self.x, self.jacobian, self.r, self.J = x, bool(jacobian), r, J
        self.solves, self.jacobians, self.pairing, self.swaps = int(solves), int(jacobians), pairing, list(swaps)


class ModalFitEvaluations:
    """One start's evaluations of the modal fit (module docstring), the FE-stage interface of the driver
    (:class:`tasks.driver.Driver`: ``run``, ``outcomes``, ``write``, ``rows``, ``rounds``, ``ran``, ``replayed``,
    ``stored``, ``replay_only``, ``logger``, ``stage``). ``extra``: info for the stage's record (the first
    start's: the active modes and the FE runs before the fit, what a resume needs without an eigen-solve)."""

    def __init__(self, store: RunStore, residual, iteration: int, stage: str, log, extra: dict | None = None):
        self.store, self.residual, self.iteration, self.stage, self.logger = store, residual, iteration, stage, log
        self.extra, self.replay_only, self.stored = dict(extra or {}), False, {}
        self.rows: list = []
        self.results: list[_Evaluation] = []
        self.rounds = self.ran = self.replayed = 0
        self.previous = self._read() if store.is_finished(iteration, stage) else []

    def _read(self) -> list[_Evaluation]:
        runs = self.store.read_table(self.iteration, self.stage, "evaluations")
        res = self.store.read_table(self.iteration, self.stage, "residuals")
        xs = runs[[c for c in runs.columns if c.startswith("x")]].to_numpy(float)
        jcols = [c for c in res.columns if c.startswith("J")]
        out = []
        for k, row in enumerate(runs.itertuples(index=False)):
            mine = res[res["evaluation"].to_numpy() == k]
            jac = bool(row.jacobian)
            # C order, as computed: the optimiser's algebra on an F-ordered copy may round differently
            out.append(_Evaluation(xs[k], jac, np.ascontiguousarray(mine["r"].to_numpy(float)),
                                   np.ascontiguousarray(mine[jcols].to_numpy(float)) if jac else None, row.solves,
                                   row.jacobians, json.loads(row.pairing), json.loads(row.swaps)))
        return out

    def _compute(self, x, jacobian: bool) -> _Evaluation:
        res = self.residual
        n0, j0, s0, label = res.n_evaluations, res.n_jacobians, len(res.swaps), res.label
        res.label = self.stage  # the FE run's stage in modal_runs.jsonl
        try:
            e = res.evaluate(x, jacobian=jacobian)
        finally:
            res.label = label
        p = e["pairing"]
        pairing = {"test": np.asarray(p.test).tolist(), "model": np.asarray(p.model).tolist(),
                   "f_model": np.asarray(e["f_model"]).tolist(), "mac": np.asarray(e["mac"]).tolist(),
                   "unpaired": list(e["unpaired"])}
        return _Evaluation(np.array(x, float), jacobian, np.array(e["r"], float),
                           np.array(e["J"], float) if jacobian else None, res.n_evaluations - n0,
                           res.n_jacobians - j0, pairing, res.swaps[s0:])

    def _replay(self, e: _Evaluation) -> _Evaluation:
        """A stored evaluation taken as this run's: the residual's swap tracking goes on from its pairing."""
        self.residual.swaps.extend(e.swaps)
        self.residual.last_pairs = (tuple(e.pairing["test"]), tuple(e.pairing["model"]))
        return e

    def run(self, ids, points, jacobian) -> list:
        self.rounds += 1
        out = []
        for i, x, jac in zip(ids, np.asarray(points, float), jacobian):
            k = len(self.results)
            stored = self.previous[k] if k < len(self.previous) and self.ran == 0 else None
            if stored is not None and stored.jacobian == bool(jac) and np.array_equal(stored.x, x):
                e = self._replay(stored)
                self.replayed += 1
            else:  # not stored, or another run's (the fit went elsewhere): computed, and all after it
                e = self._compute(x, bool(jac))
                self.ran += 1
            self.rows.append((int(i), e.x))
            self.results.append(e)
            out.append(e)
        return out

    def outcomes(self, frames, jacobian) -> list:
        return [Outcome(e.r, e.J) for e in frames]

    def write(self, info: dict) -> dict:
        p = len(self.results[0].x)
        runs = pd.DataFrame({"id": [i for i, _ in self.rows], **{f"x{j}": [e.x[j] for e in self.results]
                                                                  for j in range(p)},
                             "jacobian": [e.jacobian for e in self.results],
                             "solves": [e.solves for e in self.results],
                             "jacobians": [e.jacobians for e in self.results],
                             "pairing": [json.dumps(e.pairing) for e in self.results],
                             "swaps": [json.dumps(e.swaps) for e in self.results]})
        parts = []
        for k, e in enumerate(self.results):
            J = e.J if e.J is not None else np.full((e.r.size, p), np.nan)
            parts.append(pd.DataFrame({"evaluation": np.full(e.r.size, k), "r": e.r,
                                       **{f"J{j}": J[:, j] for j in range(p)}}))
        self.store.write_table(self.iteration, self.stage, "evaluations", runs)
        self.store.write_table(self.iteration, self.stage, "residuals", pd.concat(parts, ignore_index=True))
        self.store.finish(self.iteration, self.stage, ["evaluations", "residuals"], {
            "evaluations": len(self.results), "fe_runs": sum(e.solves for e in self.results),
            "jacobians": sum(e.jacobians for e in self.results), "ran_now": self.ran, **self.extra, **info})
        modal.write_runs(self.residual, self.store.root)
        return self.store.stage_info(self.iteration, self.stage)


def run_fit(store: RunStore, residual, lower, upper, n_starts: int, seed: int, stated: bool, x0=None):
    """The fit (first start ``x0``, default the nominal model) under the driver, its evaluations stored and
    replayed (module docstring). Returns (:class:`fe_core.modal_update.fit.ModalFit` with the run's counts of
    FE runs and Jacobians, the final evaluation's pairing: ``test``, ``model``, ``f_model``, ``mac``,
    ``unpaired``, and the evaluations computed now, not read back)."""
    from tasks.common import logger
    from tasks.driver import Driver

    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    first = fit_stage(1)
    if store.is_finished(ITERATION, first):  # the modes paired at the nominal model, read back (no eigen-solve)
        before = store.stage_info(ITERATION, first)
        residual.active = np.asarray(before["active"], int)
    else:
        residual.set_active(np.zeros(lower.size))
        before = {"active": residual.active.tolist(), "fe_runs_before": residual.n_evaluations,
                  "jacobians_before": residual.n_jacobians}
    stages: list[ModalFitEvaluations] = []

    def evaluations(iteration, stage, log, modes, replay_only):
        extra = {k: before[k] for k in ("active", "fe_runs_before", "jacobians_before")} if stage == first else {}
        stages.append(ModalFitEvaluations(store, residual, iteration, stage, log, extra))
        return stages[-1]

    strategy = ModalFitStrategy(lower, upper, n_starts, seed, stated, x0=x0, iteration=ITERATION)
    driver = Driver(store, None, None, None, make=lambda memo: strategy, stages=evaluations,
                    where=lambda k, s: (ITERATION, f"fit-{s}"))
    try:
        driver.run()
    finally:
        modal.write_runs(residual, store.root)  # the FE runs computed so far, whatever happened
    fit = strategy.result
    final = stages[-1].results[-1]
    assert np.array_equal(final.x, fit.theta), "the fit's last evaluation is at its end point"
    done = [e for s in stages for e in s.results]
    fit.n_fe_runs = int(before["fe_runs_before"]) + sum(e.solves for e in done)
    fit.n_jacobians = int(before["jacobians_before"]) + sum(e.jacobians for e in done)
    computed = sum(s.ran for s in stages)
    logger().info("modal fit: %s; %d evaluations (%d computed now, %d read back)", strategy.reason(), len(done),
                  computed, len(done) - computed)
    return fit, final.pairing, computed
