"""Recompute one stage of a finished or stopped run from its stored inputs: ``python -m flows.update rerun``.

The stage runs again on the run's stored results into a new folder beside the original,
``iteration=<k>/stage=<stage>.rerun-<label>-<UTC time>/``; the original stage and everything after it are
untouched. Which stages, by strategy:

* the paper's loop (``adaptive``, ``conventional``): ``train`` (``--trainer``), ``predict``, ``intervals``;
* the hybrid (the default): ``local``, ``global`` (their stored FE runs are read back where the rerun asks
  for the same points; other points run on the FE model, into the rerun's folder), ``check`` (``--noise``),
  ``intervals`` (``--noise``, ``--posterior-fe``).

The run's problem (model, measured data, box) is resolved once from its manifest, as for the run itself.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from flows import problem as problems
from flows.config import ConfigError, UpdateConfig, stored_settings
from tasks import hybrid as hybrid_tasks
from tasks import paper as paper_tasks
from tasks.intervals import INTERVALS_STAGE, intervals_task
from tasks.runstore import RunStore

__all__ = ["rerun_stage", "rerunnable", "run_problem"]


def rerunnable(strategy: str) -> tuple[str, ...]:
    """The stages a rerun recomputes for runs of ``strategy``."""
    own = hybrid_tasks.RERUNNABLE if strategy == "hybrid" else paper_tasks.RERUNNABLE
    return (*own, INTERVALS_STAGE)


#: The problem of a stored run (kept under its old name for the tests and benchmarks that use it).
run_problem = problems.stored_problem


def rerun_stage(run_root: Path, iteration: int, stage: str, trainer: str | None = None, noise: float | None = None,
                posterior_fe: int | None = None) -> Path:
    """Recompute ``stage`` of ``iteration`` into a new folder beside it; returns that folder.

    ``trainer``, ``noise`` and ``posterior_fe`` replace the run's settings for the rerun (None: the run's).
    """
    store = RunStore(run_root)
    manifest = store.read_manifest()
    if manifest is None:
        raise ConfigError(f"{run_root}: no manifest.json; is this a run folder?")
    config = UpdateConfig(**stored_settings(manifest["config"]))
    allowed = rerunnable(config.strategy)
    if stage not in allowed:
        raise ConfigError(f"stage {stage!r} cannot be rerun for a run of the {config.strategy} strategy; choose one "
                          f"of {', '.join(allowed)}")
    if not store.stage_dir(iteration, stage).is_dir() or not store.is_finished(iteration, stage):
        raise ConfigError(f"{run_root}: iteration {iteration} has no finished '{stage}' stage to rerun")
    config = config.replace(**{k: v for k, v in (("trainer", trainer), ("noise", noise),
                                                 ("posterior_fe", posterior_fe)) if v is not None})
    label = trainer or (f"noise{noise:g}" if noise is not None else config.trainer)
    name = f"{stage}.rerun-{label}-{dt.datetime.now(dt.timezone.utc).strftime('%Y%m%dT%H%M%SZ')}"
    problem = run_problem(config, manifest, store.manifest_path)
    root = str(store.root)
    if stage == "train":
        paper_tasks.train_task.fn(root, problem, config, iteration, trainer=config.trainer, output_stage=name)
    elif stage == "predict":
        paper_tasks.predict_task.fn(root, problem, config, iteration, output_stage=name)
    elif stage == hybrid_tasks.LOCAL_STAGE:
        hybrid_tasks.local_task.fn(root, problem, config, iteration, list(problem.nominal), output_stage=name)
    elif stage == hybrid_tasks.GLOBAL_STAGE:
        minima = [mn["x"] for k in range(1, iteration) for s in (hybrid_tasks.LOCAL_STAGE, hybrid_tasks.GLOBAL_STAGE)
                  if store.is_finished(k, s) for mn in store.stage_info(k, s)["minima"]]
        hybrid_tasks.global_task.fn(root, problem, config, iteration, minima, output_stage=name)
    elif stage == hybrid_tasks.CHECK_STAGE:
        hybrid_tasks.check_task.fn(root, problem, config, iteration, output_stage=name)
    else:  # the intervals, from where the run's intervals started
        start = store.read_table(iteration, INTERVALS_STAGE)["start"].to_numpy(float)
        intervals_task.fn(root, problem, config, iteration, np.asarray(start), output_stage=name)
    return store.stage_dir(iteration, name)
