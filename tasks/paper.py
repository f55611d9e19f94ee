"""Prefect tasks of the paper's loop (strategies ``adaptive`` and ``conventional``); each wraps one step of
:mod:`strategies.paper`.

Stages of iteration k (``STAGES``)::

    samples -> fe -> errors -> distribution -> train -> predict -> select
                               (stop check)                        -> samples of k + 1

Every task reads its inputs from the run folder, calls the step, writes its outputs with
:class:`tasks.runstore.RunStore` and returns a small value. A task whose stage is already finished (record
present, checksums intact) reads its result back instead of recomputing it, so a killed run resumes where
it stopped. The logic is reachable without Prefect through ``task.fn(...)``.
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
from prefect import task
from prefect.cache_policies import NO_CACHE

from mrgp_core.modal_outputs import ModalLayout
from strategies import paper as steps
from tasks import record
from tasks.common import beating, done, finish, logger
from tasks.fe_runs import FEStage
from tasks.runstore import RunStore

__all__ = ["STAGES", "paper_options", "samples_task", "fe_task", "errors_task", "distribution_task", "train_task",
           "predict_task", "select_task", "training_data", "residual_matrix", "modal_layout",
           "fe_count", "RERUNNABLE"]

STAGES = steps.STEPS
#: Stages a rerun recomputes from their stored inputs (``python -m flows.update rerun``).
RERUNNABLE = ("train", "predict")


def paper_options(config) -> steps.PaperOptions:
    """The loop's settings from the run's config (keys documented in flows/config.py)."""
    return steps.PaperOptions(q=config.q, s=config.s, z=config.z, w=config.w, threshold=config.threshold,
                              max_iterations=config.max_iterations, max_fe=loop_budget(config),
                              min_distance_factor=config.min_distance_factor, std_floor=config.std_floor,
                              trainer=config.trainer, outputs=config.outputs, emulate=config.emulate,
                              conventional=config.strategy == "conventional",
                              conventional_samples=config.conventional_samples, seed=config.seed)


def uses_polish(config) -> bool:
    """The polish stage follows the adaptive loop (the conventional baseline stays the paper's)."""
    return bool(config.polish) and config.strategy == "adaptive"


def loop_budget(config) -> int:
    """FE runs the MRGP loop may use: the budget minus what is reserved for the polish."""
    return config.max_fe_evaluations - (config.polish_max_fe if uses_polish(config) else 0)


def modal_layout(problem) -> ModalLayout:
    """The emulated outputs' layout for the run's kept values and ``problem.modes`` modes."""
    data = problem.data
    line, channel = data.cells
    omega = 2.0 * np.pi * np.asarray(data.frequencies_hz, float)[line]
    damping = tuple(float(v) for v in problem.model.damping)
    return ModalLayout(omega, np.asarray(channel, int), int(data.amplitude.shape[1]), damping, problem.modes)


# -- the run folder's training data ------------------------------------------------------------------------
def training_data(store: RunStore, iteration: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(sample ids (r,), X (r, m), Y (r, k) relative residuals, overall errors (r,)): every successfully
    FE-evaluated sample of iterations 1..``iteration``."""
    ids, X, Y, E = [], [], [], []
    for k in range(1, iteration + 1):
        samples = store.read_table(k, "samples")
        errs = store.read_table(k, "errors", "errors")
        res = store.read_table(k, "errors", "residuals")
        ok = errs[errs["status"] == "ok"]
        merged = samples.merge(ok[["sample_id", "overall_error"]], on="sample_id")
        ids.append(merged["sample_id"].to_numpy())
        X.append(merged[record.parameter_columns(samples)].to_numpy())
        Y.append(residual_matrix(res, merged["sample_id"]))
        E.append(merged["overall_error"].to_numpy())
    return np.concatenate(ids), np.vstack(X), np.vstack(Y), np.concatenate(E)


def residual_matrix(res: pd.DataFrame, sample_ids) -> np.ndarray:
    """Residual vectors (rows in the order of ``sample_ids``) from a long residual table: columns
    frequency-major, channels fastest (Eq. 5); with complex residuals all real parts, then all imaginary."""
    parts = ["residual_real", "residual_imag"] if "residual_real" in res.columns else ["residual"]
    out = []
    for value in parts:
        wide = res.pivot_table(index="sample_id", columns=["frequency_hz", "sensor"], values=value)
        out.append(wide.sort_index(axis=1).loc[sample_ids].to_numpy())
    return np.hstack(out)


def modal_training_set(store: RunStore, problem, iteration: int):
    """(X (r, m), Y (r, n_outputs), overall errors (r,), layout): the emulated modal outputs of every
    successful FE run of iterations 1..``iteration``, in the order of :func:`training_data`."""
    ids, X, _, E = training_data(store, iteration)
    data = problem.data
    p, n = data.amplitude.shape
    line, channel = data.cells
    resp = record.responses(store, iteration, ids)
    by_id = {int(sid): part.sort_values(["frequency_hz", "sensor"], kind="stable")
             for sid, part in resp.groupby("sample_id", sort=False)}
    counts = {sum(c.startswith("omega2_") for c in by_id[int(sid)].columns) for sid in ids}
    if len(counts) != 1 or 0 in counts:
        raise RuntimeError(f"{store.root}: the FE results hold {sorted(counts)} modes; the modal emulator needs the "
                           "same modes in every FE run (was the run started with emulate = \"errors\"?)")
    modes = counts.pop()
    lay = modal_layout(problem.with_modes(modes))
    Y = np.empty((len(ids), lay.n_outputs))
    for i, sid in enumerate(ids):
        part = by_id[int(sid)]
        Z = (part["real"].to_numpy() + 1j * part["imag"].to_numpy()).reshape(p, n)[line, channel]
        omega2 = np.array([part[f"omega2_{r + 1}"].iloc[0] for r in range(modes)])
        P = np.array([part[f"participation_{r + 1}"].to_numpy()[:n] for r in range(modes)])
        Y[i] = lay.outputs(omega2, P, Z)
    return X, Y, E, lay


def fe_count(store: RunStore, iteration: int) -> int:
    """FE runs of iterations 1..``iteration`` (the polish's included once it has finished)."""
    return int(record.spent(store, iteration)["evaluations"])


# -- the tasks ------------------------------------------------------------------------------------------------
@task(name="samples", task_run_name="iteration-{iteration}-samples", cache_policy=NO_CACHE)
def samples_task(root: str, problem, config, iteration: int) -> int:
    """The FE batch of an iteration: uniform samples first (step c), then the previous selection."""
    store = RunStore(root)
    if not done(store, iteration, "samples"):
        if iteration == 1:
            X = steps.first_samples(paper_options(config), problem.lower, problem.upper, problem.nominal)
            first_id = 0
        else:
            X = store.read_table(iteration - 1, "select")[problem.names].to_numpy()
            first_id = int(store.stage_info(iteration - 1, "select")["next_sample_id"])
        df = pd.DataFrame(X, columns=problem.names)
        df.insert(0, "iteration", np.int64(iteration))
        df.insert(0, "sample_id", np.arange(first_id, first_id + len(df), dtype=np.int64))
        store.write_table(iteration, "samples", "samples", df)
        finish(store, iteration, "samples", ["samples"], {"n": len(df)}, STAGES)
    return int(store.stage_info(iteration, "samples")["n"])


@task(name="fe", task_run_name="iteration-{iteration}-fe", cache_policy=NO_CACHE)
def fe_task(root: str, problem, config, iteration: int) -> int:
    """FE runs of the iteration's samples in parallel (:class:`tasks.fe_runs.FEStage`); returns how many ran
    now (the rest were read back)."""
    store = RunStore(root)
    if done(store, iteration, "fe"):
        return 0
    samples = store.read_table(iteration, "samples")
    stage = FEStage(store, problem, config, iteration, "fe", logger(), modes=problem.modes)
    stage.run(samples["sample_id"], samples[problem.names].to_numpy(), [False] * len(samples))
    stage.write({"n": int(len(samples)), "modes": problem.modes}, STAGES)
    return stage.ran


@task(name="errors", task_run_name="iteration-{iteration}-errors", cache_policy=NO_CACHE)
def errors_task(root: str, problem, config, iteration: int) -> dict:
    """Residuals (Eq. 5, or complex), overall (Eq. 6b) and per-channel (Eq. 15) errors of the iteration's FE
    runs, over the run's kept values."""
    store = RunStore(root)
    if done(store, iteration, "errors"):
        return store.stage_info(iteration, "errors")
    data = problem.data
    runs = store.read_table(iteration, "fe", "runs").sort_values("sample_id", kind="stable")
    resp = store.read_table(iteration, "fe", "responses")
    p, n = data.amplitude.shape
    errors = runs[["sample_id"]].assign(iteration=np.int64(iteration), overall_error=runs["overall_error"],
                                        status=runs["status"])
    for j in range(n):
        errors[f"error_sensor_{j + 1}"] = runs[f"error_sensor_{j + 1}"].to_numpy()
    for sid, msg in zip(runs.loc[runs["status"] != "ok", "sample_id"], runs.loc[runs["status"] != "ok", "message"]):
        logger().warning("iteration %d: FE run of sample %d failed and is excluded: %s", iteration, sid, msg)
    parts = []
    for sid, part in resp.groupby("sample_id", sort=True):
        Z, _ = record.grid(part, p, n, problem.m)
        columns = data.residual_columns(Z)
        parts.append(pd.DataFrame({"sample_id": np.full(columns["residual"].size, sid, dtype=np.int64), **columns}))
    store.write_table(iteration, "errors", "errors", errors.reset_index(drop=True))
    store.write_table(iteration, "errors", "residuals", pd.concat(parts, ignore_index=True))
    ok = errors.loc[errors["status"] == "ok", "overall_error"]
    finish(store, iteration, "errors", ["errors", "residuals"],
           {"best": float(ok.min()) if len(ok) else float("inf"), "failed": int((errors["status"] != "ok").sum()),
            "residual": data.residual, "values": data.n_values}, STAGES)
    return store.stage_info(iteration, "errors")


@task(name="distribution", task_run_name="iteration-{iteration}-distribution", cache_policy=NO_CACHE)
def distribution_task(root: str, problem, config, iteration: int) -> dict:
    """Step f: the sampling distribution of the next candidates, and the minimum distance."""
    store = RunStore(root)
    if not done(store, iteration, "distribution"):
        _, X, _, E = training_data(store, iteration)
        kind, mean, std, d_min = steps.distribution(paper_options(config), iteration, X, E, problem.lower,
                                                    problem.upper)
        df = pd.DataFrame({"parameter": problem.names, "mean": mean, "std": std})
        store.write_table(iteration, "distribution", "distribution", df)
        finish(store, iteration, "distribution", ["distribution"], {"kind": kind, "min_distance": d_min}, STAGES)
    return store.stage_info(iteration, "distribution")


def _previous_hyperparameters(store: RunStore, iteration: int) -> dict | None:
    if iteration > 1 and store.is_finished(iteration - 1, "train"):
        df = store.read_table(iteration - 1, "train", "hyperparameters")
        return dict(zip(df["name"], df["value"]))
    return None


@task(name="train", task_run_name="iteration-{iteration}-train", cache_policy=NO_CACHE, retries=1)
@beating("train (the MRGP's hyper-parameters)")
def train_task(root: str, problem, config, iteration: int, trainer: str | None = None,
               output_stage: str = "train") -> dict:
    """MRGP training on all FE data so far; the hyper-parameters are stored, not the model."""
    store = RunStore(root)
    trainer = trainer or config.trainer
    if not done(store, iteration, output_stage):
        options = paper_options(config)
        if options.modes:
            X, Y, _, layout = modal_training_set(store, problem, iteration)
        else:
            _, X, Y, _ = training_data(store, iteration)
            layout = None
        t0 = time.perf_counter()
        hyper, info = steps.train(options, iteration, X, Y, _previous_hyperparameters(store, iteration), trainer,
                                  layout)
        seconds = time.perf_counter() - t0
        df = pd.DataFrame({"name": list(hyper), "value": [float(v) for v in hyper.values()]})
        store.write_table(iteration, output_stage, "hyperparameters", df)
        finish(store, iteration, output_stage, ["hyperparameters"],
               {"trainer": trainer, "seconds": seconds, "n_train": int(X.shape[0]), **info}, STAGES)
        logger().info("iteration %d, stage train: %s on %d runs in %.2f s", iteration, trainer, X.shape[0], seconds)
        if info["outputs"] == "reduced":
            logger().info("iteration %d, stage train: outputs=%s -> reduced basis, k=%d responses -> r=%d directions "
                          "(%.3f %% of the standardised variance)", iteration, options.outputs, info["n_responses"],
                          info["components"], 100 * info["captured"])
        else:
            logger().info("iteration %d, stage train: outputs=%s -> full MRGP", iteration, options.outputs)
    return store.stage_info(iteration, output_stage)


@task(name="predict", task_run_name="iteration-{iteration}-predict", cache_policy=NO_CACHE)
@beating("predict (the candidates on the MRGP)")
def predict_task(root: str, problem, config, iteration: int, train_stage: str = "train",
                 output_stage: str = "predict") -> dict:
    """Step g: draw ``w`` candidates and predict their overall errors with the trained MRGP."""
    store = RunStore(root)
    if not done(store, iteration, output_stage):
        options = paper_options(config)
        info = store.stage_info(iteration, "distribution")
        d = store.read_table(iteration, "distribution")
        C = steps.candidates(options, iteration, info["kind"], d["mean"].to_numpy(), d["std"].to_numpy(),
                             problem.lower, problem.upper)
        hp = store.read_table(iteration, train_stage, "hyperparameters")
        hyper = dict(zip(hp["name"], hp["value"]))
        fitted_outputs = store.stage_info(iteration, train_stage).get("outputs", "full")
        t0 = time.perf_counter()
        if options.modes:
            X, Y, E, layout = modal_training_set(store, problem, iteration)
            C, predicted = steps.predict(options, C, X, Y, E, hyper, fitted_outputs, layout,
                                         problem.data, problem.solver_box)
        else:
            _, X, Y, E = training_data(store, iteration)
            C, predicted = steps.predict(options, C, X, Y, E, hyper, fitted_outputs)
        df = pd.DataFrame(C, columns=problem.names)
        df.insert(0, "candidate_id", np.arange(len(df), dtype=np.int64))
        df["predicted_error"] = predicted
        store.write_table(iteration, output_stage, "candidates", df)
        finish(store, iteration, output_stage, ["candidates"],
               {"seconds": time.perf_counter() - t0, "best_predicted": float(np.nanmin(predicted))}, STAGES)
    return store.stage_info(iteration, output_stage)


@task(name="select", task_run_name="iteration-{iteration}-select", cache_policy=NO_CACHE)
def select_task(root: str, problem, config, iteration: int) -> dict:
    """Step d: the next FE batch, the best predicted candidates at least a minimum distance apart."""
    store = RunStore(root)
    if not done(store, iteration, "select"):
        cand = store.read_table(iteration, "predict", "candidates")
        evaluated = np.vstack([store.read_table(k, "samples")[problem.names].to_numpy()
                               for k in range(1, iteration + 1)])
        d_min = float(store.stage_info(iteration, "distribution")["min_distance"])
        chosen = steps.select(paper_options(config), cand[problem.names].to_numpy(),
                              cand["predicted_error"].to_numpy(), d_min, evaluated)
        df = cand.iloc[chosen].reset_index(drop=True)
        next_id = int(max(store.read_table(k, "samples")["sample_id"].max() for k in range(1, iteration + 1)) + 1)
        store.write_table(iteration, "select", "select", df)
        finish(store, iteration, "select", ["select"], {"n": len(df), "next_sample_id": next_id}, STAGES)
    return store.stage_info(iteration, "select")
