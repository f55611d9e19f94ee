"""The paper's adaptive MRGP loop (Zhou & Tang, Table 2) as a strategy, and its steps.

One iteration k of the loop::

    samples -> FE runs -> errors -> stop? -> distribution -> train -> predict -> select -> samples of k + 1

The steps are pure functions of arrays (:func:`first_samples`, :func:`distribution`, :func:`candidates`,
:func:`train`, :func:`predict`, :func:`select`, :func:`stop`), each with its own generator
(:func:`stage_rng`, a pure function of seed, iteration and step). The flow runs them one per stage with
their results stored (``tasks/paper.py``); :class:`PaperLoop` chains them in memory behind the strategy
interface (:mod:`.base`), so both make the same samples from the same FE results.

What the MRGP emulates (``emulate``): ``"errors"``, the paper's relative residuals (isotropic kernel,
Table 1's ``l~`` bound); ``"modes"`` (default, beyond the paper), the lowest modes and the rest of the
receptance of each FE run (:mod:`.modal_emulation`), the nominal model being one of the first samples.
``conventional``: Section 3.4's baseline, ``conventional_samples`` uniform FE runs, one MRGP, the best of
``w`` predictions evaluated.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

import mrgp_core

from . import modal_emulation
from .base import Batch, StopDecision
from .emulation import length_scales, predict_overall_error, train_mrgp
from .table2 import (default_min_distance, draw_candidates, fit_distribution, select_diverse, stopping_rule,
                     uniform_samples, SamplingDistribution)

__all__ = ["PaperOptions", "PaperLoop", "STEPS", "stage_rng", "first_samples", "distribution", "candidates",
           "train", "predict", "select", "stop"]

#: The loop's steps, in order; each has its own generator (:func:`stage_rng`).
STEPS = ("samples", "fe", "errors", "distribution", "train", "predict", "select")
EMULATES = ("modes", "errors")


@dataclass(frozen=True)
class PaperOptions:
    """Settings of the loop (Table 2 of Zhou & Tang; see ``flows/config.py`` for each key)."""

    q: int = 20
    s: int = 20
    z: int = 20
    w: int = 10_000
    threshold: float = 0.01
    max_iterations: int = 12
    max_fe: int = 240
    min_distance_factor: float = 0.1
    std_floor: float = 1e-4
    trainer: str = "gradient"
    outputs: str = "auto"
    emulate: str = "modes"
    conventional: bool = False
    conventional_samples: int = 300
    seed: int = 0

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


@dataclass
class PaperLoop:
    """The loop in memory (:class:`.base.Strategy`): the caller evaluates each iteration's batch.

    ``residual(Z) -> r`` maps the receptance at the k kept values (k,) to the residual vector (its Eq. 6b is
    the overall error); ``lower``, ``upper`` the search box; ``solver_box`` the box of Gauss-Newton runs and
    of the nominal sample; ``layout`` a :class:`mrgp_core.modal_outputs.ModalLayout` when the modes are
    emulated (the evaluation's outcomes then carry ``modes``).
    """

    options: PaperOptions
    residual: object
    lower: np.ndarray
    upper: np.ndarray
    solver_box: tuple
    layout: object = None
    iteration: int = 0
    X: np.ndarray = field(default=None)
    E: np.ndarray = field(default=None)
    Y: np.ndarray = field(default=None)
    history: list = field(default_factory=list)  # (iteration, X batch, errors batch)
    _next: np.ndarray = field(default=None)
    _previous: dict | None = None
    _decision: StopDecision = field(default_factory=lambda: StopDecision(False, False, "start"))

    def __post_init__(self) -> None:
        if self.options.modes and self.layout is None:
            raise ValueError("emulate = 'modes' needs the modal layout of the kept values")
        nominal = np.clip(np.zeros(len(self.lower)), *self.solver_box)
        self._next = first_samples(self.options, self.lower, self.upper, nominal)

    def propose(self) -> Batch:
        return Batch(np.array(self._next), (False,) * len(self._next), f"iteration-{self.iteration + 1}")

    def update(self, batch: Batch, outcomes: Sequence) -> None:
        self.iteration += 1
        k = self.iteration
        rows, errors, outputs = [], [], []
        for x, out in zip(batch.points, outcomes):
            Z = np.asarray(out[0], complex)
            if not np.all(np.isfinite(Z)):
                continue  # a failed FE run is excluded
            r = self.residual(Z)
            rows.append(np.asarray(x, float))
            errors.append(float(np.mean(np.abs(r))))
            outputs.append(self.layout.outputs(*out.modes, Z) if self.options.modes else r)
        self.history.append((k, np.array(batch.points), np.array(errors)))
        new = (np.array(rows), np.array(errors), np.array(outputs))
        self.X, self.E, self.Y = new if self.X is None else (np.vstack([self.X, new[0]]),
                                                             np.concatenate([self.E, new[1]]),
                                                             np.vstack([self.Y, new[2]]))
        fe_count = sum(len(h[1]) for h in self.history)
        self._decision = stop(self.options, k, float(self.E.min()), fe_count)
        if self._decision.stop:
            return
        kind, mean, std, d_min = distribution(self.options, k, self.X, self.E, self.lower, self.upper)
        layout = self.layout if self.options.modes else None
        hyper, info = train(self.options, k, self.X, self.Y, self._previous, layout=layout)
        self._previous = hyper
        C = candidates(self.options, k, kind, mean, std, self.lower, self.upper)
        C, predicted = predict(self.options, C, self.X, self.Y, self.E, hyper, info["outputs"], layout,
                               self.residual, self.solver_box)
        evaluated = np.vstack([h[1] for h in self.history])
        self._next = C[select(self.options, C, predicted, d_min, evaluated)]

    def stop(self) -> StopDecision:
        return self._decision

    def best(self) -> tuple[np.ndarray, float]:
        """The FE-evaluated point with the lowest overall error, and that error."""
        i = int(np.argmin(self.E))
        return self.X[i], float(self.E[i])
