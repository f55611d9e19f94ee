"""The paper's adaptive MRGP loop (Zhou & Tang, Table 2) as a strategy, and its steps.

One iteration k of the loop (the stages of iteration k in the run folder)::

    fe (the batch's FE runs) -> stop? -> distribution -> train -> predict -> select -> the batch of k + 1

The steps are pure functions of arrays (:func:`first_samples`, :func:`distribution`, :func:`candidates`,
:func:`train`, :func:`predict`, :func:`select`, :func:`stop`), each with its own generator
(:func:`stage_rng`, a pure function of seed, iteration and step). :class:`PaperLoop` chains them behind the
strategy interface (:mod:`.base`); under the run's driver each step is a stage whose result is stored through
the memo and read back on resume, so the loop in memory and the stored run make the same samples from the same
FE results.

What the MRGP emulates (``emulate``): ``"errors"``, the paper's relative residuals (isotropic kernel,
Table 1's ``l~`` bound); ``"modes"`` (default, beyond the paper), the lowest modes and the rest of the
receptance of each FE run (:mod:`.modal_emulation`), the nominal model being one of the first samples.
``conventional``: Section 3.4's baseline, ``conventional_samples`` uniform FE runs, one MRGP, the best of
``w`` predictions evaluated.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

import mrgp_core

from . import modal_emulation
from .base import Batch, InMemory, Report, Step, StopDecision
from .options import setting, uses
from .emulation import length_scales, predict_overall_error, train_mrgp
from .table2 import (default_min_distance, draw_candidates, fit_distribution, select_diverse, stopping_rule,
                     uniform_samples, SamplingDistribution)

__all__ = ["PaperOptions", "PaperLoop", "STEPS", "STAGES", "RERUNNABLE", "TRAINERS", "stage_rng", "first_samples",
           "distribution", "candidates",
           "train", "predict", "select", "stop"]

#: The loop's steps, in order; each has its own generator (:func:`stage_rng`: the index in this tuple).
STEPS = ("samples", "fe", "errors", "distribution", "train", "predict", "select")
#: The stages of an iteration in the run folder: the FE runs, then the steps kept through the memo.
STAGES = ("fe", "distribution", "train", "predict", "select")
#: Stages ``rerun`` recomputes (``python -m flows.update rerun``).
RERUNNABLE = ("train", "predict")
EMULATES = ("modes", "errors")
TRAINERS = ("sao", "pso", "gradient")


@dataclass(frozen=True)
class PaperOptions:
    """Settings of the loop (Table 2 of Zhou & Tang); the fields marked :func:`.options.setting` are keys of the
    run's config (``flows/config.py``, ``data/update.example.toml``)."""

    q: int = setting(20, help="initial uniform samples")
    s: int = setting(20, help="FE runs per iteration (the best predicted, kept apart); the hybrid's space-filling "
                     "FE runs of a global cycle")
    z: int = setting(20, help="best FE samples defining the next sampling distribution")
    w: int = setting(10_000, help="candidates predicted per iteration (the hybrid's per global cycle)")
    threshold: float = setting(0.01, help="stop at this overall error (Eq. 6b), e.g. 0.01 = 1 %")
    max_iterations: int = setting(12, help="iteration budget (iteration 1 is the initial sampling)")
    max_fe: int = uses("max_fe_evaluations", 240)
    min_distance_factor: float = setting(0.1, help="minimum distance between samples selected in one iteration, "
                                         "as a fraction of the sampling distribution's spread")
    std_floor: float = setting(1e-4, help="smallest standard deviation of the sampling distribution")
    trainer: str = setting("gradient", choices=TRAINERS, help="MRGP hyper-parameter trainer: sao, pso (Table 1) "
                           "or gradient")
    outputs: str = setting("auto", choices=("full", "reduced", "auto"), help="MRGP over all k responses (full), in "
                           "a reduced output basis (reduced), or auto: reduced when k > 200 (the benchmark's k = 72 "
                           "keeps the full MRGP)")
    emulate: str = setting("modes", choices=EMULATES, help="what the paper loop's MRGP emulates: modes (the lowest "
                           "modes of each FE run and the rest of its receptance; the error of a candidate computed "
                           "from them, Gauss-Newton end points on the emulator's mean join the candidates, the "
                           "nominal model is a first sample) or errors (the paper's relative residuals)")
    conventional: bool = False
    conventional_samples: int = setting(300, help="uniform FE runs of the conventional baseline (Section 3.4)")
    seed: int = uses("seed", 0)

    @property
    def batch(self) -> int:
        """FE runs per iteration after the first."""
        return 1 if self.conventional else self.s

    @property
    def modes(self) -> bool:
        return self.emulate == "modes" and not self.conventional


def stage_rng(seed: int, iteration: int, step: str) -> np.random.Generator:
    """The generator of one step: a pure function of (seed, iteration, step), so a resumed run repeats it."""
    return np.random.default_rng([seed, iteration, STEPS.index(step)])


def first_samples(options: PaperOptions, lower, upper, nominal) -> np.ndarray:
    """Step c: the first FE batch, uniform in the box, shape (n, m); with the modes emulated the nominal
    model ``nominal`` (m,) (every factor 0, kept inside the solver's box) is the first sample."""
    n = options.conventional_samples if options.conventional else options.q
    X = uniform_samples(n, lower, upper, stage_rng(options.seed, 1, "samples"))
    if options.modes:
        X[0] = nominal
    return X


def distribution(options: PaperOptions, iteration: int, X, E, lower, upper) -> tuple[str, np.ndarray, np.ndarray,
                                                                                     float]:
    """Step f: (kind, mean, std, minimum distance) of the next candidates: uniform over the box in the first
    iteration (step c) and in the conventional baseline, else the normal distribution of the best z."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    if iteration == 1 or options.conventional:
        kind, mean, std, dist = "uniform", (lower + upper) / 2, (upper - lower) / np.sqrt(12), None
    else:
        dist = fit_distribution(X, E, options.z, options.std_floor)
        kind, mean, std = "normal", dist.mean, dist.std
    return kind, mean, std, default_min_distance(dist, lower, upper, options.min_distance_factor)


def candidates(options: PaperOptions, iteration: int, kind: str, mean, std, lower, upper) -> np.ndarray:
    """Step g: ``w`` candidates, shape (w, m), from the distribution of :func:`distribution`."""
    rng = stage_rng(options.seed, iteration, "predict")
    if kind == "uniform":
        return uniform_samples(options.w, lower, upper, rng)
    return draw_candidates(SamplingDistribution(np.asarray(mean), np.asarray(std)), options.w, lower, upper, rng)


def train(options: PaperOptions, iteration: int, X, Y, previous: dict | None, trainer: str | None = None,
          layout=None) -> tuple[dict, dict]:
    """The MRGP's hyper-parameters on the FE runs so far: (hyper-parameters, diagnostics).

    ``Y`` the emulated outputs: the relative residuals (``emulate = "errors"``, Table 1's ``l~`` bound from
    ``previous``) or the modal outputs of ``layout`` (one length scale per parameter, no bound; with a
    reduced output basis the modes get an MRGP of their own, :func:`.modal_emulation.separate_modes`).
    """
    kernel, outputs, extra = "iso", options.outputs, {}
    if layout is not None:
        separate = modal_emulation.separate_modes(options.outputs, layout)
        if separate:  # the hyper-parameters of the modes' own MRGP
            Y, outputs = Y[:, :layout.n_modal], "auto"
        extra = {"modal": {"modes": layout.n_modes, "outputs": layout.n_outputs, "modes_separate": separate}}
        kernel, previous = "ard", None  # no l~ bound: the modes do not sharpen as the samples gather
    rng = stage_rng(options.seed, iteration, "train")
    hyper, info = train_mrgp(X, Y, trainer or options.trainer, rng, previous, outputs=outputs, kernel=kernel)
    info.update(extra)
    return hyper, info


def predict(options: PaperOptions, C, X, Y, E, hyper: dict, fitted_outputs: str = "full", layout=None,
            residual=None, box=None) -> tuple[np.ndarray, np.ndarray]:
    """(candidates, predicted overall errors): the MRGP's Eq. (6b) of each candidate (``emulate =
    "errors"``), or the error of the receptance its emulated modes give with Gauss-Newton end points on the
    emulator appended (``layout``, ``residual``: the run's residual of the kept values, ``box``: the
    solver's (low, high))."""
    if layout is None:
        return C, predict_overall_error(X, Y, hyper, C, outputs=fitted_outputs)
    h = mrgp_core.Hyperparameters(length_scale=length_scales(hyper), nugget=float(hyper["nugget"]))
    return modal_emulation.predict(X, Y, E, layout, h, C, residual, box[0], box[1],
                                   modal_emulation.separate_modes(options.outputs, layout))


def select(options: PaperOptions, C, predicted, d_min: float, evaluated) -> np.ndarray:
    """Step d: indices of the next batch, the best predicted candidates at least ``d_min`` apart and from
    every sample evaluated so far."""
    return select_diverse(C, predicted, options.batch, d_min, exclude=evaluated)


def stop(options: PaperOptions, iteration: int, best: float, fe_count: int) -> StopDecision:
    """Step e after iteration ``iteration``'s FE runs (``best``: the lowest overall error so far)."""
    if options.conventional:
        return StopDecision(iteration == 2, best <= options.threshold,
                            "conventional: one MRGP, best prediction evaluated")
    return stopping_rule(best, options.threshold, iteration, options.max_iterations, fe_count, options.max_fe,
                         options.s)


class PaperLoop:
    """The loop (:class:`.base.Strategy`): the caller evaluates each iteration's batch.

    ``residual(Z) -> r`` maps the receptance at the k kept values (k,) to the residual vector (its Eq. 6b is
    the overall error); ``lower``, ``upper`` the search box; ``solver_box`` the box of Gauss-Newton runs and
    of the nominal sample; ``layout`` a :class:`mrgp_core.modal_outputs.ModalLayout` when the modes are
    emulated (the evaluation's outcomes then carry ``modes``); ``names`` the parameters (the stored tables'
    columns); ``memo`` where the steps of each iteration go (:class:`.base.Memo`): ``distribution``,
    ``train`` (the hyper-parameters), ``predict`` (the candidates), ``select`` (the next batch).
    """

    def __init__(self, options: PaperOptions, residual, lower, upper, solver_box: tuple, layout=None,
                 names=None, memo=None):
        self.options, self.residual, self.layout = options, residual, layout
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.solver_box = solver_box
        self.names = list(names) if names is not None else [f"alpha_{i + 1}" for i in range(self.lower.size)]
        self.memo = memo if memo is not None else InMemory()
        if self.options.modes and self.layout is None:
            raise ValueError("emulate = 'modes' needs the modal layout of the kept values")
        self.iteration = 0
        self.X = self.E = self.Y = None
        self.ids: list[int] = []  # request index of each successful run (the driver's sample id)
        self.Z: list[np.ndarray] = []  # and its receptance at the kept values
        self.history: list = []  # (iteration, X batch, errors batch)
        self.requests = 0
        self._previous = None
        self._decision = StopDecision(False, False, "start")
        nominal = np.clip(np.zeros(len(self.lower)), *self.solver_box)
        self._next = first_samples(self.options, self.lower, self.upper, nominal)

    def propose(self) -> Batch:
        k = self.iteration + 1
        return Batch(np.array(self._next), (False,) * len(self._next), f"iteration-{k}", k, "fe", self.options.modes)

    def update(self, batch: Batch, outcomes: Sequence) -> None:
        self.iteration += 1
        k = self.iteration
        rows, errors, outputs = [], [], []
        # where each run ended: the point asked, or where the evaluation moved it (local steps from it)
        where = np.array(batch.points, float)
        for i, out in enumerate(outcomes):
            if getattr(out, "at", None) is not None:
                where[i] = out.at
        for i, (x, out) in enumerate(zip(where, outcomes)):
            Z = np.asarray(out[0], complex)
            if not np.all(np.isfinite(Z)):
                continue  # a failed FE run is excluded
            r = self.residual(Z)
            rows.append(np.asarray(x, float))
            errors.append(float(np.mean(np.abs(r))))
            outputs.append(self.layout.outputs(*out.modes, Z) if self.options.modes else r)
            self.ids.append(self.requests + i)
            self.Z.append(Z)
        self.requests += len(batch)
        self.history.append((k, where, np.array(errors)))
        new = (np.array(rows).reshape(len(rows), self.lower.size), np.array(errors), np.array(outputs))
        self.X, self.E, self.Y = new if self.X is None else (np.vstack([self.X, new[0]]),
                                                             np.concatenate([self.E, new[1]]),
                                                             np.vstack([self.Y, new[2]]) if len(rows) else self.Y)
        best = float(self.E.min()) if self.E.size else float("inf")
        self._decision = stop(self.options, k, best, self.requests)
        if self._decision.stop:
            return
        dist = self.memo.step(k, "distribution", lambda: self._distribution(k))
        trained = self.memo.step(k, "train", lambda: self._train(k))
        hp = trained.table("hyperparameters")
        self._previous = dict(zip(hp["name"], map(float, hp["value"])))
        predicted = self.memo.step(k, "predict", lambda: self._predict(k, dist, trained))
        chosen = self.memo.step(k, "select", lambda: self._select(dist, predicted))
        sel = chosen.table("select")
        self._next = np.column_stack([np.asarray(sel[n], float) for n in self.names])

    # -- the steps of an iteration, each a :class:`.base.Step` --------------------------------------------------
    def _distribution(self, k: int) -> Step:
        kind, mean, std, d_min = distribution(self.options, k, self.X, self.E, self.lower, self.upper)
        return Step({"distribution": {"parameter": np.array(self.names), "mean": mean, "std": std}},
                    {"kind": kind, "min_distance": d_min})

    def _train(self, k: int) -> Step:
        import time

        layout = self.layout if self.options.modes else None
        t0 = time.perf_counter()
        hyper, info = train(self.options, k, self.X, self.Y, self._previous, layout=layout)
        seconds = time.perf_counter() - t0
        note = f"{self.options.trainer} on {self.X.shape[0]} runs in {seconds:.2f} s; outputs={self.options.outputs}"
        note += (f" -> reduced basis, k={info['n_responses']} responses -> r={info['components']} directions "
                 f"({100 * info['captured']:.3f} % of the standardised variance)" if info["outputs"] == "reduced"
                 else " -> full MRGP")
        return Step({"hyperparameters": {"name": np.array(list(hyper)), "value": np.array(list(hyper.values()),
                                                                                           float)}},
                    {"trainer": self.options.trainer, "seconds": seconds, "n_train": int(self.X.shape[0]), **info},
                    note)

    def _predict(self, k: int, dist: Step, trained: Step) -> Step:
        import time

        d = dist.table("distribution")
        C = candidates(self.options, k, dist.info["kind"], np.asarray(d["mean"], float), np.asarray(d["std"], float),
                       self.lower, self.upper)
        hp = trained.table("hyperparameters")
        hyper = dict(zip(hp["name"], map(float, hp["value"])))
        fitted_outputs = trained.info.get("outputs", "full")
        t0 = time.perf_counter()
        if self.options.modes:
            C, predicted = predict(self.options, C, self.X, self.Y, self.E, hyper, fitted_outputs, self.layout,
                                   self.residual, self.solver_box)
        else:
            C, predicted = predict(self.options, C, self.X, self.Y, self.E, hyper, fitted_outputs)
        table = {"candidate_id": np.arange(len(C), dtype=np.int64), **{n: C[:, j] for j, n in enumerate(self.names)},
                 "predicted_error": np.asarray(predicted, float)}
        return Step({"candidates": table}, {"seconds": time.perf_counter() - t0,
                                            "best_predicted": float(np.nanmin(predicted))})

    def _select(self, dist: Step, predicted: Step) -> Step:
        cand = predicted.table("candidates")
        C = np.column_stack([np.asarray(cand[n], float) for n in self.names])
        evaluated = np.vstack([points for _, points, _ in self.history])
        chosen = select(self.options, C, np.asarray(cand["predicted_error"], float),
                        float(dist.info["min_distance"]), evaluated)
        return Step({"select": {c: np.asarray(v)[chosen] for c, v in cand.items()}},
                    {"n": int(len(chosen)), "next_sample_id": self.requests})

    # -- the result ---------------------------------------------------------------------------------------------
    def stop(self) -> StopDecision:
        return self._decision

    def best(self) -> tuple[np.ndarray, float]:
        """The FE-evaluated point with the lowest overall error, and that error."""
        i = self.best_index()
        return self.X[i], float(self.E[i])

    def best_index(self) -> int:
        """Row of :meth:`best` among the successful runs (``ids[i]``, ``Z[i]``: its request index, receptance)."""
        if self.E is None or not self.E.size:
            raise ValueError("no successful FE run")
        return int(np.argmin(self.E))

    def stage_info(self, iteration: int, stage: str) -> dict:
        if stage != "fe" or not 1 <= iteration <= len(self.history):
            return {}
        return {"n": int(len(self.history[iteration - 1][1])),
                "modes": int(self.layout.n_modes) if self.options.modes else 0}

    def report(self) -> Report:
        """The run's result: from every FE run, but for the conventional baseline its final batch (its one MRGP's
        best prediction); converged when that result is at the threshold."""
        candidates = None
        if self.options.conventional and self.history:
            first = self.requests - len(self.history[-1][1])
            final = [i for i in self.ids if i >= first]
            candidates = final or None
        pool = self.E if candidates is None else self.E[[self.ids.index(i) for i in candidates]]
        converged = bool(pool.size and float(np.min(pool)) <= self.options.threshold)
        return Report(self._decision.reason, converged, candidates, iterations=self.iteration)
