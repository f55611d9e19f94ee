"""FE runs of any stage: evaluated in parallel, stored one file each as they finish, replayed on resume.

Every stage that runs the FE model (the driver's FE stages, ``tasks/driver.py``: the paper loop's ``fe``, the
polish, the hybrid's ``local`` and ``global``) goes through :class:`FEStage`:

* each run is written as soon as it finishes to ``iteration=<k>/stage=<name>/sample=<id>.parquet`` (the
  complex receptance of the measured channels, frequency-major; with its derivative columns
  ``dreal_<i>``/``dimag_<i>`` when asked, and the lowest modes ``omega2_<r>``/``participation_<r>`` when the
  paper loop emulates them; the parameters travel with it) and logged to ``fe_evaluations.jsonl``;
* a resumed stage asks for the same points in the same order (every strategy is deterministic), so a stored
  run is read back instead of run again when it was made for (nearly) the same parameters; anything else
  stored under that id is set aside as ``*.corrupt-<time>`` and logged ``discarded``;
* the finished stage writes the run record's two tables (:mod:`tasks.record`): ``runs.parquet`` (one row
  per FE run) and ``responses.parquet`` (the long complex table).

The evaluation functions run in worker processes; they get a :class:`tasks.problem.ModelRef`, not the model.
A large model (at least :data:`LARGE_DOFS` free DOFs) is run differently, so that both cores work and one
factorisation serves as much as it can (issue 41): a round of one FE run (a Gauss-Newton step) runs in this
process with PARDISO on all the run's cores (:func:`solver_threads`), where the factor of the previous run (or
of the preflight's band check, at the nominal model) is still held and preconditions the next one
(:mod:`fe_core.solvers.nearby`), and its Krylov space seeds the next one's (:mod:`fe_core.solvers.recycle`);
a round of several goes to the worker processes, one core each, after this process has freed its idle
factor, and each worker frees its own (and its kept space) after each run; as many workers as the memory left
then holds (:func:`tasks.machine.runs_that_fit`), and when not two, the round's runs one after another here.
"""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from joblib import delayed

from fe_core.inference.residual import overall_error
from fe_core.solvers import reduced_basis
from fe_core.threads import cores
from strategies.base import Outcome
from tasks.faults import kill_point
from tasks.fe_log import FE_LOG, append_log, read_fe_log
from tasks.machine import available_bytes, runs_that_fit
from tasks.common import finish
from tasks.fe_backends import run_unordered
from tasks.record import RESPONSE_COLUMNS, RUN_COLUMNS, grid
from tasks import jacobian_memo
from tasks.problem import black_box
from tasks.runstore import RunStore, _parquet_bytes, atomic_write_bytes

__all__ = ["evaluate_sample", "evaluate_sample_jacobian", "FEStage", "JACOBIAN_COST", "FE_LOG", "append_log",
           "read_fe_log", "FE_DELAY_ENV", "modal_columns", "fd_frame", "LARGE_DOFS", "is_large", "solver_threads",
           "run_cores"]

#: Environment variable: seconds each FE run sleeps (only for interruption tests).
FE_DELAY_ENV = "MRGP_FE_DELAY_SECONDS"
#: Columns of one FE result as the worker returns it (the parameters are added by the stage).
RESULT_COLUMNS = ("sample_id", "sensor", "frequency_hz", "real", "imag", "status", "message", "seconds", "pid")
#: Cost of an FE run with its exact Jacobian, in FE runs: the CPU time ratio of
#: ``fe_core.solvers.sensitivity.frf_jacobian`` (Krylov) to ``model.frf`` on the benchmark, 2.3 measured (one
#: thread, load 10), rounded up; ``python -m benchmarks.suite`` measures it again in every run (docs/results/suite.md).
#: Data with several references cost this once per reference.
JACOBIAN_COST = 2.5
#: Stored results are reused for requested points this close (max-norm, fraction of the box width): far below
#: any step of the strategies (a resumed least-squares step can differ from the stored one in the last bits).
REPLAY_TOLERANCE = 1e-12
#: Models with at least this many free DOFs run single FE runs in this process on all the run's cores (see the
#: module docstring); smaller ones keep one core per FE run in the workers (their factorisations take seconds).
LARGE_DOFS = 50_000


def is_large(model) -> bool:
    """An in-process model with at least :data:`LARGE_DOFS` free DOFs (a black-box solver deck never is)."""
    return not black_box(model) and getattr(model, "n_dofs", 0) >= LARGE_DOFS


def run_cores(settings) -> int:
    """The cores a run may use: ``n_jobs`` (-1: every core this process may use; :func:`fe_core.threads.cores`),
    from the run's settings (an object with ``n_jobs`` or the closure's dict)."""
    n = settings.get("n_jobs", 1) if isinstance(settings, dict) else getattr(settings, "n_jobs", 1)
    return cores(n)


def solver_threads(problem, settings):
    """A context in which this thread's PARDISO calls use all the run's cores when the model is large (the
    intervals' Jacobians, a single FE run in this process); otherwise nothing changes."""
    from fe_core.solvers import pardiso

    if not is_large(problem.model):
        return contextlib.nullcontext()
    return pardiso.threads(run_cores(settings))


@contextlib.contextmanager
def _fe_run(model, threads: int, keep_factor: bool):
    """One FE run's solver settings: ``threads`` PARDISO threads; a large model's idle factors freed after it
    unless ``keep_factor`` (this process's next FE run may be preconditioned by it)."""
    from fe_core.solvers import pardiso, recycle

    with pardiso.threads(threads):
        try:
            yield
        finally:
            if is_large(model):  # where a large model's factorisations went (each ~a minute at 500k DOFs)
                pardiso.log.info("PARDISO in this process so far: %s",
                                 ", ".join(f"{k} {v}" for k, v in pardiso.stats.items()))
            if not keep_factor and is_large(model):
                pardiso.release_idle()
                recycle.forget(model)
                reduced_basis.forget(model)


# -- in worker processes -------------------------------------------------------------------------------
def _frame(sample_id: int, freqs_hz, n: int, Z: np.ndarray, status: str, message: str, t0: float) -> pd.DataFrame:
    p = len(freqs_hz)
    return pd.DataFrame({
        "sample_id": np.full(p * n, sample_id, dtype=np.int64),
        "sensor": np.tile(np.arange(1, n + 1), p).astype(np.int64),
        "frequency_hz": np.repeat(np.asarray(freqs_hz, float), n),
        "real": Z.real.ravel(), "imag": Z.imag.ravel(), "status": status, "message": message,
        "seconds": time.perf_counter() - t0, "pid": os.getpid(),
    })


def _delay() -> None:
    delay = float(os.environ.get(FE_DELAY_ENV, "0") or 0)
    if delay > 0:  # fault-injection tests need FE runs slow enough to be interrupted
        time.sleep(delay)


def evaluate_sample(ref, sample_id: int, theta: np.ndarray, freqs_hz: np.ndarray, channels=None,
                    modes: int = 0, threads: int = 1, keep_factor: bool = False) -> pd.DataFrame:
    """One FE run: the complex FRF of the measured channels as a long table.

    ``ref`` is the run's :class:`tasks.problem.ModelRef`; ``theta`` the parameter vector, shape (m,): the
    stiffness factors and, when the model file updates masses, the mass factors. ``channels`` =
    ``(responses, references)`` (0-based model sensor and excitation of each measured channel) gives those
    channels through one solve with a load column per reference; None gives the model's sensors under its
    default excitation. ``modes`` > 0 adds the lowest modes (:meth:`fe_core.model.ParametricModel.modal_terms`):
    ``omega2_<r>`` (the same on every row) and ``participation_<r>`` (in the row's channel).

    A failed evaluation (a singular system, say) does not raise: its rows hold NaN responses, ``status =
    "failed"`` and the reason, so the run records it, excludes the sample and goes on.

    ``threads``: PARDISO threads of this run; ``keep_factor``: keep a large model's factor afterwards (an FE
    run in the flow's process, see the module docstring), else it is freed.

    Returns
    -------
    DataFrame
        :data:`RESULT_COLUMNS` (and the modal columns); one row per (frequency, channel), frequency-major;
        ``sensor`` is the channel number (1-based).
    """
    t0 = time.perf_counter()
    model = ref.load()
    n, p = (model.n_sensors if channels is None else len(channels[0])), len(freqs_hz)
    _delay()
    theta = np.asarray(theta, dtype=float)
    try:
        with _fe_run(model, threads, keep_factor):
            Z = model.parameter_frf(theta, freqs_hz, channels)
            if not np.all(np.isfinite(Z)):
                raise FloatingPointError("the FRF has non-finite values")
            if modes:
                omega2, participation = model.modal_terms(theta, modes, channels)
                if not (np.all(np.isfinite(omega2)) and np.all(np.isfinite(participation))):
                    raise FloatingPointError("the modes have non-finite values")
        status, message = "ok", ""
    except (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError) as exc:  # a solver's CcxError too
        Z = np.full((p, n), np.nan + 1j * np.nan)
        omega2, participation = np.full(modes, np.nan), np.full((modes, n), np.nan)
        status, message = "failed", f"{type(exc).__name__}: {exc}"
    df = _frame(sample_id, freqs_hz, n, Z, status, message, t0)
    for r in range(modes):
        df[f"omega2_{r + 1}"] = np.full(p * n, omega2[r])
        df[f"participation_{r + 1}"] = np.tile(participation[r], p)
    return df


def evaluate_sample_jacobian(ref, sample_id: int, theta: np.ndarray, freqs_hz: np.ndarray,
                             channels=None, threads: int = 1, keep_factor: bool = False,
                             reduce: bool = False) -> pd.DataFrame:
    """One FE run with the exact derivative of the receptance (:func:`fe_core.solvers.sensitivity.frf_jacobian`).

    Columns of :func:`evaluate_sample` plus ``dreal_<i>``, ``dimag_<i>`` (i = 1..m, the parameter vector's
    order) and ``cost`` (FE-run equivalents: :data:`JACOBIAN_COST` per reference of the channels). A failed
    run has NaN everywhere. ``threads``, ``keep_factor``: as in :func:`evaluate_sample`; ``reduce``: through the
    model's global reduced basis (:mod:`fe_core.solvers.reduced_basis`: a large model's local Gauss-Newton round).
    """
    from fe_core.solvers.sensitivity import frf_jacobian

    t0 = time.perf_counter()
    model = ref.load()
    theta = np.asarray(theta, float)
    m, p = theta.size, len(freqs_hz)
    n = model.n_sensors if channels is None else len(channels[0])
    references = 1 if channels is None else np.unique(channels[1]).size
    _delay()
    reduced = None  # whether the reduced basis served the run (None: not asked)
    try:  # one Krylov space for all the channels' references
        with _fe_run(model, threads, keep_factor):
            Z, dZ, reduced = (reduced_basis.frf_jacobian(model, theta, freqs_hz, channels=channels)
                              if reduce and keep_factor and is_large(model) else
                              (*frf_jacobian(model, theta, freqs_hz, channels=channels), None))
        if not (np.all(np.isfinite(Z)) and np.all(np.isfinite(dZ))):
            raise FloatingPointError("the FRF or its derivative has non-finite values")
        status, message = "ok", ""
        if keep_factor and not reduced:  # this process's full-order run: the intervals may start from it
            jacobian_memo.keep(model, theta, freqs_hz, channels, Z, dZ)
    except (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError) as exc:
        Z, dZ = np.full((p, n), np.nan + 1j * np.nan), np.full((p, n, m), np.nan + 1j * np.nan)
        status, message = "failed", f"{type(exc).__name__}: {exc}"
    df = _frame(sample_id, freqs_hz, n, Z, status, message, t0)
    df["cost"] = JACOBIAN_COST * references
    if reduced is not None: df["reduced"] = bool(reduced)  # noqa: E701 - only a large model's runs say
    for i in range(m):
        df[f"dreal_{i + 1}"] = dZ[:, :, i].real.ravel()
        df[f"dimag_{i + 1}"] = dZ[:, :, i].imag.ravel()
    return df


def _served(df: pd.DataFrame) -> bool:
    """Whether a large model's reduced basis served this FE result (only such runs have the column)."""
    return bool(df["reduced"].iloc[0]) if "reduced" in df else False


def fd_frame(sid: int, frames: list[pd.DataFrame], steps) -> pd.DataFrame:
    """One FE result with its forward-difference derivative from the m + 1 runs ``frames`` (the point, then
    each parameter stepped by ``steps[i]``): the columns of :func:`evaluate_sample_jacobian`; ``cost`` m + 1,
    ``seconds`` their sum; failed (NaN everywhere, the first failure's message) when any run failed."""
    base = frames[0].copy()
    base["sample_id"] = sid
    Z = [f["real"].to_numpy() + 1j * f["imag"].to_numpy() for f in frames]
    failed = [f for f in frames if f["status"].iloc[0] != "ok"]
    base["seconds"] = float(sum(f["seconds"].iloc[0] for f in frames))
    base["cost"] = float(len(frames))
    if failed:
        base["real"], base["imag"] = np.nan, np.nan
        base["status"], base["message"] = "failed", failed[0]["message"].iloc[0]
    for i, h in enumerate(steps):
        d = (Z[i + 1] - Z[0]) / h if not failed else np.full(len(base), np.nan + 0j)
        base[f"dreal_{i + 1}"], base[f"dimag_{i + 1}"] = d.real, d.imag
    return base


def modal_columns(modes: int) -> tuple[str, ...]:
    """The FE result columns of ``modes`` emulated modes (:func:`evaluate_sample`)."""
    return tuple(f"{name}_{r + 1}" for r in range(modes) for name in ("omega2", "participation"))


# -- one stage's FE runs ---------------------------------------------------------------------------------
class FEStage:
    """The FE runs of one stage: ``run(ids, points, jacobian)`` per round, ``write(info)`` at the end.

    ``settings``: the run's config (``fe_backend``, ``n_jobs``, ``dask_address``); ``modes``: modes each run
    gives (:func:`evaluate_sample`).
    """

    def __init__(self, store: RunStore, problem, settings, iteration: int, stage: str, logger, modes: int = 0,
                 replay_only: bool = False):
        self.replay_only = replay_only  # a rerun replaying the stages before its own: no FE run, nothing written
        self.store, self.problem, self.settings = store, problem, settings
        self.iteration, self.stage, self.logger, self.modes = iteration, stage, logger, modes
        self.p, self.n = problem.data.amplitude.shape
        self.tol = REPLAY_TOLERANCE * float(np.max(problem.upper - problem.lower))
        self.stored = {int(p.stem.split("=")[1]): p for p in sorted(store.stage_dir(iteration, stage).glob(
            "sample=*.parquet"))}
        self.logged = {e["sample_id"] for e in read_fe_log(store.root) if e.get("iteration") == iteration
                       and e.get("stage") == stage and e["event"] != "discarded"}
        self.borrowed: dict[int, Path] = {}
        self.rows: list[dict] = []  # one per request: sample_id, round, jacobian, parameters
        self.results: dict[int, pd.DataFrame] = {}
        self.rounds = self.ran = self.replayed = 0

    def _log(self, sid: int, event: str, **extra) -> None:
        append_log(self.store, {"iteration": self.iteration, "stage": self.stage, "sample_id": sid, "event": event,
                                **extra, "unix": time.time()})

    def _set_aside(self, sid: int, path: Path, reason: str) -> None:
        aside = path.with_name(f"{path.name}.corrupt-{int(time.time())}")
        path.rename(aside)
        self._log(sid, "discarded", file=str(path), reason=reason)
        self.logger.warning("iteration %d, stage %s: FE result %s: %s; set aside as %s, that point runs again",
                            self.iteration, self.stage, path, reason, aside.name)

    def borrow(self, stage: str) -> None:
        """Also read back the FE runs of another stage of this iteration (a rerun's original) where they fit
        the request; they are left where they are when they do not."""
        folder = self.store.stage_dir(self.iteration, stage)
        self.borrowed = {int(p.stem.split("=")[1]): p for p in sorted(folder.glob("sample=*.parquet"))}

    def _replay(self, sid: int, x: np.ndarray, jac: bool) -> pd.DataFrame | None:
        """The stored result of request ``sid`` when it is valid for ``x`` (else set aside, None)."""
        path = self.stored.pop(sid, None)
        borrowed = path is None and sid in self.borrowed
        if borrowed:
            path = self.borrowed.pop(sid)
        if path is None:
            return None
        try:
            df = pq.read_table(path, page_checksum_verification=True).to_pandas()
            needed = [*RESULT_COLUMNS, *self.problem.names, *modal_columns(self.modes),
                      *((f"dreal_{self.problem.m}",) if jac else ())]
            missing = [c for c in needed if c not in df.columns]
            problem = None
            if missing:
                problem = f"wrong schema: columns {missing} missing"
            elif len(df) != self.p * self.n:
                problem = f"{len(df)} rows, expected {self.p * self.n}"
            elif not (df["sample_id"] == sid).all():
                problem = f"holds sample ids {sorted(set(df['sample_id']))}, not {sid}"
            else:
                xs = df[self.problem.names].to_numpy()[0].astype(float)
                if np.max(np.abs(xs - x)) > self.tol:
                    problem = f"computed for other parameters ({xs.tolist()}) than requested"
        except Exception as exc:  # noqa: BLE001 - pyarrow raises several types for damaged files
            problem = f"unreadable ({type(exc).__name__}: {exc})"
        if problem and borrowed:
            return None
        if problem:
            self._set_aside(sid, path, problem)
            return None
        if sid not in self.logged and not borrowed:  # killed between writing the result and logging it: one FE run
            self._log(sid, "recovered", status=df["status"].iloc[0], pid=int(df["pid"].iloc[0]))
        return df

    def run(self, ids, points, jacobian) -> list[pd.DataFrame]:
        """One round: the stored or fresh result of each request, in order."""
        self.rounds += 1
        todo = []
        for sid, x, jac in zip(ids, points, jacobian):
            sid, x = int(sid), np.asarray(x, float)
            self.rows.append({"sample_id": sid, "round": self.rounds, "jacobian": bool(jac),
                              **dict(zip(self.problem.names, map(float, x)))})
            df = self._replay(sid, x, bool(jac))
            if df is not None:  # the record keeps the parameters the run was made at (equal within the tolerance)
                self.rows[-1].update(zip(self.problem.names, map(float, df[self.problem.names].to_numpy()[0])))
                self.results[sid] = df
            else:
                todo.append((sid, x, bool(jac)))
        self.replayed += len(ids) - len(todo)
        if 0 < len(todo) < len(ids):
            self.logger.info("iteration %d, stage %s: %d of %d FE results found on disk", self.iteration,
                             self.stage, len(ids) - len(todo), len(ids))
        if todo and self.replay_only:
            raise RuntimeError(f"iteration {self.iteration}, stage {self.stage}: {len(todo)} of the {len(ids)} points "
                               "asked for have no stored FE run (the settings changed what comes before the stage)")
        for sid, x, _ in todo:  # the model refuses these (recorded as failed); a strategy should never ask
            if np.any(~np.isfinite(x)) or np.any(x <= -1.0):
                self.logger.warning("iteration %d: sample %d is outside the valid domain (factors > -1): %s",
                                    self.iteration, sid, x)
        if todo:
            self._evaluate(todo, len(ids))
        return [self.results[int(sid)] for sid in ids]

    def _calls(self, todo: list) -> tuple[dict, dict]:
        """The round's calls ``{key: delayed(...)}`` and the forward-difference parts of a black box."""
        p = self.problem
        fd = black_box(p.model)  # no solver Jacobians: a Jacobian request is m + 1 runs in the same round
        jobs, parts = {}, {}
        for sid, x, jac in todo:
            if jac and fd:
                points, steps = p.model.fd_points(x, p.solver_box[1])
                parts[sid] = (steps, {})
                for i, xi in enumerate(points):  # sub-runs under negative ids: -(sid (m + 1) + i + 1)
                    key = -(sid * (p.m + 1) + i + 1)
                    jobs[key] = delayed(evaluate_sample)(p.ref, key, xi, p.freqs_hz, p.channels, 0)
            else:
                jobs[sid] = (delayed(evaluate_sample_jacobian)(p.ref, sid, x, p.freqs_hz, p.channels) if jac else
                             delayed(evaluate_sample)(p.ref, sid, x, p.freqs_hz, p.channels, self.modes))
        return jobs, parts

    def _results(self, jobs: dict):
        """The calls' results as they complete: a large model's as the module docstring says, others on the backend."""
        from fe_core.solvers import pardiso

        s, n_jobs = self.settings, self.settings.n_jobs
        if is_large(self.problem.model) and s.fe_backend == "loky":
            if len(jobs) == 1:
                (func, args, kwargs), = jobs.values()
                local = self.stage == "local" and func is evaluate_sample_jacobian  # the hybrid's local phase: it
                yield func(*args, **{**kwargs, "threads": run_cores(s), "keep_factor": True,  # confirms its centre
                                     **({"reduce": True} if local else {})})
                return
            pardiso.release_idle()  # the workers need the memory of this process's idle factor
            reduced_basis.forget(self.problem.ref.load())  # and of its reduced basis
            n_jobs = self._workers(len(jobs))
            if n_jobs < 2:  # one at a time here, on every core: half the memory of two workers, most of the speed
                yield from (func(*args, **{**kwargs, "threads": run_cores(s)}) for func, args, kwargs in jobs.values())
                return
        yield from run_unordered(jobs, lambda r: int(r["sample_id"].iloc[0]), fe_backend=s.fe_backend,
                                 n_jobs=n_jobs, dask_address=s.dask_address,
                                 label=f"iteration {self.iteration}, stage {self.stage}", logger=self.logger)

    def _workers(self, n_runs: int) -> int:
        """Workers for a large model's round of ``n_runs`` FE runs: the run's cores, as many as the memory left
        now holds (:func:`tasks.machine.runs_that_fit`); said in the log when fewer."""
        wanted = min(n_runs, run_cores(self.settings))
        fit = runs_that_fit(wanted, self.problem.worker_bytes)
        if fit < wanted:
            how = f"{fit} worker processes" if fit > 1 else "one FE run at a time in this process, on every core"
            self.logger.warning("iteration %d, stage %s: %d FE runs at once need about %.1f GB, %.1f GB is left: %s",
                                self.iteration, self.stage, wanted, wanted * self.problem.worker_bytes / 1e9,
                                available_bytes(used_by_run=True) / 1e9, how)
        return fit

    def _evaluate(self, todo: list, total: int) -> None:
        p = self.problem
        jobs, parts = self._calls(todo)
        params = {sid: x for sid, x, _ in todo}
        done = total - len(todo)
        for result in self._results(jobs):
            key = int(result["sample_id"].iloc[0])
            if key < 0:  # one run of a forward-difference Jacobian: the request is done with its m + 1 runs
                sid, i = divmod(-key - 1, p.m + 1)
                steps, got = parts[sid]
                got[i] = result
                kill_point(f"{self.stage}-fd-run/iteration={self.iteration}/sample={sid}/run={i}")
                if len(got) < p.m + 1:
                    continue
                result = fd_frame(sid, [got[k] for k in range(p.m + 1)], steps)
            sid = int(result["sample_id"].iloc[0])
            for j, c in enumerate(p.names):  # the parameters travel with the result, so it cannot be mismatched
                result[c] = params[sid][j]
            path = self.store.stage_dir(self.iteration, self.stage) / f"sample={sid:06d}.parquet"
            atomic_write_bytes(path, _parquet_bytes(result))
            kill_point(f"{self.stage}-result-written/iteration={self.iteration}/sample={sid}")
            self._log(sid, "evaluated", status=result["status"].iloc[0], pid=int(result["pid"].iloc[0]))
            kill_point(f"{self.stage}-logged/iteration={self.iteration}/sample={sid}")
            self.results[sid] = result
            self.ran += 1
            done += 1
            self.logger.info("iteration %d, stage %s: %d/%d FE runs done", self.iteration, self.stage, done, total)

    def cost(self, df: pd.DataFrame, jac: bool) -> float:
        return float(df["cost"].iloc[0]) if jac and "cost" in df.columns else (JACOBIAN_COST if jac else 1.0)

    def outcomes(self, frames: list[pd.DataFrame], jacobian) -> list[Outcome]:
        """The results at the run's kept values (``data.cells``): Z (k,), dZ (k, m) or None, cost, and the modes
        ``(omega2 (r,), participation (r, n))`` when the stage's runs give them."""
        line, channel = self.problem.data.cells
        out = []
        for df, jac in zip(frames, jacobian):
            Z, dZ = grid(df, self.p, self.n, self.problem.m)
            modes = None
            if self.modes:
                part = df.sort_values(["frequency_hz", "sensor"], kind="stable")
                modes = (np.array([part[f"omega2_{r + 1}"].iloc[0] for r in range(self.modes)]),
                         np.array([part[f"participation_{r + 1}"].to_numpy()[:self.n] for r in range(self.modes)]))
            out.append(Outcome(Z[line, channel], dZ[line, channel] if jac and dZ is not None else None,
                               self.cost(df, jac), modes, reduced=_served(df)))
        return out

    def write(self, info: dict, order: tuple[str, ...] = ()) -> dict:
        """Write ``runs`` and ``responses`` (:mod:`tasks.record`) and finish the stage with ``info``; when the
        stage replaced a different earlier result, the stages after it in ``order`` are stale."""
        for sid, path in self.stored.items():  # results the stage never asked for (not expected)
            self._set_aside(sid, path, "not requested by the resumed stage")
        data = self.problem.data
        runs = pd.DataFrame(self.rows, columns=["sample_id", "round", "jacobian", *self.problem.names])
        extra = {c: [] for c in ("cost", "seconds", "pid", "status", "message", "overall_error")}
        channel_errors = []
        for sid, jac in zip(runs["sample_id"], runs["jacobian"]):
            df = self.results[int(sid)]
            Z, _ = grid(df, self.p, self.n, self.problem.m)
            ok = bool(np.all(np.isfinite(Z))) and df["status"].iloc[0] == "ok"
            r = data.residuals(Z) if ok else None
            extra["cost"].append(self.cost(df, bool(jac)))
            extra["seconds"].append(float(df["seconds"].iloc[0]))  # the run's own time (the worker's)
            extra["pid"].append(int(df["pid"].iloc[0]))
            extra["status"].append("ok" if ok else "failed")
            extra["message"].append(str(df["message"].iloc[0]) if not ok else "")
            extra["overall_error"].append(float(overall_error(r)) if ok else np.nan)
            channel_errors.append(data.channel_errors(r) if ok else np.full(self.n, np.nan))
        for key, values in extra.items():
            runs[key] = values
        served = [_served(self.results[int(sid)]) for sid in runs["sample_id"]]
        if any(served):  # a large model's rounds served by its reduced basis: approximate (tasks.record.best_run)
            runs["reduced"] = served
        for j in range(self.n):
            runs[f"error_sensor_{j + 1}"] = [float(e[j]) for e in channel_errors] if channel_errors else []
        runs = runs.astype({"sample_id": np.int64, "round": np.int64, "jacobian": bool})
        keep = [*RESPONSE_COLUMNS, *modal_columns(self.modes)]
        parts = [self.results[int(sid)][keep] for sid in runs["sample_id"]]
        responses = (pd.concat(parts, ignore_index=True) if parts else
                     pd.DataFrame({c: pd.Series(dtype=float if c in ("frequency_hz", "real", "imag") else np.int64)
                                   for c in keep}))
        reduced = sum(_served(df) for df in self.results.values())
        info = {**info, **({"reduced_evaluations": reduced} if reduced else {})}  # a large model's reduced basis
        info = {"evaluations": int(len(runs)), "jacobians": int(runs["jacobian"].sum()), "rounds": self.rounds,
                "cost": float(runs["cost"].sum()), "ran_now": self.ran, **info}
        self.store.write_table(self.iteration, self.stage, "runs", runs[[c for c in (*RUN_COLUMNS, "reduced")
                                                                           if c in runs] + self.problem.names
                                                                          + [c for c in runs if
                                                                             c.startswith("error_sensor_")]])
        self.store.write_table(self.iteration, self.stage, "responses", responses)
        finish(self.store, self.iteration, self.stage, ["runs", "responses"], info, order)
        return self.store.stage_info(self.iteration, self.stage)
