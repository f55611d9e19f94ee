"""Local when the nominal model suffices, global when the data say it does not (issue 17's default).

Every FE run goes out in *rounds*: one call ``evaluate(points, jacobian)`` is
a batch whose runs may execute in parallel and which must finish before the
next is chosen. A run returns the complex receptance ``Z`` at the k measured
(frequency, sensor) pairs and, where ``jacobian`` asks for it, its exact
derivative ``dZ`` (k, m) (an adjoint on the FE model, :mod:`fe_core.solvers.sensitivity`;
its cost in FE-run equivalents is the caller's ``jacobian_cost``).

1. **Local phase** (:func:`local_phase`): trust-region Gauss-Newton from the
   nominal model with exact derivatives and the composite inverse-receptance
   model (:mod:`.gauss_newton`), one FE run with its Jacobian per round.
2. **Check** (:func:`check`): when the local phase has converged above the
   target, is what is left noise? The chi-square test of the log residual
   (:func:`fe_core.inference.residual.analyse_residual`) against the configured noise,
   or the noise estimated from second differences along frequency, which a
   misfit smooth in frequency (a wrong basin) does not inflate.
3. **Global phase** (:func:`global_phase`), only when the check finds
   structure: one round of space-filling points (uniform in ``sqrt(1 + x)``,
   ``warp``); an MRGP emulator of the log
   amplitudes on every FE run so far (the composite objective: the error is
   computed from the emulated responses); the ``starts`` best distinct
   candidates of ``w`` predicted ones, away from every minimum found, start
   Gauss-Newton runs side by side (one trial point each per round), the
   worse half dropped every ``halve_every`` rounds. The best run's end point
   is checked again; another cycle follows while the budget lasts.

Deterministic for a given seed and FE results (so a stored run replays).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import qmc

from fe_core.inference.residual import chi_square_test, estimate_noise

from .gauss_newton import Residual, TrustRegionGN

__all__ = ["HybridOptions", "Ledger", "Layout", "Minimum", "Check", "HybridResult", "local_phase", "check",
           "global_phase", "hybrid", "BudgetSpent", "Residual"]

log = logging.getLogger(__name__)

#: ``evaluate(points, jacobian) -> [(Z, dZ or None[, cost]), ...]``: one parallel round. An optional third
#: entry is that run's cost in FE runs (default 1, or ``jacobian_cost`` with a derivative).
Evaluate = Callable[[list, list], Sequence[tuple]]


@dataclass(frozen=True)
class Layout:
    """Where the k measured values sit: line ``line[i]`` (of ``freqs_hz``) and channel ``channel[i]``.

    ``Layout.grid(p, n)`` is the full frequency-major grid of Eq. 5.
    """

    freqs_hz: np.ndarray
    line: np.ndarray
    channel: np.ndarray

    @classmethod
    def grid(cls, freqs_hz, n: int) -> "Layout":
        p = len(freqs_hz)
        return cls(np.asarray(freqs_hz, float), np.repeat(np.arange(p), n), np.tile(np.arange(n), p))


@dataclass(frozen=True)
class HybridOptions:
    """Settings of :func:`hybrid` (defaults: the measured choices of docs/suite.md).

    target : overall error (Eq. 6b) at which a Gauss-Newton run stops (the floor of noise-free data);
    step_tol : ... once the last accepted step was also below this (max-norm), so that the parameters,
        not only the error, have settled;
    noise : relative amplitude noise (standard deviation) for the check; None = estimated;
    max_noise : an estimated noise level above this is not believed (the residual is called structure): second
        differences over lines spaced wider than a resonance's half-power band see a wrong basin's misfit as
        "noise" of 25-90 % (measured on the cantilever example, docs/suite.md);
    significance : chi-square level below which the residual is structure ...
    noise_ratio : ... unless its rms is within this factor of the noise: with thousands of values the test
        rejects a misfit far below the noise (hammer.uff: rms 1.34 % against an estimated 1.10 %, p = 1e-173);
    max_cost : budget in FE-run equivalents (an FE run 1, one with its Jacobian ``jacobian_cost``);
    radius : first trust-region radius (max-norm); shrink, expand : its factors after a rejected and a good
        step (:class:`TrustRegionGN`); model : Gauss-Newton local model;
    stall_window, stall_rtol : a run has converged when its objective improved by less than
        ``stall_rtol`` (relative) over ``stall_window`` trial points;
    space_filling : FE runs of a global round (Sobol); candidates : emulator predictions per cycle;
    starts : parallel Gauss-Newton runs of a cycle; start_distance : their smallest max-norm distance;
    basin_radius : starts keep at least this max-norm distance from every minimum found;
    warp : "sqrt": the global phase's Sobol points and emulator candidates are uniform in ``sqrt(1 + x)``, and
        the emulator's inputs are ``sqrt(1 + x)`` (x a stiffness or mass factor ``1 + x``; a mode's frequency
        goes with its square root, so uniform-in-x points leave the soft end, where the frequencies move
        fastest, sparse); "none": uniform in x. Measured on the suite's 24 noise-free truths with five cycle
        seeds each: 112/120 solved with "none", 119/120 with "sqrt" (docs/suite.md); every truth that failed had
        a parameter at or below -0.86;
    halve_every : rounds between dropping the worse half of the runs;
    hedge : when > 0, each local round adds an FE run (no Jacobian) at ``hedge`` times the trust radius, taken
        (with a Broyden update of the derivative) when it is better than the main trial point;
    trainer, kernel : of the emulator (:func:`mrgp_core.fit`); seed : of the Sobol points and the trainer.
    """

    target: float = 1e-4
    step_tol: float = 1e-3
    noise: float | None = None
    max_noise: float = 0.05
    noise_ratio: float = 1.5
    significance: float = 0.01
    max_cost: float = 300.0
    jacobian_cost: float = 2.5
    radius: float = 0.2
    shrink: float = 0.5
    expand: float = 2.0
    model: str = "inverse"
    stall_window: int = 4
    stall_rtol: float = 1e-2
    space_filling: int = 20
    candidates: int = 10_000
    starts: int = 6
    start_distance: float = 0.3
    basin_radius: float = 0.15
    halve_every: int = 2
    warp: str = "sqrt"
    hedge: float = 0.0
    trainer: str = "gradient"
    kernel: str = "ard"
    seed: int = 0


class BudgetSpent(Exception):
    """The next round would exceed the budget."""


@dataclass
class Ledger:
    """Counts every FE run, Jacobian and round; wraps the caller's ``evaluate``.

    ``history`` holds ``(round, x, error, with_jacobian, phase)`` in evaluation order.
    """

    evaluate: Evaluate
    residual: Residual
    max_cost: float
    jacobian_cost: float
    evaluations: int = 0
    jacobians: int = 0
    rounds: int = 0
    spent: float = 0.0
    history: list = field(default_factory=list)
    responses: list = field(default_factory=list)  # (x, Z) of every FE run, for the emulator

    @property
    def cost(self) -> float:
        """FE-run equivalents spent (as the runs reported them)."""
        return self.spent

    def round_cost(self, jacobian: Sequence[bool]) -> float:
        return sum(self.jacobian_cost if j else 1.0 for j in jacobian)

    def run(self, points: list, jacobian: Sequence[bool], phase: str) -> list[tuple[np.ndarray, np.ndarray | None]]:
        if not points:
            return []
        jacobian = [bool(j) for j in jacobian]
        if self.cost + self.round_cost(jacobian) > self.max_cost + 1e-9:
            raise BudgetSpent
        results = self.evaluate([np.asarray(x, float).copy() for x in points], jacobian)
        self.rounds += 1
        out = []
        for x, j, result in zip(points, jacobian, results):
            Z, dZ = result[0], result[1]
            Z = np.asarray(Z, complex).ravel()
            self.evaluations += 1
            self.jacobians += int(j)
            self.spent += float(result[2]) if len(result) > 2 else (self.jacobian_cost if j else 1.0)
            ok = bool(np.all(np.isfinite(Z)))
            error = self.residual.error(Z) if ok else np.inf
            self.history.append((self.rounds, np.asarray(x, float).copy(), error, j, phase))
            if ok:
                self.responses.append((np.asarray(x, float).copy(), Z))
            out.append((Z, None if dZ is None else np.asarray(dZ, complex)))
        return out

    def best(self) -> tuple[np.ndarray, float]:
        i = int(np.argmin([h[2] for h in self.history]))
        return self.history[i][1], self.history[i][2]


@dataclass(frozen=True)
class Minimum:
    """Where a Gauss-Newton run ended: ``status`` is "target", "converged" or "budget"."""

    x: np.ndarray
    Z: np.ndarray
    error: float
    status: str


@dataclass(frozen=True)
class Check:
    """Noise or structure at a minimum (:func:`check`)."""

    at_floor: bool
    reason: str
    rms: float
    sigma: float
    sigma_source: str
    p_chi2: float


def _settled(gn: TrustRegionGN, options: HybridOptions, last_step: float) -> str | None:
    if gn.error <= options.target and last_step <= options.step_tol:
        return "target"
    if gn.stalled(options.stall_window, options.stall_rtol):
        return "converged"
    return None


def local_phase(ledger: Ledger, x0: np.ndarray, lower: np.ndarray, upper: np.ndarray, options: HybridOptions,
                phase: str = "local") -> Minimum:
    """Gauss-Newton from ``x0`` until the target, convergence or the budget; one FE run with Jacobian per round."""
    x0 = np.clip(np.asarray(x0, float), lower, upper)
    try:
        (Z, dZ), = ledger.run([x0], [True], phase)
    except BudgetSpent:
        raise
    if not np.all(np.isfinite(Z)) or dZ is None:
        raise RuntimeError(f"the FE run at the start {x0.tolist()} failed")
    gn = TrustRegionGN(x0, Z, dZ, ledger.residual, lower, upper, radius=options.radius, model=options.model,
                      shrink=options.shrink, expand=options.expand)
    last_step = np.inf
    status = _settled(gn, options, last_step)
    while status is None:
        steps = [gn.propose()]
        if options.hedge > 0:
            hedge = gn.propose(options.hedge)
            if np.max(np.abs(hedge.x - steps[0].x)) > 1e-12:
                steps.append(hedge)
        try:
            results = ledger.run([s.x for s in steps], [True] + [False] * (len(steps) - 1), phase)
        except BudgetSpent:
            status = "budget"
            break
        pick = int(np.argmin([gn.objective(Z) for Z, _ in results]))
        before = gn.x.copy()
        if gn.tell(steps[pick].x, *results[pick]):
            last_step = float(np.max(np.abs(gn.x - before)))
        status = _settled(gn, options, last_step)
    return Minimum(gn.x.copy(), gn.Z.copy(), gn.error, status)


def check(Z: np.ndarray, residual: Residual, layout: Layout, n_fitted: int, options: HybridOptions) -> Check:
    """Is the residual at ``Z`` (shape (k,)) noise? The chi-square test of the log amplitude residual.

    ``ln(|Z| / |measured|)`` (:mod:`fe_core.inference.residual`: multiplicative noise is additive there) against the
    configured noise, or the noise estimated from second differences along frequency on the lines where every
    channel is kept; an estimate above ``max_noise`` is not believed. Noise when the test passes or the rms is
    within ``noise_ratio`` times the noise (a wrong basin leaves several times the noise: 10-40 % against
    1 % on the benchmark's suite).
    """
    Z = np.asarray(Z)
    error = residual.error(Z)
    r = np.log(np.abs(Z) / residual.u)
    rms = float(np.sqrt(np.mean(r**2)))
    if error <= options.target:
        return Check(True, f"overall error {error:.3e} <= target {options.target:.1e}", rms, float("nan"), "none", 1.0)
    p, n = len(layout.freqs_hz), int(layout.channel.max()) + 1
    grid = np.full((p, n), np.nan)
    grid[layout.line, layout.channel] = r
    complete = np.all(np.isfinite(grid), axis=1)
    if options.noise is not None:
        sigma, source = float(options.noise), "configured"
    else:
        sigma, source = estimate_noise(grid[complete], layout.freqs_hz[complete]), "estimated"
        if not (np.isfinite(sigma) and sigma > 0):
            return Check(False, "the noise cannot be estimated (no band of three complete lines) and is not "
                                "configured: treated as structure", rms, float("nan"), "none", 0.0)
    T, dof, p_chi2 = chi_square_test(r, sigma, n_fitted)
    reason = f"rms {rms:.3%} vs noise {sigma:.3%} ({source}); chi2 {T:.1f} on {dof} dof, p = {p_chi2:.3g}"
    if source == "estimated" and sigma > options.max_noise:
        return Check(False, f"{reason}; but an estimated noise of {sigma:.1%} is above the {options.max_noise:.0%} "
                            "believed for measured amplitudes: structure", rms, sigma, source, p_chi2)
    at_floor = p_chi2 >= options.significance or rms <= options.noise_ratio * sigma
    why = "noise" if p_chi2 >= options.significance else (f"rms within {options.noise_ratio:g} x the noise"
                                                           if at_floor else "structure")
    return Check(at_floor, f"{reason}: {why}", rms, sigma, source, p_chi2)


def _emulator_starts(ledger: Ledger, lower, upper, minima: list[np.ndarray], options: HybridOptions,
                     cycle: int) -> list[np.ndarray]:
    """The best distinct candidates by the emulator's composite objective, away from known minima."""
    import mrgp_core

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
                 options: HybridOptions, cycle: int) -> list[Minimum]:
    """One global cycle; returns where its Gauss-Newton runs ended (best first). Raises BudgetSpent."""
    phase = f"global-{cycle}"
    sobol = qmc.Sobol(lower.size, scramble=True, seed=np.random.default_rng([options.seed, cycle, 0]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        points = list(_from_unit(sobol.random(options.space_filling), lower, upper, options))
    ledger.run(points, [False] * len(points), phase)
    starts = _emulator_starts(ledger, lower, upper, minima, options, cycle)
    log.info("global cycle %d: %d starts from the emulator", cycle, len(starts))
    results = ledger.run(starts, [True] * len(starts), phase)
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
            results = ledger.run([p.x for p in proposals], [True] * len(proposals), phase)
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


@dataclass(frozen=True)
class HybridResult:
    """Outcome of :func:`hybrid`.

    x, error : best point and its overall error (Eq. 6b); status : "target", "floor" (the check found
    noise) or "budget"; evaluations, jacobians, rounds, cost (FE-run equivalents); minima : where
    Gauss-Newton runs ended; checks : (minimum, Check) in order; history : see :class:`Ledger`.
    """

    x: np.ndarray
    error: float
    status: str
    evaluations: int
    jacobians: int
    rounds: int
    cost: float
    minima: list
    checks: list
    history: list


def hybrid(evaluate: Evaluate, x0: np.ndarray, residual, layout, lower: np.ndarray, upper: np.ndarray,
           options: HybridOptions = HybridOptions()) -> HybridResult:
    """Run the whole strategy from ``x0`` (the nominal model).

    ``residual`` is a :class:`Residual` (or the measured amplitudes, shape (k,)); ``layout`` a
    :class:`Layout` of the k values (or the frequencies, shape (p,), of a full frequency-major grid).
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    residual = residual if isinstance(residual, Residual) else Residual(residual)
    if not isinstance(layout, Layout):
        layout = Layout.grid(layout, residual.u.size // len(layout))
    ledger = Ledger(evaluate, residual, options.max_cost, options.jacobian_cost)
    minima: list[Minimum] = []
    checks: list = []
    status = "budget"
    try:
        found = [local_phase(ledger, x0, lower, upper, options)]
        cycle = 0
        while True:
            best = found[0]
            minima += found
            verdict = check(best.Z, residual, layout, lower.size, options)
            checks.append((best, verdict))
            if best.status == "target" or verdict.at_floor:
                status = "target" if best.status == "target" else "floor"
                break
            cycle += 1
            found = global_phase(ledger, lower, upper, [m.x for m in minima], options, cycle)
            if not found:
                break
    except BudgetSpent:
        pass
    x, error = ledger.best()
    return HybridResult(x=x, error=error, status=status, evaluations=ledger.evaluations, jacobians=ledger.jacobians,
                        rounds=ledger.rounds, cost=ledger.cost, minima=minima, checks=checks, history=ledger.history)
