"""Prefect tasks of one updating iteration; each wraps one core call.

Every task reads its inputs from the run folder, calls the core, writes its
outputs with :class:`tasks.runstore.RunStore` and returns a small value. A
task whose stage is already finished (record present, checksums intact) reads
its result back instead of recomputing it, so a killed run resumes where it
stopped. The logic is reachable without Prefect through ``task.fn(...)``.

Stages of iteration k (``STAGES``)::

    samples -> fe -> errors -> distribution -> train -> predict -> select
                               (stop check)                        -> samples of k + 1
"""

from __future__ import annotations

import json
import logging
import os
import re
import time
from pathlib import Path

import numpy as np
import pandas as pd
from joblib import delayed
from prefect import task
from prefect.cache_policies import NO_CACHE

import mrgp_core
from mrgp_core import adaptive
from tasks.faults import kill_point
from tasks.fe_backends import run_unordered
from tasks.runstore import RunStore

__all__ = [
    "STAGES",
    "stage_rng",
    "samples_task",
    "fe_task",
    "errors_task",
    "distribution_task",
    "train_task",
    "predict_task",
    "select_task",
    "evaluate_sample",
    "training_data",
    "load_model",
    "parameter_box",
]

#: Environment variable: seconds each FE run sleeps (only for interruption tests).
FE_DELAY_ENV = "MRGP_FE_DELAY_SECONDS"

STAGES = ("samples", "fe", "errors", "distribution", "train", "predict", "select")
_STAGE_CODES = {name: i for i, name in enumerate(STAGES)}

log = logging.getLogger(__name__)


def _logger():
    """Prefect's run logger inside a run (shown in the UI), the module logger outside."""
    try:
        from prefect import get_run_logger

        return get_run_logger()
    except Exception:
        return log


def stage_rng(seed: int, iteration: int, stage: str) -> np.random.Generator:
    """The generator of one stage: a pure function of (seed, iteration, stage), so resumes repeat it."""
    return np.random.default_rng([seed, iteration, _STAGE_CODES[stage]])


def load_model(name: str):
    """The FE model by name or model-file path (built once per process, then cached).

    ``three_plate`` is a shortcut to the benchmark's model file
    ``data/benchmark/model.toml`` (the same FRF as :func:`fe_core.benchmark.three_plate`,
    tested). A model file (``.toml``, relative to the repository when not absolute)
    is cached by the SHA-256 of its own and its mesh/matrix files' contents, so an
    edited file is read again and an unchanged one never is. Raises
    :class:`fe_core.io.ModelFileError` for a file that cannot be used.
    """
    return _model_from_file(MODEL_SHORTCUTS.get(name, name))


#: Model names and the model files they stand for.
MODEL_SHORTCUTS = {"three_plate": "data/benchmark/model.toml"}
#: Models kept per process (a test process may alternate between a few).
_CACHE_SIZE = 4
_MODEL_CACHE: dict[tuple[str, str], object] = {}
_REPO = Path(__file__).resolve().parents[1]


def model_checksum(path: Path) -> str:
    """SHA-256 over the model file and the files it refers to (mesh, matrices, DOF table)."""
    import hashlib

    from fe_core.io import model_files

    digest = hashlib.sha256()
    for f in model_files(path):
        digest.update(f.name.encode() + b"\0" + f.read_bytes())
    return digest.hexdigest()


def model_fingerprint(name: str) -> str | None:
    """The checksum of a model file and its mesh/matrices (None for a built-in model name)."""
    if name in MODEL_SHORTCUTS:
        return None
    path = Path(name) if Path(name).is_absolute() else _REPO / name
    return model_checksum(path)


def _model_from_file(name: str):
    from fe_core.io import read_model

    path = Path(name) if Path(name).is_absolute() else _REPO / name
    key = (str(path), model_checksum(path) if path.exists() else "")
    if key not in _MODEL_CACHE:
        for old in [k for k in _MODEL_CACHE if k[0] == key[0]]:  # an edited file's old model
            del _MODEL_CACHE[old]
        while len(_MODEL_CACHE) >= _CACHE_SIZE:
            del _MODEL_CACHE[next(iter(_MODEL_CACHE))]
        _MODEL_CACHE[key] = read_model(path)
    return _MODEL_CACHE[key]


def parameter_box(config, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The search box, shape (m,) each: the model file's bounds (of alpha, and of gamma where the mass is
    updated) where given, else lower/upper."""
    lower, upper = np.full(m, float(config.lower)), np.full(m, float(config.upper))
    bounds = getattr(load_model(config.model), "parameter_bounds", None)
    if bounds is not None:
        lower = np.where(np.isfinite(bounds[:, 0]), bounds[:, 0], lower)
        upper = np.where(np.isfinite(bounds[:, 1]), bounds[:, 1], upper)
    return lower, upper


#: The FE model refuses alpha = -1 (zero stiffness): local solvers and fixed points stay this far inside.
DOMAIN_MARGIN = 1e-3


def solver_box(config, m: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`parameter_box` with its lower bound at least ``DOMAIN_MARGIN`` inside the domain's edge -1: the box of
    the polish, the hybrid's Gauss-Newton, the intervals and the nominal model as a sample."""
    lower, upper = parameter_box(config, m)
    return np.maximum(lower, -1.0 + DOMAIN_MARGIN), upper


def parameter_names(config) -> list[str]:
    """The run's parameters, the columns of its sample tables: ``alpha_1 .. alpha_m`` and, for segments
    whose mass factor the model file updates, ``gamma_j`` (:attr:`fe_core.ParametricModel.parameter_names`)."""
    return load_model(config.model).parameter_names


#: A parameter column of a run's tables (samples, FE results, polish, candidates).
PARAMETER_COLUMN = re.compile(r"(alpha|gamma)_\d+")


def parameter_columns(table: pd.DataFrame) -> list[str]:
    """The parameter columns of a stored table, in the order written (the model's parameter order)."""
    return [c for c in table.columns if PARAMETER_COLUMN.fullmatch(str(c))]


# -- FE evaluation (runs in joblib worker processes) ---------------------------------------------
def evaluate_sample(model_name: str, sample_id: int, alpha: np.ndarray, freqs_hz: np.ndarray,
                    channels: tuple[np.ndarray, np.ndarray] | None = None, modes: int = 0) -> pd.DataFrame:
    """One FE run: the complex FRF of the measured channels as a long table.

    ``alpha`` is the parameter vector, shape (n_parameters,): the stiffness factors and, when the
    model file updates masses, the mass factors (:meth:`fe_core.ParametricModel.factors`).

    A failed evaluation (for instance a singular system) does not raise: it
    returns rows with NaN responses, ``status = "failed"`` and the reason, so
    the run records it, excludes the sample and goes on.

    ``channels`` = ``(responses, references)`` (0-based model sensor and
    excitation of each measured channel, :attr:`tasks.update_data.UpdateData.channels`)
    gives those channels through one solve with a load column per reference
    (:meth:`fe_core.model.ParametricModel.frf_channels`); None gives the
    model's sensors under its default excitation (``model.frf``).

    ``modes`` > 0 adds the lowest modes the adaptive loop emulates
    (:meth:`fe_core.model.ParametricModel.modal_terms`): columns ``omega2_<r>``
    (the squared circular frequency of mode r, the same on every row) and
    ``participation_<r>`` (its participation in the row's channel), r = 1..modes.

    Returns
    -------
    DataFrame
        Columns ``sample_id, sensor, frequency_hz, real, imag, status, message, seconds, pid``;
        one row per (frequency, channel), frequency-major; ``sensor`` is the
        channel number (1-based; the sensor when ``channels`` is None).
    """
    t0 = time.perf_counter()
    model = load_model(model_name)
    n, p = (model.n_sensors if channels is None else len(channels[0])), len(freqs_hz)
    delay = float(os.environ.get(FE_DELAY_ENV, "0") or 0)
    if delay > 0:  # fault-injection tests need FE runs slow enough to be interrupted
        time.sleep(delay)
    try:
        Z = model.parameter_frf(np.asarray(alpha, dtype=float), freqs_hz, channels)
        if not np.all(np.isfinite(Z)):
            raise FloatingPointError("the FRF has non-finite values")
        if modes:
            omega2, participation = model.modal_terms(np.asarray(alpha, dtype=float), modes, channels)
            if not (np.all(np.isfinite(omega2)) and np.all(np.isfinite(participation))):
                raise FloatingPointError("the modes have non-finite values")
        status, message = "ok", ""
    except (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError) as exc:
        Z = np.full((p, n), np.nan + 1j * np.nan)
        omega2, participation = np.full(modes, np.nan), np.full((modes, n), np.nan)
        status, message = "failed", f"{type(exc).__name__}: {exc}"
    modal = {}
    for r in range(modes):
        modal[f"omega2_{r + 1}"] = np.full(p * n, omega2[r])
        modal[f"participation_{r + 1}"] = np.tile(participation[r], p)
    return pd.DataFrame(
        {
            "sample_id": np.full(p * n, sample_id, dtype=np.int64),
            "sensor": np.tile(np.arange(1, n + 1), p).astype(np.int64),
            "frequency_hz": np.repeat(np.asarray(freqs_hz, float), n),
            "real": Z.real.ravel(),
            "imag": Z.imag.ravel(),
            "status": status,
            "message": message,
            "seconds": time.perf_counter() - t0,
            "pid": os.getpid(),
            **modal,
        }
    )


# -- helpers over the run folder ----------------------------------------------------------------
def training_data(store: RunStore, iteration: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All successfully FE-evaluated samples of iterations 1..``iteration``.

    Returns
    -------
    sample_ids : ndarray, shape (r,)
    X : ndarray, shape (r, m)
    Y : ndarray, shape (r, p * n)
        Relative residuals (Eq. 5 layout).
    errors : ndarray, shape (r,)
        Overall errors (Eq. 6b).
    """
    ids, X, Y, E = [], [], [], []
    for k in range(1, iteration + 1):
        samples = store.read_table(k, "samples")
        errs = store.read_table(k, "errors", "errors")
        res = store.read_table(k, "errors", "residuals")
        ok = errs[errs["status"] == "ok"]
        cols = parameter_columns(samples)
        merged = samples.merge(ok[["sample_id", "overall_error"]], on="sample_id")
        ids.append(merged["sample_id"].to_numpy())
        X.append(merged[cols].to_numpy())
        Y.append(residual_matrix(res, merged["sample_id"]))
        E.append(merged["overall_error"].to_numpy())
    return np.concatenate(ids), np.vstack(X), np.vstack(Y), np.concatenate(E)


def fe_results(store: RunStore, iteration: int) -> dict[int, pd.DataFrame]:
    """Every FE result of iterations 1..``iteration`` by sample id, rows frequency-major, channels fastest."""
    out = {}
    for k in range(1, iteration + 1):
        for sid, part in store.read_table(k, "fe").groupby("sample_id", sort=False):
            out[int(sid)] = part.sort_values(["frequency_hz", "sensor"], kind="stable")
    return out


def residual_matrix(res: pd.DataFrame, sample_ids) -> np.ndarray:
    """Residual vectors (rows in the order of ``sample_ids``) from a long residual table.

    Columns frequency-major, channels fastest (Eq. 5); with complex residuals
    (columns ``residual_real``, ``residual_imag``) all real parts, then all
    imaginary parts (:meth:`tasks.update_data.UpdateData.residuals`).
    """
    parts = ["residual_real", "residual_imag"] if "residual_real" in res.columns else ["residual"]
    out = []
    for value in parts:
        wide = res.pivot_table(index="sample_id", columns=["frequency_hz", "sensor"], values=value)
        out.append(wide.sort_index(axis=1).loc[sample_ids].to_numpy())
    return np.hstack(out)


def _finish(store: RunStore, iteration: int, stage: str, names: list[str], info: dict) -> None:
    """Record a stage as finished; if it replaced a different earlier result, later stages are stale."""
    if store.finish(iteration, stage, names, info):
        store.invalidate_after(iteration, stage, STAGES)


#: Columns of one FE result as written per sample (``evaluate_sample`` plus the parameters).
FE_RESULT_COLUMNS = ("sample_id", "sensor", "frequency_hz", "real", "imag", "status", "message", "seconds", "pid")
FE_LOG = "fe_evaluations.jsonl"


def _append_log(store: RunStore, entry: dict) -> None:
    """Append one line to ``fe_evaluations.jsonl`` with a single write (a kill cannot split it)."""
    path = store.root / FE_LOG
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        lead = b""
        if os.fstat(fd).st_size:  # a line cut short by a crash of the filesystem: start a new line
            with open(path, "rb") as fh:
                fh.seek(-1, os.SEEK_END)
                lead = b"" if fh.read(1) == b"\n" else b"\n"
        os.write(fd, lead + (json.dumps(entry) + "\n").encode())
    finally:
        os.close(fd)


def read_fe_log(root: Path | str) -> list[dict]:
    """The entries of a run's ``fe_evaluations.jsonl`` (unparsable lines are skipped).

    Each entry has ``iteration``, ``sample_id`` and ``event``: ``evaluated``
    (an FE run whose result was written), ``recovered`` (a result found on
    disk without its log line, written back on resume: still one FE run) or
    ``discarded`` (a result file found corrupt and set aside; the sample is
    evaluated again). Entries written before ``event`` existed count as
    ``evaluated``.
    """
    path = Path(root) / FE_LOG
    out = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                entry = json.loads(line)
            except ValueError:
                continue
            entry.setdefault("event", "evaluated")
            out.append(entry)
    return out


def _sample_check(samples: pd.DataFrame, cols: list[str], rows: int, extra: tuple[str, ...] = ()):
    """A validator of per-sample FE files: right columns (``extra`` too), rows, sample id and parameters."""
    alpha = {int(sid): x for sid, x in zip(samples["sample_id"], samples[cols].to_numpy())}

    def check(sid: int, table: pd.DataFrame) -> str | None:
        missing = [c for c in (*FE_RESULT_COLUMNS, *extra, *cols) if c not in table.columns]
        if missing:
            return f"wrong schema: columns {missing} missing"
        if len(table) != rows:
            return f"{len(table)} rows, expected {rows}"
        if not (table["sample_id"] == sid).all():
            return f"holds sample ids {sorted(set(table['sample_id']))}, not {sid}"
        if sid in alpha and not np.array_equal(table[cols].to_numpy()[0], alpha[sid]):
            return "computed for other parameters than the sample's"
        return None

    return check


def _done(store: RunStore, iteration: int, stage: str) -> bool:
    if store.is_finished(iteration, stage):
        _logger().info("iteration %d, stage %s: finished earlier, read back", iteration, stage)
        return True
    return False


# -- the tasks ------------------------------------------------------------------------------------
@task(name="samples", task_run_name="iteration-{iteration}-samples", cache_policy=NO_CACHE)
def samples_task(root: str, config, iteration: int, m: int) -> int:
    """The FE batch of an iteration: uniform samples first, then the previous selection."""
    store = RunStore(root)
    if not _done(store, iteration, "samples"):
        cols = parameter_names(config)
        if iteration == 1:
            n = config.conventional_samples if config.strategy == "conventional" else config.q
            lower, upper = parameter_box(config, m)
            X = adaptive.uniform_samples(n, lower, upper, stage_rng(config.seed, iteration, "samples"))
            if trust_region_loop(config) or emulates_modes(config):  # every user has the nominal model
                X[0] = np.clip(np.zeros(m), *solver_box(config, m))
            first_id = 0
        else:
            X = store.read_table(iteration - 1, "select")[cols].to_numpy()
            first_id = int(store.stage_info(iteration - 1, "select")["next_sample_id"])
        df = pd.DataFrame(X, columns=cols)
        df.insert(0, "iteration", np.int64(iteration))
        df.insert(0, "sample_id", np.arange(first_id, first_id + len(df), dtype=np.int64))
        store.write_table(iteration, "samples", "samples", df)
        _finish(store, iteration, "samples", ["samples"], {"n": len(df)})
    return int(store.stage_info(iteration, "samples")["n"])


@task(name="fe", task_run_name="iteration-{iteration}-fe", cache_policy=NO_CACHE)
def fe_task(root: str, config, iteration: int, freqs_hz: np.ndarray, channels=None) -> int:
    """FE runs of the iteration's samples in parallel (joblib: loky processes or a Dask cluster).

    Each result is written as soon as it arrives, so a crash loses at most
    the runs in flight; on resume, samples with a result on disk are not run
    again. A lost worker costs only its runs in flight: they are submitted
    again (:func:`tasks.fe_backends.run_unordered`). ``channels``: as in
    :func:`evaluate_sample`. Returns the number of FE runs made by this call.
    """
    store = RunStore(root)
    logger = _logger()
    if _done(store, iteration, "fe"):
        return 0
    samples = store.read_table(iteration, "samples")
    cols = parameter_columns(samples)
    n = load_model(config.model).n_sensors if channels is None else len(channels[0])
    modes = 0
    if emulates_modes(config):  # fixed by iteration 1's FE stage for the whole run (the emulator needs one count)
        from tasks import modal_emulation

        recorded = store.stage_info(1, "fe").get("modes") if iteration > 1 else None
        modes = int(recorded) if recorded else modal_emulation.n_modes(config, freqs_hz)
    check = _sample_check(samples, cols, len(freqs_hz) * n, modal_columns(modes))
    done = store.finished_samples(iteration, check)
    _reconcile_log(store, iteration, done)
    todo = samples[~samples["sample_id"].isin(list(done))]
    for sid, x in zip(todo["sample_id"], todo[cols].to_numpy()):
        # The model refuses these (the run records the failure and goes on); sampling should never make one.
        if np.any(~np.isfinite(x)) or np.any(x <= -1.0):
            logger.warning("iteration %d: sample %d is outside the valid domain (factors > -1): %s",
                           iteration, sid, x)
    if done:
        logger.info("iteration %d, stage fe: %d of %d FE results found on disk", iteration, len(done), len(samples))
    total, count = len(samples), len(done)
    jobs = {
        int(sid): delayed(evaluate_sample)(config.model, int(sid), x, freqs_hz, channels, modes)
        for sid, x in zip(todo["sample_id"], todo[cols].to_numpy())
    }
    ran = 0
    if len(todo):
        results = run_unordered(jobs, lambda r: int(r["sample_id"].iloc[0]), fe_backend=config.fe_backend,
                                n_jobs=config.n_jobs, dask_address=config.dask_address,
                                label=f"iteration {iteration}, stage fe", logger=logger)
        alpha = dict(zip(todo["sample_id"], todo[cols].to_numpy()))
        for result in results:
            sid = int(result["sample_id"].iloc[0])
            for j, c in enumerate(cols):  # the parameters travel with the result, so it cannot be mismatched
                result[c] = alpha[sid][j]
            store.write_sample(iteration, sid, result)
            kill_point(f"fe-result-written/iteration={iteration}/sample={sid}")
            _append_log(store, {"iteration": iteration, "sample_id": sid, "event": "evaluated",
                                "status": result["status"].iloc[0], "pid": int(result["pid"].iloc[0]),
                                "unix": time.time()})
            kill_point(f"fe-logged/iteration={iteration}/sample={sid}")
            ran += 1
            count += 1
            logger.info("iteration %d, stage fe: %d/%d FE runs done", iteration, count, total)
    wanted = set(samples["sample_id"])
    parts = [pd.read_parquet(p) for sid, p in sorted(store.finished_samples(iteration, check).items())
             if sid in wanted]
    missing = wanted - {int(part["sample_id"].iloc[0]) for part in parts}
    if missing:
        raise RuntimeError(f"iteration {iteration}: FE results of samples {sorted(missing)} were lost while the "
                           "stage ran; run again to evaluate them")
    fe = pd.concat(parts, ignore_index=True).sort_values(["sample_id", "frequency_hz", "sensor"], kind="stable")
    store.write_table(iteration, "fe", "fe", fe.reset_index(drop=True))
    _finish(store, iteration, "fe", ["fe"], {"n": int(fe["sample_id"].nunique()), "modes": modes})
    return ran


def _reconcile_log(store: RunStore, iteration: int, done: dict[int, Path]) -> None:
    """Log discarded result files, and results on disk whose log line a kill prevented."""
    for k, sid, path, reason in store.discarded:
        _append_log(store, {"iteration": k, "sample_id": sid, "event": "discarded", "file": str(path),
                            "reason": reason, "unix": time.time()})
    store.discarded.clear()
    last = {}
    for entry in read_fe_log(store.root):
        if entry.get("iteration") == iteration:
            last[entry["sample_id"]] = entry["event"]
    for sid, path in sorted(done.items()):
        if last.get(sid) not in ("evaluated", "recovered"):
            table = pd.read_parquet(path, columns=["status", "pid"])
            _append_log(store, {"iteration": iteration, "sample_id": sid, "event": "recovered",
                                "status": table["status"].iloc[0], "pid": int(table["pid"].iloc[0]),
                                "unix": time.time()})


@task(name="errors", task_run_name="iteration-{iteration}-errors", cache_policy=NO_CACHE)
def errors_task(root: str, config, iteration: int, measured_amplitude: np.ndarray, data=None) -> dict:
    """Residuals (Eq. 5), overall (Eq. 6b) and per-sensor (Eq. 15) errors of the iteration's FE runs.

    With ``data`` (:class:`tasks.update_data.UpdateData`) the residual is the run's
    (amplitude or complex) over the kept values, the errors per channel.
    """
    store = RunStore(root)
    if not _done(store, iteration, "errors"):
        fe = store.read_table(iteration, "fe")
        p, n = measured_amplitude.shape
        status = fe.groupby("sample_id", sort=True)["status"].first()
        ids = status.index.to_numpy()
        if data is not None:
            _fit_errors(store, iteration, fe, ids, status, data)
            return store.stage_info(iteration, "errors")
        amp = np.hypot(fe["real"].to_numpy(), fe["imag"].to_numpy()).reshape(len(ids), p, n)
        res = adaptive.relative_residuals(amp, measured_amplitude)  # (r, p*n)
        overall = adaptive.overall_error(res)
        sensor = adaptive.per_sensor_error(res, n)
        errors = pd.DataFrame({"sample_id": ids, "iteration": np.int64(iteration), "overall_error": overall,
                               "status": status.to_numpy()})
        for j in range(n):
            errors[f"error_sensor_{j + 1}"] = sensor[:, j]
        failed = errors["status"] != "ok"
        if failed.any():
            messages = fe[fe["status"] != "ok"].groupby("sample_id")["message"].first()
            for sid, msg in messages.items():
                _logger().warning("iteration %d: FE run of sample %d failed and is excluded: %s", iteration, sid, msg)
        residuals = pd.DataFrame({
            "sample_id": np.repeat(ids, p * n),
            "frequency_hz": fe["frequency_hz"].to_numpy(),
            "sensor": fe["sensor"].to_numpy(),
            "residual": res.ravel(),
        })
        store.write_table(iteration, "errors", "errors", errors)
        store.write_table(iteration, "errors", "residuals", residuals)
        ok = errors.loc[~failed, "overall_error"]
        _finish(store, iteration, "errors", ["errors", "residuals"],
                     {"best": float(ok.min()) if len(ok) else float("inf"), "failed": int(failed.sum())})
    return store.stage_info(iteration, "errors")


def _fit_errors(store: RunStore, iteration: int, fe: pd.DataFrame, ids: np.ndarray, status: pd.Series, data) -> None:
    """The errors stage on the run's :class:`tasks.update_data.UpdateData` (channels, kept values, residual)."""
    p, n = data.amplitude.shape
    Z = (fe["real"].to_numpy() + 1j * fe["imag"].to_numpy()).reshape(len(ids), p, n)
    res = data.residuals(Z)  # (r, k)
    errors = pd.DataFrame({"sample_id": ids, "iteration": np.int64(iteration),
                           "overall_error": adaptive.overall_error(res), "status": status.to_numpy()})
    for j, e in enumerate(data.channel_errors(res).T):
        errors[f"error_sensor_{j + 1}"] = e
    failed = errors["status"] != "ok"
    if failed.any():
        messages = fe[fe["status"] != "ok"].groupby("sample_id")["message"].first()
        for sid, msg in messages.items():
            _logger().warning("iteration %d: FE run of sample %d failed and is excluded: %s", iteration, sid, msg)
    parts = []
    for sid, z in zip(ids, Z):
        columns = data.residual_columns(z)
        parts.append(pd.DataFrame({"sample_id": np.full(columns["residual"].size, sid, dtype=np.int64), **columns}))
    store.write_table(iteration, "errors", "errors", errors)
    store.write_table(iteration, "errors", "residuals", pd.concat(parts, ignore_index=True))
    ok = errors.loc[~failed, "overall_error"]
    _finish(store, iteration, "errors", ["errors", "residuals"],
            {"best": float(ok.min()) if len(ok) else float("inf"), "failed": int(failed.sum()),
             "residual": data.residual, "values": data.n_values})


@task(name="distribution", task_run_name="iteration-{iteration}-distribution", cache_policy=NO_CACHE)
def distribution_task(root: str, config, iteration: int, m: int) -> dict:
    """Step f: the sampling distribution of the next candidates, and the minimum distance."""
    store = RunStore(root)
    if not _done(store, iteration, "distribution"):
        lower, upper = parameter_box(config, m)
        extra = {}
        if trust_region_loop(config):
            from tasks import trust_region

            _, X, _, E = training_data(store, iteration)
            previous = trust_region.region(store, iteration - 1) if iteration > 1 else None
            tr = adaptive.update_trust_region(previous, X, E)
            low, high = tr.box(lower, upper)
            kind, mean, std, dist = "trust_region", (low + high) / 2, (high - low) / np.sqrt(12), None
            lower, upper = low, high  # the minimum distance scales with the region's spread
            extra = {"trust_region": {"centre": tr.centre.tolist(), "length": tr.length, "successes": tr.successes,
                                      "failures": tr.failures, "best": tr.best}}
        elif iteration == 1 or config.strategy == "conventional":
            # Table 2, step c: the first candidates are uniform over the whole box.
            kind, mean, std, dist = "uniform", (lower + upper) / 2, (upper - lower) / np.sqrt(12), None
        else:
            _, X, _, E = training_data(store, iteration)
            dist = adaptive.fit_distribution(X, E, config.z, config.std_floor)
            kind, mean, std = "normal", dist.mean, dist.std
        d_min = adaptive.default_min_distance(dist, lower, upper, config.min_distance_factor)
        df = pd.DataFrame({"parameter": parameter_names(config), "mean": mean, "std": std})
        store.write_table(iteration, "distribution", "distribution", df)
        _finish(store, iteration, "distribution", ["distribution"], {"kind": kind, "min_distance": d_min, **extra})
    return store.stage_info(iteration, "distribution")


def emulates_modes(config) -> bool:
    """The adaptive strategy's paper loop with ``emulate = "modes"`` (:mod:`tasks.modal_emulation`)."""
    return config.strategy == "adaptive" and config.loop == "paper" and config.emulate == "modes"


def modal_columns(modes: int) -> tuple[str, ...]:
    """The FE result columns of ``modes`` emulated modes (:func:`evaluate_sample`)."""
    return tuple(f"{name}_{r + 1}" for r in range(modes) for name in ("omega2", "participation"))


def trust_region_loop(config) -> bool:
    """The adaptive strategy with the trust-region loop (:mod:`tasks.trust_region`), not the paper's steps."""
    return config.loop == "trust-region"  # the config refuses it with another strategy


@task(name="train", task_run_name="iteration-{iteration}-train", cache_policy=NO_CACHE, retries=1)
def train_task(root: str, config, iteration: int, trainer: str | None = None, output_stage: str = "train",
               data=None) -> dict:
    """MRGP training on all FE data so far; the hyper-parameters are stored, not the model.

    With the trust-region loop (``data``: the run's UpdateData): on the inverse receptance of the FE runs
    near the trust region, one length scale per parameter (:mod:`tasks.trust_region`). With ``emulate =
    "modes"``: on the modes and the remainder of the receptance of all FE runs (:mod:`tasks.modal_emulation`).
    """
    store = RunStore(root)
    trainer = trainer or config.trainer
    if not _done(store, iteration, output_stage):
        kernel, outputs, modal = "iso", config.outputs, {}
        previous = _previous_hyperparameters(store, iteration)
        if trust_region_loop(config) and store.stage_info(iteration, "distribution")["kind"] == "trust_region":
            from tasks import trust_region

            X, Y = trust_region.training_set(store, config, iteration, data)
            kernel = "ard"
        elif emulates_modes(config):
            from tasks import modal_emulation

            X, Y, _, layout = modal_emulation.training_set(store, config, iteration, data)
            separate = modal_emulation.separate_modes(config, layout)
            if separate:  # the hyper-parameters of the modes' own MRGP
                Y, outputs = Y[:, :layout.n_modal], "auto"
            modal = {"modal": {"modes": layout.n_modes, "outputs": layout.n_outputs, "modes_separate": separate}}
            kernel = "ard"
            # No Table 1 l~ bound: the modes do not sharpen as the samples gather (docs/update-results.md)
            previous = None
        else:
            _, X, Y, _ = training_data(store, iteration)
        if previous is not None and len(_length_scales(previous)) != (X.shape[1] if kernel == "ard" else 1):
            previous = None  # the first trust-region iteration follows an isotropic uniform one: no l~ yet
        rng = stage_rng(config.seed, iteration, "train")
        t0 = time.perf_counter()
        hyper, info = train_mrgp(X, Y, trainer, rng, previous, outputs=outputs, kernel=kernel)
        info.update(modal)
        seconds = time.perf_counter() - t0
        df = pd.DataFrame({"name": list(hyper), "value": [float(v) for v in hyper.values()]})
        store.write_table(iteration, output_stage, "hyperparameters", df)
        _finish(store, iteration, output_stage, ["hyperparameters"],
                     {"trainer": trainer, "seconds": seconds, "n_train": int(X.shape[0]), **info})
        _logger().info("iteration %d, stage train: %s on %d runs in %.2f s", iteration, trainer, X.shape[0], seconds)
        _log_outputs(iteration, outputs, info)
    return store.stage_info(iteration, output_stage)


def _previous_hyperparameters(store: RunStore, iteration: int) -> dict | None:
    if iteration > 1 and store.is_finished(iteration - 1, "train"):
        df = store.read_table(iteration - 1, "train", "hyperparameters")
        return dict(zip(df["name"], df["value"]))
    return None


@task(name="predict", task_run_name="iteration-{iteration}-predict", cache_policy=NO_CACHE)
def predict_task(root: str, config, iteration: int, m: int, train_stage: str = "train",
                 output_stage: str = "predict", data=None) -> dict:
    """Draw ``w`` candidates and predict their overall errors with the trained MRGP.

    With the trust-region loop: candidates in the region and Gauss-Newton end points on the emulator
    (:func:`tasks.trust_region.predict`). With ``emulate = "modes"``: errors from the emulated modes, and
    Gauss-Newton end points added (:func:`tasks.modal_emulation.predict`).
    """
    store = RunStore(root)
    if not _done(store, iteration, output_stage):
        lower, upper = parameter_box(config, m)
        rng = stage_rng(config.seed, iteration, "predict")
        info = store.stage_info(iteration, "distribution")
        if info["kind"] == "trust_region":
            from tasks import trust_region

            hp = store.read_table(iteration, train_stage, "hyperparameters")
            t0 = time.perf_counter()
            C, predicted = trust_region.predict(store, config, iteration, data, dict(zip(hp["name"], hp["value"])),
                                                rng)
            _write_candidates(store, config, iteration, output_stage, C, predicted, time.perf_counter() - t0)
            return store.stage_info(iteration, output_stage)
        if info["kind"] == "uniform":
            C = adaptive.uniform_samples(config.w, lower, upper, rng)
        else:
            d = store.read_table(iteration, "distribution")
            dist = adaptive.SamplingDistribution(d["mean"].to_numpy(), d["std"].to_numpy())
            C = adaptive.draw_candidates(dist, config.w, lower, upper, rng)
        hp = store.read_table(iteration, train_stage, "hyperparameters")
        outputs = store.stage_info(iteration, train_stage).get("outputs", "full")  # what the train stage fitted
        t0 = time.perf_counter()
        if emulates_modes(config):
            from tasks import modal_emulation

            C, predicted = modal_emulation.predict(store, config, iteration, data, dict(zip(hp["name"], hp["value"])),
                                                   C)
        else:
            _, X, Y, _ = training_data(store, iteration)
            predicted = predict_overall_error(X, Y, dict(zip(hp["name"], hp["value"])), C, outputs=outputs)
        _write_candidates(store, config, iteration, output_stage, C, predicted, time.perf_counter() - t0)
    return store.stage_info(iteration, output_stage)


def _write_candidates(store: RunStore, config, iteration: int, stage: str, C: np.ndarray, predicted: np.ndarray,
                      seconds: float) -> None:
    """The predict stage's table (candidate_id, parameters, predicted_error) and its record."""
    df = pd.DataFrame(C, columns=parameter_names(config))
    df.insert(0, "candidate_id", np.arange(len(df), dtype=np.int64))
    df["predicted_error"] = predicted
    store.write_table(iteration, stage, "candidates", df)
    _finish(store, iteration, stage, ["candidates"], {"seconds": seconds, "best_predicted": float(np.nanmin(predicted))})


@task(name="select", task_run_name="iteration-{iteration}-select", cache_policy=NO_CACHE)
def select_task(root: str, config, iteration: int, m: int, s: int | None = None) -> dict:
    """Step d: the next FE batch, the best predicted candidates at least a minimum distance apart."""
    store = RunStore(root)
    if not _done(store, iteration, "select"):
        s = s or config.s
        cand = store.read_table(iteration, "predict", "candidates")
        cols = parameter_names(config)
        ids, X, _, _ = training_data(store, iteration)
        d_min = float(store.stage_info(iteration, "distribution")["min_distance"])
        chosen = adaptive.select_diverse(cand[cols].to_numpy(), cand["predicted_error"].to_numpy(), s, d_min,
                                         exclude=_all_evaluated(store, iteration, cols))
        df = cand.iloc[chosen].reset_index(drop=True)
        next_id = _next_sample_id(store, iteration)
        store.write_table(iteration, "select", "select", df)
        _finish(store, iteration, "select", ["select"], {"n": len(df), "next_sample_id": next_id})
    return store.stage_info(iteration, "select")


def _all_evaluated(store: RunStore, iteration: int, cols: list[str]) -> np.ndarray:
    return np.vstack([store.read_table(k, "samples")[cols].to_numpy() for k in range(1, iteration + 1)])


def _next_sample_id(store: RunStore, iteration: int) -> int:
    return int(max(store.read_table(k, "samples")["sample_id"].max() for k in range(1, iteration + 1)) + 1)


# -- MRGP adapters: the only place that knows the mrgp_core API ---------------------------------
def train_mrgp(X: np.ndarray, Y: np.ndarray, trainer: str, rng: np.random.Generator,
               previous: dict | None, outputs: str = "full", kernel: str = "iso") -> tuple[dict, dict]:
    """Fit the MRGP's hyper-parameters; returns (hyper-parameters, diagnostics).

    For the paper's trainers (``sao``, ``pso``) the squared length scale is
    bounded above by the previous iteration's optimum, Table 1's ``l~``; the
    gradient trainer searches the default bounds every time.

    ``outputs`` (``full``, ``reduced`` or ``auto``, see :func:`reduced_outputs`)
    picks the full MRGP or the one in a reduced output basis
    (:mod:`mrgp_core.reduced`); the diagnostics then say which (``outputs``)
    and, for the reduced one, its rank ``components`` and ``captured`` variance.
    """
    X, Y = merge_duplicates(X, Y)
    l_upper = None
    if previous is not None and trainer in ("sao", "pso"):
        l_upper = _length_scales(previous)
        l_upper = float(l_upper[0]) if l_upper.size == 1 else l_upper
    reduced = reduced_outputs(outputs, Y.shape[1])
    fit = mrgp_core.fit_reduced if reduced else mrgp_core.fit
    model = fit(X, Y, trainer, rng=rng, l_upper=l_upper, kernel=kernel)
    h = model.hyperparameters
    hyper = {f"length_scale_{i + 1}": float(v) for i, v in enumerate(np.atleast_1d(h.length_scale))}
    hyper["nugget"] = float(h.nugget)
    info = {"log_likelihood": float(model.log_likelihood), "evaluations": int(model.training.result.nfev),
            "l_upper": None if l_upper is None else np.atleast_1d(l_upper).tolist(),
            **_outputs_info(model, reduced)}
    return hyper, info


def predict_overall_error(X: np.ndarray, Y: np.ndarray, hyper: dict, C: np.ndarray,
                          outputs: str = "full") -> np.ndarray:
    """Predicted overall error (Eq. 6b) of each candidate, shape (w,), from stored hyper-parameters.

    With reduced outputs the basis is rebuilt from the same training data
    (deterministic), so a resumed or rerun stage predicts what the original did.
    """
    h = mrgp_core.Hyperparameters(length_scale=_length_scales(hyper), nugget=float(hyper["nugget"]))
    X, Y = merge_duplicates(X, Y)
    condition = mrgp_core.condition_reduced if reduced_outputs(outputs, Y.shape[1]) else mrgp_core.condition
    return condition(X, Y, h).predicted_overall_error(C)


# -- output model: full MRGP or reduced output basis (config key ``outputs``) ----------------------
#: ``outputs = "auto"`` uses the reduced output basis above this many responses k. Up to it the full
#: MRGP (the paper's method) is affordable and stays: one likelihood evaluation scales as k^3, 4.5 s at
#: k = 1,998 (docs/many-responses.md), so about 5 ms at k = 200 against 0.07 s at k = 500 and 0.8 GB
#: for Q at k = 10,000. The benchmark (k = 72) keeps the full MRGP. "k > n" is not a criterion: the
#: benchmark's k = 72 exceeds n = 20 in every first iteration and the full MRGP handles it.
AUTO_REDUCED_ABOVE = 200


def reduced_outputs(outputs: str, k: int) -> bool:
    """Whether ``outputs`` (``full``, ``reduced`` or ``auto``) means the reduced basis for k responses."""
    if outputs not in ("full", "reduced", "auto"):
        raise ValueError(f"outputs must be 'full', 'reduced' or 'auto', got {outputs!r}")
    return outputs == "reduced" or (outputs == "auto" and k > AUTO_REDUCED_ABOVE)


def _outputs_info(model, reduced: bool) -> dict:
    """Stage-record entries naming the output model; rank and captured variance for the reduced one."""
    if not reduced:
        return {"outputs": "full"}
    return {"outputs": "reduced", "components": int(model.n_components),
            "captured": float(model.outputs.captured), "n_responses": int(model.n_responses)}


def _log_outputs(iteration: int, requested: str, info: dict) -> None:
    if info["outputs"] == "reduced":
        _logger().info("iteration %d, stage train: outputs=%s -> reduced basis, k=%d responses -> r=%d directions "
                       "(%.3f %% of the standardised variance)", iteration, requested, info["n_responses"],
                       info["components"], 100 * info["captured"])
    else:
        _logger().info("iteration %d, stage train: outputs=%s -> full MRGP", iteration, requested)


#: Samples closer than this (max-norm, relative to the largest spread of a parameter) are one input.
DUPLICATE_RTOL = 1e-6


def merge_duplicates(X: np.ndarray, Y: np.ndarray, rtol: float = DUPLICATE_RTOL) -> tuple[np.ndarray, np.ndarray]:
    """Merge (nearly) duplicated inputs into one row with the mean of their responses.

    Two FE runs at the same parameters make the MRGP's correlation matrix
    Sigma singular up to its jitter; the profile likelihood then rewards
    vanishing length scales (measured: the gradient trainer's length scale
    falls from 0.5 to 2e-8 with five duplicates 1e-12 apart) and the
    emulator degrades to its linear trend. One row per distinct input keeps
    the information and the likelihood well posed.
    """
    X, Y = np.asarray(X, float), np.asarray(Y, float)
    if len(X) < 2:
        return X, Y
    tol = rtol * max(float(np.ptp(X, axis=0).max()), 1e-300)
    group = np.full(len(X), -1)
    n = 0
    for i in range(len(X)):  # r is a few hundred at most: the quadratic scan is cheap
        if group[i] >= 0:
            continue
        close = (group < 0) & (np.max(np.abs(X - X[i]), axis=1) <= tol)
        group[close] = n
        n += 1
    if n == len(X):
        return X, Y
    _logger().warning("%d FE samples duplicate others (within %.1g); merged into %d distinct inputs for the MRGP",
                      len(X) - n, tol, n)
    counts = np.bincount(group, minlength=n)[:, None]
    Xm = np.zeros((n, X.shape[1]))
    Ym = np.zeros((n, Y.shape[1]))
    np.add.at(Xm, group, X)
    np.add.at(Ym, group, Y)
    return Xm / counts, Ym / counts


def _length_scales(hyper: dict) -> np.ndarray:
    """``length_scale_1 .. length_scale_d`` of a stored hyper-parameter record, in input order."""
    keys = sorted((k for k in hyper if k.startswith("length_scale_")), key=lambda k: int(k.rsplit("_", 1)[1]))
    return np.array([hyper[k] for k in keys], dtype=float)
