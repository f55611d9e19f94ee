"""The hybrid strategy's phases, each a generator of rounds (driven by :class:`.hybrid.Hybrid`).

1. :func:`local_phase`: trust-region Gauss-Newton from a start with exact derivatives and the composite
   inverse-receptance model (:mod:`.gauss_newton`), one FE run with its Jacobian per round.
2. :func:`global_phase`: one round of space-filling points (uniform in ``sqrt(1 + x)``, ``warp``); an MRGP
   emulator of the log amplitudes on every FE run so far (the composite objective: the error is computed
   from the emulated responses); the ``starts`` best distinct candidates of ``w`` predicted ones, away from
   every minimum found, start Gauss-Newton runs side by side (one trial point each per round), the worse half
   dropped every ``halve_every`` rounds.

A phase yields ``(points, jacobian)`` and receives ``[(Z, dZ or None), ...]``; it returns where its
Gauss-Newton runs ended (:class:`Minimum`). Deterministic for a given seed and FE results (so a stored
run replays).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

import numpy as np

from fe_core.inference.residual import MAX_NOISE

from .base import InMemory, Step
from .gauss_newton import TrustRegionGN
from .ledger import BudgetSpent, Ledger
from .options import setting, uses

__all__ = ["HybridOptions", "Minimum", "local_phase", "global_phase", "WARPS"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class HybridOptions:
    """Settings of :func:`hybrid` (defaults: the measured choices of docs/results/suite.md).

    target : overall error (Eq. 6b) at which a Gauss-Newton run stops (the floor of noise-free data);
    step_tol : ... once the last accepted step was also below this (max-norm), so that the parameters,
        not only the error, have settled;
    noise : relative amplitude noise (standard deviation) for the check; None = estimated;
    max_noise : an estimated noise level above this is not believed (the residual is called structure): second
        differences over lines spaced wider than a resonance's half-power band see a wrong basin's misfit as
        "noise" of 25-90 % (measured on the cantilever example, docs/results/suite.md);
    significance : chi-square level below which the residual is structure ...
    noise_ratio : ... unless its rms is within this factor of the noise: with thousands of values the test
        rejects a misfit far below the noise (hammer.uff: rms 1.34 % against an estimated 1.10 %, p = 1e-173);
    max_cost : budget in FE-run equivalents (an FE run 1, one with its Jacobian ``jacobian_cost``);
    cap : a budget that follows the evidence: a phase running when ``max_cost`` is reached goes on, up to
        ``cap`` FE-run equivalents, while its rounds still improve its best error by ``improve_rtol`` (relative)
        over ``improve_rounds`` rounds (:meth:`.ledger.Ledger.admit`); None: stop at ``max_cost``. A run's
        cap is ``CAP_FACTOR`` times its budget (:mod:`.hybrid`; measured in docs/guide/closure-far-off.md);
    radius : first trust-region radius (max-norm); shrink, expand : its factors after a rejected and a good
        step (:class:`TrustRegionGN`); model : Gauss-Newton local model;
    optimum_std : a run has converged when the Gauss-Newton step from its centre is below this many standard
        deviations (:meth:`TrustRegionGN.step_in_std`; the intervals' test of the optimum): further rounds would
        move the parameters by less than the data can tell;
    stall_window, stall_rtol : ... or when its objective improved by less than ``stall_rtol`` (relative) over
        ``stall_window`` trial points;
    space_filling : FE runs of a global round (Sobol); candidates : emulator predictions per cycle;
    starts : parallel Gauss-Newton runs of a cycle; start_distance : their smallest max-norm distance;
    basin_radius : starts keep at least this max-norm distance from every minimum found;
    basin_rtol : a global cycle whose best minimum is not better than the best found before it by this much
        (relative overall error) ends the search for basins (status "basin"): it found the same basin again or a
        worse one, and what is left is for the closure (issue 40's held-out cases: hb13's cycles 2-4 ended within
        0.1 % of the local phase's 2.2474 %, 135 FE runs; hb14's within 3 %, 136); None: cycles go on to the budget;
    basin_near : ... but only where that best basin's overall error is at most this: farther off, a later cycle
        may still find a better basin (the development set, main at ``ba8b9b1``: dev08's cycles 2-4 came back to
        3.12 %, dev03's to 8.12-8.15 %, where the rule saves 68 and 90 FE runs; dev12's cycles 2 and 3 found
        nothing better than 40.5 % and its cycle 4 found 26.8 %); None: wherever it is;
    warp : "sqrt": the global phase's Sobol points and emulator candidates are uniform in ``sqrt(1 + x)``, and
        the emulator's inputs are ``sqrt(1 + x)`` (x a stiffness or mass factor ``1 + x``; a mode's frequency
        goes with its square root, so uniform-in-x points leave the soft end, where the frequencies move
        fastest, sparse); "none": uniform in x. Measured on the suite's 24 noise-free truths with five cycle
        seeds each: 112/120 solved with "none", 119/120 with "sqrt" (docs/results/suite.md); every truth that failed had
        a parameter at or below -0.86;
    halve_every : rounds between dropping the worse half of the runs;
    trainer, kernel : of the emulator (:func:`mrgp_core.fit`); seed : of the Sobol points and the trainer;
    weigh_early : weigh the evidence of a missing effect after the local phase, against the local fit, before any
        global round (set for a large model, whose global round is 20 FE runs of a minute or more each: the
        500k panel's took the whole machine's memory with two workers); a global round follows only on "basins".
    """

    target: float = uses("polish_target", 1e-4)
    step_tol: float = 1e-3
    noise: float | None = uses("noise", None)
    max_noise: float = MAX_NOISE
    noise_ratio: float = 1.5
    significance: float = 0.01
    max_cost: float = uses("max_fe_evaluations", 300.0)
    cap: float | None = None
    improve_rounds: int = 2
    improve_rtol: float = 0.05
    jacobian_cost: float = 2.5
    radius: float = 0.2
    shrink: float = 0.5
    expand: float = 2.0
    model: str = "inverse"
    optimum_std: float = 0.1
    stall_window: int = 4
    stall_rtol: float = 1e-2
    space_filling: int = uses("s", 20)
    candidates: int = uses("w", 10_000)
    starts: int = setting(6, help="parallel Gauss-Newton runs of a global cycle of the hybrid strategy, started "
                          "from the emulator's best distinct candidates")
    start_distance: float = 0.3
    basin_radius: float = 0.15
    basin_rtol: float | None = 0.01
    basin_near: float | None = 0.2
    halve_every: int = 2
    warp: str = "sqrt"
    trainer: str = uses("trainer", "gradient")
    kernel: str = "ard"
    seed: int = uses("seed", 0)
    weigh_early: bool = False


@dataclass(frozen=True)
class Minimum:
    """Where a Gauss-Newton run ended: ``status`` is "target", "converged" or "budget"."""

    x: np.ndarray
    Z: np.ndarray
    error: float
    status: str


def _settled(gn: TrustRegionGN, options: HybridOptions, last_step: float) -> str | None:
    if gn.error <= options.target and last_step <= options.step_tol:
        return "target"
    if gn.step_in_std() <= options.optimum_std or gn.stalled(options.stall_window, options.stall_rtol):
        return "converged"
    return None


def local_phase(ledger: Ledger, x0: np.ndarray, lower: np.ndarray, upper: np.ndarray, options: HybridOptions):
    """Gauss-Newton from ``x0`` until the target, convergence or the budget; one FE run with Jacobian per
    round. Returns the :class:`Minimum` (a generator: see the module docstring)."""
    x0 = np.clip(np.asarray(x0, float), lower, upper)
    (Z, dZ), = yield [x0], [True]  # BudgetSpent here ends the strategy: nothing was evaluated
    if not np.all(np.isfinite(Z)) or dZ is None:
        raise RuntimeError(f"the FE run at the start {x0.tolist()} failed")
    gn = TrustRegionGN(x0, Z, dZ, ledger.residual, lower, upper, radius=options.radius, model=options.model,
                       shrink=options.shrink, expand=options.expand)
    last_step = np.inf
    status = _settled(gn, options, last_step)
    reduced = False  # the centre's result came from a large model's reduced basis (not a full-order run)
    while True:
        while status is None:
            step = gn.propose()
            try:
                (Z, dZ), = yield [step.x], [True]
            except BudgetSpent:
                status = "budget"
                break
            before = gn.x.copy()
            if gn.tell(step.x, Z, dZ):
                last_step = float(np.max(np.abs(gn.x - before)))
                reduced = ledger.reduced[-1]
            status = _settled(gn, options, last_step)
        if not reduced or status == "budget":
            break
        # A reduced basis's centre is confirmed by a full-order run at the same point (the basis runs a point
        # it served once at full order when asked again: fe_core.solvers.reduced_basis); the centre takes the
        # full-order results, and the run goes on where they disagree with the reduced ones.
        try:
            (Z, dZ), = yield [gn.x.copy()], [True]
        except BudgetSpent:
            break
        reduced = ledger.reduced[-1]
        same = _confirmed(gn.Z, Z)
        gn.Z, gn.dZ, gn.f = np.asarray(Z), np.asarray(dZ), gn.objective(Z)
        # The full-order Jacobian decides too: a reduced one off by a few per cent moves Gauss-Newton's fixed point
        # (the stall rule does not: slow reduced rounds are no evidence of the full-order optimum)
        status = "converged" if same and gn.step_in_std() <= options.optimum_std else None
        if status is not None:
            break
        log.info("the full-order run at the reduced centre %s; Gauss-Newton goes on from it",
                 "gives another step" if same else "differs from it")
    return Minimum(gn.x.copy(), gn.Z.copy(), gn.error, status)


#: A reduced centre is confirmed when the full-order responses agree with it to this rms relative difference
#: (a tenth of the 1 % noise of measured data; the reduced basis aims at ~1e-5: fe_core.solvers.reduced_basis).
CONFIRM_RTOL = 1e-3


def _confirmed(Z_reduced, Z_full) -> bool:
    Z_full = np.asarray(Z_full)
    if not np.all(np.isfinite(Z_full)):
        return False
    rel = np.abs(np.asarray(Z_reduced) - Z_full) / np.maximum(np.abs(Z_full), np.finfo(float).tiny)
    return bool(np.sqrt(np.mean(rel**2)) <= CONFIRM_RTOL)


def _emulator_starts(ledger: Ledger, lower, upper, minima: list[np.ndarray], options: HybridOptions,
                     cycle: int) -> list[np.ndarray]:
    """The best distinct candidates by the emulator's composite objective, away from known minima."""
    import mrgp_core
    from scipy.stats import qmc  # here, not at the top: scipy.stats is 0.7 s of CPU to import, unused by most runs

    X = np.array([x for x, _ in ledger.responses])
    Y = np.log(np.abs(np.array([Z for _, Z in ledger.responses])))
    logu = np.log(ledger.residual.u)
    X, Y = _merge_duplicates(X, Y)
    rng = np.random.default_rng([options.seed, cycle, 1])
    fit = mrgp_core.fit_reduced if Y.shape[1] > 200 else mrgp_core.fit
    emulator = fit(_warped(X, options), Y, options.trainer, rng=rng, kernel=options.kernel)
    sobol = qmc.Sobol(lower.size, scramble=True, seed=np.random.default_rng([options.seed, cycle, 2]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Sobol balance: any count is fine here
        C = _from_unit(sobol.random(options.candidates), lower, upper, options)
    mean, _ = emulator.predict(_warped(C, options), return_var=False)
    # Composite: sum r^2 of the amplitude residual from the emulated log amplitudes (the phase is not emulated;
    # the score only ranks the starts).
    score = np.sum(np.expm1(mean - logu) ** 2, axis=1)
    starts: list[np.ndarray] = []
    for i in np.argsort(score, kind="stable"):
        x = C[i]
        if all(np.max(np.abs(x - mx)) > options.basin_radius for mx in minima) and \
                all(np.max(np.abs(x - s)) > options.start_distance for s in starts):
            starts.append(x)
            if len(starts) == options.starts:
                break
    return starts


WARPS = ("sqrt", "none")


def _warped(X: np.ndarray, options: HybridOptions) -> np.ndarray:
    """The coordinates the global phase samples and emulates in: ``sqrt(1 + x)`` or ``x``."""
    if options.warp == "sqrt":
        return np.sqrt(np.maximum(1.0 + X, 0.0))
    if options.warp == "none":
        return X
    raise ValueError(f"unknown warp {options.warp!r}; choose one of {', '.join(WARPS)}")


def _from_unit(q: np.ndarray, lower: np.ndarray, upper: np.ndarray, options: HybridOptions) -> np.ndarray:
    """Points of [0, 1]^m to the box, uniform in the warped coordinates (:func:`_warped`)."""
    if options.warp == "none":
        from scipy.stats import qmc  # here, not at the top: scipy.stats is 0.7 s of CPU to import, unused by most runs
        return qmc.scale(q, lower, upper)
    a, b = _warped(lower, options), _warped(upper, options)
    return np.clip((a + q * (b - a)) ** 2 - 1.0, lower, upper)


def _merge_duplicates(X, Y, rtol: float = 1e-9):
    keep, seen = [], []
    for i, x in enumerate(X):
        if not any(np.max(np.abs(x - s)) <= rtol for s in seen):
            keep.append(i)
            seen.append(x)
    return X[keep], Y[keep]


def global_phase(ledger: Ledger, lower: np.ndarray, upper: np.ndarray, minima: list[np.ndarray],
                 options: HybridOptions, cycle: int, memo=None, iteration: int | None = None):
    """One global cycle; returns where its Gauss-Newton runs ended (best first). BudgetSpent in its first
    two rounds (the space-filling points, the starts) goes through to the caller.

    The emulator's starts are the step ``emulator`` of ``iteration`` (default ``cycle + 1``) of ``memo``
    (:class:`.base.Memo`; default in memory): its table ``starts``, one row per start."""
    from scipy.stats import qmc  # here, not at the top: scipy.stats is 0.7 s of CPU to import, unused by most runs
    memo = memo if memo is not None else InMemory()
    iteration = cycle + 1 if iteration is None else iteration
    sobol = qmc.Sobol(lower.size, scramble=True, seed=np.random.default_rng([options.seed, cycle, 0]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        points = list(_from_unit(sobol.random(options.space_filling), lower, upper, options))
    yield points, [False] * len(points)

    def emulate() -> Step:
        found = _emulator_starts(ledger, lower, upper, minima, options, cycle)
        columns = np.array(found).reshape(len(found), lower.size)
        return Step({"starts": {f"x_{i + 1}": columns[:, i] for i in range(lower.size)}},
                    {"cycle": cycle, "trained_on": len(ledger.responses), "starts": len(found)},
                    f"{len(found)} starts from the emulator trained on {len(ledger.responses)} FE runs")

    table = memo.step(iteration, "emulator", emulate).table("starts")
    starts = list(np.column_stack([np.asarray(table[f"x_{i + 1}"], float) for i in range(lower.size)]))
    log.info("global cycle %d: %d starts from the emulator", cycle, len(starts))
    results = yield starts, [True] * len(starts)
    runs = [TrustRegionGN(x, Z, dZ, ledger.residual, lower, upper, radius=options.radius, model=options.model,
                          shrink=options.shrink, expand=options.expand)
            for x, (Z, dZ) in zip(starts, results) if np.all(np.isfinite(Z)) and dZ is not None]
    ended: list[Minimum] = []
    steps = {id(g): np.inf for g in runs}
    rounds = 0
    while runs:
        active = []
        for g in runs:
            status = _settled(g, options, steps[id(g)])
            if status is None:
                active.append(g)
            else:
                ended.append(Minimum(g.x.copy(), g.Z.copy(), g.error, status))
        if any(m.status == "target" for m in ended) or not active:
            runs = []
            break
        runs = active
        proposals = [g.propose() for g in runs]
        try:
            results = yield [p.x for p in proposals], [True] * len(proposals)
        except BudgetSpent:
            break
        for g, p, (Z, dZ) in zip(runs, proposals, results):
            before = g.x.copy()
            if g.tell(p.x, Z, dZ):
                steps[id(g)] = float(np.max(np.abs(g.x - before)))
        rounds += 1
        if rounds % options.halve_every == 0 and len(runs) > 1:
            runs = sorted(runs, key=lambda g: g.f)[: max(1, len(runs) // 2)]
    ended += [Minimum(g.x.copy(), g.Z.copy(), g.error, "budget") for g in runs]
    return sorted(ended, key=lambda m: m.error)
