"""One driver for every strategy: its batches as FE stages, its steps as stages, resumed by replay.

:class:`Driver` runs any ask-tell strategy (:mod:`strategies.base`) built from the registry
(:mod:`strategies.registry`) against a run folder:

* each batch's FE runs go through :class:`tasks.fe_runs.FEStage` (in parallel, each stored as it finishes) in
  the stage the batch names, ``iteration=<k>/stage=<stage>/``; the request index is the sample id (0, 1, ...
  in the order the strategy asks); when the strategy moves to another stage or stops, the stage writes the run
  record (``runs.parquet``, ``responses.parquet``: :mod:`tasks.record`) with the strategy's info about it;
* the strategy's named steps go through :class:`StoredMemo`: each is a stage of its own (its tables and record,
  ``iteration=<k>/stage=<name>/``);
* on resume the strategy is built again and replayed from its first batch: every FE run it asks for again is
  read back from its stored result (no FE run), every step from its stage. A step is read back only when
  everything that came before it is what it was computed from (a SHA-256 of the FE results and the steps so far,
  kept in the step's record as ``inputs``); else it is computed again.

``rerun`` goes through the same driver (:func:`rerun`): the stored batches and steps are replayed up to the
stage asked for, which is computed again with the changed settings into ``stage=<name>.rerun-<label>-<time>``
beside the original (with the steps of its iteration that follow it inside the same FE stage), nothing else
written. The Prefect composition (a subflow per iteration, a task per FE stage and per step) is
``flows/drive.py``.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd

from strategies.base import Step, close_strategy, jsonable, report_of
from tasks.common import heartbeat, logger
from tasks.context import context
from tasks.fe_runs import FEStage
from tasks.runstore import RunStore

__all__ = ["StoredMemo", "Driver", "rerun", "RerunDone"]


def _columns(table: pd.DataFrame) -> dict:
    return {c: table[c].to_numpy() for c in table.columns}


def _timeless(obj):
    """``obj`` without its ``seconds`` entries (wall times are not results)."""
    if isinstance(obj, dict):
        return {k: _timeless(v) for k, v in obj.items() if k != "seconds"}
    if isinstance(obj, list):
        return [_timeless(v) for v in obj]
    return obj


class RerunDone(Exception):
    """The stage a rerun asked for is written (``path``)."""

    def __init__(self, path: Path):
        super().__init__(str(path))
        self.path = path


class StoredMemo:
    """A strategy's steps as stages of the run folder (:class:`strategies.base.Memo`).

    ``wrap(iteration, name, fn)`` runs a step's computation (the Prefect composition makes it a task);
    ``rerun``: (iteration, stage, suffix) of a rerun (:func:`rerun`).
    """

    def __init__(self, store: RunStore, wrap=None, rerun: tuple | None = None, where=None):
        self.store, self.rerun, self.active = store, rerun, False
        self.wrap = wrap or (lambda iteration, name, fn: fn())
        self.where = where or (lambda iteration, name: (iteration, name))
        self.digest = hashlib.sha256()
        self.steps: list[tuple[int, str]] = []

    def absorb(self, outcomes) -> None:
        """Count a batch's results in what later steps are computed from."""
        for out in outcomes:  # tasks.fe_runs.FEStage.outcomes: Z, dZ or None, cost, modes or None
            for part in (out.Z, out.dZ, *(out.modes or ())):
                if part is not None:
                    self.digest.update(np.ascontiguousarray(part).tobytes())

    def _read(self, iteration: int, stage: str) -> Step:
        tables = {n: _columns(self.store.read_table(iteration, stage, n)) for n in self.store.stage_files(iteration,
                                                                                                           stage)}
        info = {k: v for k, v in self.store.stage_info(iteration, stage).items() if k != "inputs"}
        return Step(tables, info)

    def _write(self, iteration: int, stage: str, done: Step, inputs: str | None) -> Step:
        for name, cols in done.tables.items():
            self.store.write_table(iteration, stage, name, pd.DataFrame({c: np.asarray(v) for c, v in cols.items()}))
        info = jsonable(done.info)
        self.store.finish(iteration, stage, list(done.tables), {**info, **({"inputs": inputs} if inputs else {})})
        return self._read(iteration, stage)

    def step(self, iteration: int, name: str, compute) -> Step:
        log = logger()
        self.steps.append((int(iteration), name))
        if self.rerun is not None:
            return self._rerun_step(iteration, name, compute)
        iteration, name = self.where(int(iteration), name)
        inputs = self.digest.hexdigest()
        if self.store.is_finished(iteration, name):
            if self.store.stage_info(iteration, name).get("inputs") == inputs:
                log.info("iteration %d, stage %s: finished earlier, read back", iteration, name)
                return self._absorb_step(iteration, name, self._read(iteration, name))
            log.warning("iteration %d, stage %s: what it was computed from has changed; computed again", iteration,
                        name)
        t0 = time.perf_counter()
        with heartbeat(f"iteration {iteration}, stage {name}"):
            done = self.wrap(iteration, name, compute)
        log.info("iteration %d, stage %s: %s%s", iteration, name, done.note or "done",
                 f" ({time.perf_counter() - t0:.2f} s)" if not done.note else "")
        return self._absorb_step(iteration, name, self._write(iteration, name, done, inputs))

    def _absorb_step(self, iteration: int, name: str, step: Step) -> Step:
        record = self.store._record(iteration, name) or {}
        self.digest.update(json.dumps({"files": record.get("files"), "info": _timeless(step.info)}, sort_keys=True,
                                      default=str).encode())
        return step

    def _rerun_step(self, iteration: int, name: str, compute) -> Step:
        k, stage, suffix = self.rerun
        if (iteration, name) == (k, stage):
            self.active = True
        if not self.active or iteration != k:
            if self.store.is_finished(iteration, name):
                return self._read(iteration, name)
            return jsonable_step(compute())  # not stored (the rerun's settings reach it first): kept in memory
        out = f"{name}.{suffix}"
        with heartbeat(f"iteration {iteration}, stage {out}"):
            done = compute()
        step = self._write(iteration, out, done, None)
        logger().info("iteration %d, stage %s: %s", iteration, out, done.note or "done")
        if (iteration, name) == (k, stage):
            raise RerunDone(self.store.stage_dir(iteration, out))
        return step


def jsonable_step(done: Step) -> Step:
    return Step({t: {c: np.asarray(v) for c, v in cols.items()} for t, cols in done.tables.items()},
                jsonable(done.info), done.note)


class Driver:
    """Runs one strategy of the registry against a run folder (see the module docstring).

    ``spec``: its :class:`strategies.registry.StrategySpec`; ``config``: the run's settings (its options and the
    FE backend's); ``wrap``: how a step is run (:class:`StoredMemo`); ``rerun``: (iteration, stage, suffix).

    Another kind of FE run than the FRF (the modal update's eigen-solves, :mod:`tasks.modal_stages`): ``make(memo)``
    builds the strategy, ``stages(iteration, stage, logger, modes, replay_only)`` gives the object that runs and
    stores a stage's evaluations (the interface of :class:`tasks.fe_runs.FEStage` the driver uses: ``run``,
    ``outcomes``, ``write``, ``rows``, ``rounds``, ``ran``, ``replayed``, ``stored``, ``replay_only``,
    ``logger``, ``stage``), ``where(iteration, stage)`` maps the strategy's stages to the run folder's.
    """

    def __init__(self, store: RunStore, problem, config, spec, wrap=None, rerun: tuple | None = None, make=None,
                 stages=None, where=None):
        self.store, self.problem, self.config, self.spec, self.rerun = store, problem, config, spec, rerun
        self.where = where or (lambda iteration, stage: (iteration, stage))
        self.memo = StoredMemo(store, wrap, rerun, self.where)
        self.stages = stages
        self.strategy = make(self.memo) if make is not None else spec.make(context(problem, self.memo), config)
        self.next_id = 0
        self.last_iteration = 0
        self.fe = None  # the open FE stage: (iteration, stage, FEStage, t0, stored record's evaluations or None)
        self.closed: list[tuple[int, str]] = []

    # -- the loop ---------------------------------------------------------------------------------------------
    def first(self):
        """The strategy's first batch (None: it stops before any)."""
        return None if self.strategy.stop().stop else self.strategy.propose()

    def step(self, batch):
        """One batch: its FE runs, the strategy told; returns the next batch (None: the strategy stopped)."""
        fe = self._open(batch)
        ids = list(range(self.next_id, self.next_id + len(batch)))
        self.next_id += len(batch)
        self.last_iteration = max(self.last_iteration, int(batch.iteration))
        ran = fe.ran
        frames = fe.run(ids, batch.points, batch.jacobian)
        if fe.ran > ran:
            fe.logger.info("iteration %d, stage %s: round %d, %d FE runs (%d with Jacobian)", batch.iteration,
                           fe.stage, fe.rounds, len(batch), sum(map(bool, batch.jacobian)))
        outcomes = fe.outcomes(frames, batch.jacobian)
        self.memo.absorb(outcomes)
        self.strategy.update(batch, outcomes)
        following = None if self.strategy.stop().stop else self.strategy.propose()
        if following is None or (following.iteration, following.stage) != (batch.iteration, batch.stage):
            self._close()
        return following

    def run_stage(self, batch):
        """Every batch of ``batch``'s FE stage; returns the first batch of another stage (None: stopped)."""
        where = (batch.iteration, batch.stage)
        following = batch
        with heartbeat(f"iteration {where[0]}, stage {where[1]}",
                       lambda: f"{self.fe[2].rounds} rounds, {len(self.fe[2].rows)} FE runs so far" if self.fe else ""):
            while following is not None and (following.iteration, following.stage) == where:
                following = self.step(following)
        return following

    def run(self):
        """The whole strategy without Prefect; returns :meth:`outcome`. A strategy running in a thread of its own
        (:mod:`strategies.callback`) is closed however the run ends (an FE run raised, a rerun's stage reached)."""
        try:
            batch = self.first()
            while batch is not None:
                batch = self.step(batch)
            return self.outcome()
        finally:
            close_strategy(self.strategy)

    # -- FE stages ----------------------------------------------------------------------------------------------
    def _open(self, batch) -> FEStage:
        where = (int(batch.iteration), batch.stage)
        if self.fe is not None and self.fe[:2] == where:
            return self.fe[2]
        if where in self.closed:
            raise RuntimeError(f"{self.spec.name}: iteration {where[0]}, stage {where[1]} asked for again after it "
                               "was closed (a strategy's rounds of one stage must be consecutive)")
        k, stage = self.where(*where)
        modes = self.problem.modes if batch.modes else 0
        log = logger()
        if self.stages is not None:
            fe = self.stages(k, stage, log, modes, False)
        elif self.rerun is not None and where == self.rerun[:2]:  # the rerun's own stage: beside the original
            fe = FEStage(self.store, self.problem, self.config, k, f"{stage}.{self.rerun[2]}", log, modes)
            fe.borrow(stage)
            self.memo.active = True
        elif self.rerun is not None:  # before it: the stored FE runs, nothing run, nothing written
            fe = FEStage(self.store, self.problem, self.config, k, f"{stage}.replay", log, modes, replay_only=True)
            fe.borrow(stage)
        else:
            fe = FEStage(self.store, self.problem, self.config, k, stage, log, modes)
        stored = (self.store.stage_info(k, stage).get("evaluations") if self.rerun is None
                  and self.store.is_finished(k, stage) else None)
        self.fe = (*where, fe, time.perf_counter(), stored)
        return fe

    def _close(self) -> None:
        k, stage, fe, t0, stored = self.fe
        self.fe = None
        self.closed.append((k, stage))
        info = self.strategy.stage_info(k, stage) if hasattr(self.strategy, "stage_info") else {}
        k, stage = self.where(k, stage)
        if fe.replayed:
            fe.logger.info("iteration %d, stage %s: %d FE runs read back from the run folder", k, fe.stage, fe.replayed)
        if fe.replay_only:
            return
        if stored == len(fe.rows) and fe.ran == 0 and not fe.stored:  # finished before and replayed as it was
            return
        fe.write({**info, "seconds": time.perf_counter() - t0})
        if self.rerun is not None:
            raise RerunDone(self.store.stage_dir(k, fe.stage))

    # -- the result ------------------------------------------------------------------------------------------
    def outcome(self) -> tuple[int, dict]:
        """(the run's iterations, its outcome for the summary: ``stop_reason``, ``converged``, ``candidates``,
        ``intervals`` and the strategy's summary fields)."""
        report = report_of(self.strategy)
        iterations = report.iterations or self.last_iteration
        return iterations, {"stop_reason": report.stop_reason, "converged": bool(report.converged),
                            "candidates": report.candidates, "intervals": report.intervals, **report.fields}

    def describe(self, iteration: int) -> str:
        """One line on the FE stages of ``iteration`` (for the run's log)."""
        parts = []
        for k, stage in self.closed:
            if k != iteration or not self.store.is_finished(k, stage):
                continue
            info = self.store.stage_info(k, stage)
            runs = self.store.read_table(k, stage, "runs")
            ok = runs.loc[runs["status"] == "ok", "overall_error"]
            status = f" {info['status']}" if "status" in info else ""
            parts.append(f"{stage}{status}, best overall error {ok.min() if len(ok) else float('inf'):.4%} after "
                         f"{info['evaluations']} FE runs ({info['jacobians']} with Jacobian) in {info['rounds']} rounds")
        return f"{self.spec.round_word} {iteration}: " + ("; ".join(parts) or "no FE runs")


def rerun(store: RunStore, problem, config, spec, iteration: int, stage: str, suffix: str) -> Path:
    """Recompute ``stage`` of ``iteration`` with ``config`` into ``stage=<stage>.<suffix>``; returns that folder."""
    driver = Driver(store, problem, config, spec, rerun=(int(iteration), stage, suffix))
    try:
        driver.run()
    except RerunDone as done:
        return done.path
    raise RuntimeError(f"{store.root}: the {spec.name} strategy did not reach iteration {iteration}, stage {stage} "
                       "when replayed")
