"""Recompute one stage of a finished or stopped run from its stored inputs: ``python -m flows.update rerun``.

The strategy's stages go through the run's driver (:func:`tasks.driver.rerun`): the strategy is built with the
changed settings and replayed through the stored batches and steps up to the stage, which is computed again into
a new folder beside the original, ``iteration=<k>/stage=<stage>.rerun-<label>-<UTC time>/`` (an FE stage's
stored FE runs are read back where the rerun asks for the same points; other points run on the FE model, into
the rerun's folder; the steps that follow inside the same FE stage, e.g. its check, are written beside theirs).
The original stages are untouched. Which stages: each strategy's entry in :mod:`strategies.registry`
(the paper's loop: ``train`` with ``--trainer``, ``predict``; the hybrid: ``local``, ``global`` with
``--trainer``, ``check`` with ``--noise``), and every strategy's ``intervals`` (``--noise``, ``--posterior-fe``).

The run's problem (model, measured data, box) is resolved once from its manifest, as for the run itself.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from flows import problem as problems
from flows.config import ConfigError, UpdateConfig, stored_settings
from strategies import registry
from tasks import driver
from tasks.intervals import INTERVALS_STAGE, intervals_task
from tasks.runstore import RunStore

__all__ = ["rerun_stage", "rerunnable", "run_problem"]


def rerunnable(strategy: str) -> tuple[str, ...]:
    """The stages a rerun recomputes for runs of ``strategy``."""
    return (*registry.get(strategy).rerunnable, INTERVALS_STAGE)


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
    if stage == INTERVALS_STAGE:  # from where the run's intervals started
        start = store.read_table(iteration, INTERVALS_STAGE)["start"].to_numpy(float)
        intervals_task.fn(str(store.root), problem, config, iteration, np.asarray(start), output_stage=name)
        return store.stage_dir(iteration, name)
    return driver.rerun(store, problem, config, registry.get(config.strategy), iteration, stage, name.split(".", 1)[1])
