"""Any strategy of the registry as Prefect stages: a subflow per iteration, a task per FE stage and per step.

:func:`run_strategy` builds the run's strategy (:mod:`strategies.registry`) under the driver
(:class:`tasks.driver.Driver`) and runs it: each iteration is a subflow ``<round word>-<k>`` (``iteration-3``,
``cycle-2``), each of its FE stages a task ``iteration-<k>-<stage>`` (the batches of that stage, the strategy
told after each), each of the strategy's steps a task ``iteration-<k>-<step>`` (run inside the FE stage whose
results it follows). A resumed run replays the strategy through what is stored (no FE run, no step computed
again); the printout after each iteration says what its FE stages did.
"""

from __future__ import annotations

from prefect import flow, task
from prefect.cache_policies import NO_CACHE
from prefect.context import FlowRunContext

from strategies import registry
from strategies.base import close_strategy
from tasks.driver import Driver
from tasks.runstore import RunStore

__all__ = ["run_strategy"]


def _as_task(iteration: int, name: str, fn):
    """A step as a Prefect task of the running flow (a plain call outside one)."""
    if FlowRunContext.get() is None:
        return fn()
    return task(fn, name=name, task_run_name=f"iteration-{iteration}-{name}", cache_policy=NO_CACHE)()


@task(name="fe", cache_policy=NO_CACHE)
def fe_stage(driver: Driver, batch):
    """The batches of one FE stage; returns the first batch of the next stage (None: the strategy stopped)."""
    return driver.run_stage(batch)


@flow(name="iteration", validate_parameters=False, log_prints=True)
def iteration_flow(driver: Driver, batch):
    """The FE stages (and steps) of one iteration; returns the first batch of the next (None: stopped)."""
    k = batch.iteration
    while batch is not None and batch.iteration == k:
        batch = fe_stage.with_options(name=batch.stage, task_run_name=f"iteration-{k}-{batch.stage}")(driver, batch)
    print(driver.describe(k))
    return batch


def run_strategy(problem, config, store: RunStore) -> tuple[int, dict]:
    """The run's strategy to its end; returns (its iterations, its outcome: ``stop_reason``, ``converged``,
    ``candidates``, ``intervals`` and its summary fields)."""
    spec = registry.get(config.strategy)
    driver = Driver(store, problem, config, spec, wrap=_as_task)
    try:
        batch = driver.first()
        while batch is not None:
            word = spec.round_word
            batch = iteration_flow.with_options(name=word, flow_run_name=f"{word}-{batch.iteration}")(driver, batch)
        return driver.outcome()
    finally:
        close_strategy(driver.strategy)  # a strategy in a thread of its own (strategies.callback) ends with the run
