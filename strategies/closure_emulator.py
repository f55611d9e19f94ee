"""A global search over (alpha, effect position, log size) with the MRGP, for an effect not yet located.

The closure's screen linearises every candidate at zero effect (:mod:`fe_core.closure.screening`); a sizeable effect moves
the modes by several half-power bandwidths, and the first-order change then ranks its true location
anywhere (on the benchmark with a 5 % point mass at node 337 the true node ranks 505th of 585 at the true
alpha). Where the screen does not locate the effect, this module searches the segment factors and the
effect together, globally, with the project's MRGP loop (the paper's loop, :class:`PaperLoop` ask/tell, as
:mod:`strategies.modal_paper` runs it on modes):

* **the space** (:class:`EffectSpace`): the unit cube over ``alpha`` (the closure's box, or a box round the
  update's alpha), the effect's position as continuous coordinates in the box of its candidate nodes (the axes
  along which they spread; a top face has no z) and ``log10`` of its size between :data:`SIZE_FLOOR` of its
  plausible upper bound and that bound. A point's location is the candidate node nearest its position;
* **the FE runs**: the extended model's FRF at the point (alpha, the effect at that node with that size),
  batched as the loop asks (joblib, threads); each run's output is the closure's own residual,
  ``ln(|Z_model| / u)`` at every kept value;
* **the emulator**: the MRGP over those residual vectors (``emulate = "errors"``, the paper's choice), which
  predicts every candidate's mean ``|r|`` (Eq. 6b of the log residual), selects the next batch and narrows;
* **the end**: the exact joint fit (:func:`fe_core.closure.fits.joint_fit`, alpha and the size together,
  exact Jacobians) at the best FE run's node from its alpha and from the update's, each with the run's size and
  3 and 10 times it (:data:`fe_core.closure.fits.SIZE_MULTIPLES`: a loop's best run may be a small mass), then the
  closure's relocation (:func:`fe_core.closure.selection.refine`: moves to a neighbour while they help).

Handed to :func:`fe_core.closure.loop.close_loop` as its ``first_round`` (``emulator=`` :func:`first_round` with
its options; the closure in ``fe_core`` knows no MRGP); an explicit option, not automatic:
where the baseline is far off (:func:`fe_core.closure.fits.far_off`) the emulated fit joins the first round's
checked candidates, so the usual decision, swaps, evidence and location spread weigh it against the rest.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from fe_core.inference.residual import log_residual
from fe_core.model import ParametricModel
from strategies.base import Batch, Outcome, run_loop
from strategies.paper import PaperLoop, PaperOptions

from fe_core.closure.effects import Applied, Effect, extended_frf
from fe_core.closure.fits import ALPHA_BOUNDS, SIZE_MULTIPLES, Fit, fit_update, joint_fit, log_sized

__all__ = ["EmulatorOptions", "EffectSpace", "EmulatedSearch", "emulated_search", "emulated_candidate", "first_round",
           "emulator", "SIZE_FLOOR"]

log = logging.getLogger(__name__)

#: Smallest size searched, as a share of the effect's plausible upper bound (a point mass of 0.1 % of the
#: structure's mass at the default bound of 20 %): below it an effect does not move a mode by a bandwidth.
SIZE_FLOOR = 5e-3


@dataclass(frozen=True)
class EmulatorOptions:
    """Settings of the emulated search.

    ``q`` FE runs first (uniform in the cube), ``s`` per later iteration, at most ``max_iterations``
    iterations and ``max_fe`` FE runs; ``z`` best runs shape the next sampling distribution and ``w``
    candidates are predicted per iteration (Table 2 of Zhou & Tang). ``alpha_radius``: half-width of the
    alpha box round the start (None: the whole closure box). ``n_jobs``: threads of the FE runs.
    ``local_steps``: trust-region steps of alpha and the size (exact Jacobians, the location kept) from each
    point the loop asks for; the loop then learns the end point and its residual (the hybrid's Gauss-Newton
    end points, on the joint space). 0: the plain loop, one FE run per point.
    """

    q: int = 40
    s: int = 20
    z: int = 20
    w: int = 5000
    max_iterations: int = 10
    max_fe: int = 240
    alpha_radius: float | None = None
    seed: int = 0
    n_jobs: int = 1
    trainer: str = "gradient"
    local_steps: int = 0

    def paper(self, threshold: float) -> PaperOptions:
        return PaperOptions(q=self.q, s=self.s, z=self.z, w=self.w, threshold=threshold,
                            max_iterations=self.max_iterations, max_fe=self.max_fe, trainer=self.trainer,
                            emulate="errors", seed=self.seed)


class EffectSpace:
    """The unit cube of the search and its map to (alpha, location, values) of one nodal effect."""

    def __init__(self, model: ParametricModel, effect: Effect, alpha_low, alpha_high,
                 size_floor: float = SIZE_FLOOR):
        if effect.n_parameters != 1:
            raise ValueError(f"the emulated search takes an effect of one size parameter, {effect.kind!r} has "
                             f"{effect.n_parameters}")
        self.effect = effect
        self.locations = list(effect.locations())
        pos = [effect.position(loc) for loc in self.locations]
        if not self.locations or any(p is None for p in pos):
            raise ValueError(f"the emulated search needs the positions of {effect.kind!r}'s locations (a mesh "
                             "model); a matrices model has no node coordinates")
        pos = np.asarray(pos, float)
        self.axes = np.flatnonzero(np.ptp(pos, axis=0) > 0)  # the axes along which the candidates spread
        self.pos_low, self.pos_high = pos.min(axis=0)[self.axes], pos.max(axis=0)[self.axes]
        self.tree = cKDTree(pos[:, self.axes])
        self.positions = pos
        self.alpha_low, self.alpha_high = np.asarray(alpha_low, float), np.asarray(alpha_high, float)
        hi = float(np.min(effect.bounds_at(self.locations[0])[1]))
        if not np.isfinite(hi) or hi <= 0:
            hi = 1e3 * float(effect.scale_at(self.locations[0])[0])
        low = size_floor * hi
        if log_sized(effect)[0]:  # a size searched in e-folds (a spring, soft to rigid): from a tenth of its scale
            low = min(low, 0.1 * float(effect.scale_at(self.locations[0])[0]))
        self.log_size = (np.log10(low), np.log10(hi))
        self.m = self.alpha_low.size
        self.dim = self.m + self.axes.size + 1

    def decode(self, t) -> tuple[np.ndarray, str, np.ndarray]:
        """(alpha, location, values) of a point ``t`` of the unit cube."""
        t = np.clip(np.asarray(t, float), 0.0, 1.0)
        m, k = self.m, self.axes.size
        alpha = self.alpha_low + t[:m] * (self.alpha_high - self.alpha_low)
        where = self.pos_low + t[m:m + k] * (self.pos_high - self.pos_low)
        location = self.locations[int(self.tree.query(where)[1])]
        size = 10.0 ** (self.log_size[0] + t[-1] * (self.log_size[1] - self.log_size[0]))
        return alpha, location, np.array([size])

    def encode(self, alpha, location: str, values) -> np.ndarray:
        """The point of the unit cube of (alpha, location, values) (clipped into the cube)."""
        span = np.where(self.alpha_high > self.alpha_low, self.alpha_high - self.alpha_low, 1.0)
        a = (np.asarray(alpha, float) - self.alpha_low) / span
        p = self.positions[self.locations.index(location)][self.axes]
        w = (p - self.pos_low) / (self.pos_high - self.pos_low)
        s = (np.log10(max(float(np.atleast_1d(values)[0]), 1e-300)) - self.log_size[0]) / (
            self.log_size[1] - self.log_size[0])
        return np.clip(np.concatenate([a, w, [s]]), 0.0, 1.0)


@dataclass
class EmulatedSearch:
    """What :func:`emulated_search` found: the exact joint fit at the end, the loop's best FE run, its cost."""

    fit: Fit
    location: str
    values: np.ndarray
    best_alpha: np.ndarray
    best_location: str
    best_values: np.ndarray
    best_error: float
    fe_runs: int
    fit_evaluations: int
    iterations: int
    stop_reason: str
    seconds: float
    history: list = field(default_factory=list)  # (iteration, best mean |r| so far, FE runs so far)
    moves: list = field(default_factory=list)

    def summary(self) -> str:
        return (f"emulated search: {self.fit.effect} at {self.location} = {self.values[0]:.4g} (the loop's best: "
                f"{self.best_location} = {self.best_values[0]:.4g}, mean |r| {self.best_error:.4g}); "
                f"{self.fe_runs} FE runs in {self.iterations} iterations ({self.stop_reason}), "
                f"{self.fit_evaluations} FE solves in the exact fit, {self.seconds:.1f} s")


def _evaluate(model, freqs, u, space: EffectSpace, points: np.ndarray, n_jobs: int, local_steps: int,
              alpha_bounds) -> tuple[np.ndarray, np.ndarray, int]:
    """(points evaluated, their log residual rows, FE solves): each point's extended model as asked
    (``local_steps`` = 0), or the end point of that many trust-region steps from it; a row of NaN where the FE
    run failed."""

    def one(t):
        alpha, location, values = space.decode(t)
        try:
            if local_steps <= 0:
                Z = extended_frf(model, alpha, freqs, [Applied(space.effect, location, values)])
                return t, log_residual(np.abs(Z), u).ravel(), 1
            fit = fit_update(model, freqs, u, alpha, space.effect, location, values, tol=1e-4,
                             max_evaluations=2 * local_steps, alpha_bounds=alpha_bounds)
            return space.encode(fit.alpha, location, fit.values), fit.residual.ravel(), fit.evaluations
        except (np.linalg.LinAlgError, RuntimeError, ValueError, FloatingPointError):
            return t, np.full(u.size, np.nan), 1

    if n_jobs == 1 or len(points) == 1:
        out = [one(t) for t in points]
    else:
        from joblib import Parallel, delayed

        out = Parallel(n_jobs=n_jobs, prefer="threads")(delayed(one)(t) for t in points)
    return np.array([o[0] for o in out]), np.array([o[1] for o in out]), sum(o[2] for o in out)


def emulated_search(model: ParametricModel, freqs_hz, amplitude, effect: Effect, alpha_start, *,
                    options: EmulatorOptions = EmulatorOptions(), noise: float | None = None,
                    alpha_bounds: tuple[float, float] = ALPHA_BOUNDS, refine_moves: int = 6) -> EmulatedSearch:
    """The MRGP loop over (alpha, position, log size) of ``effect``, then the exact joint fit from its best run.

    Parameters
    ----------
    model : ParametricModel (with a mesh: the locations need positions)
    freqs_hz : ndarray, shape (p,)
    amplitude : ndarray, shape (p, n)
        Measured amplitudes, m/N.
    effect : Effect
        A nodal effect of one size parameter (``point_mass``, a ``grounded_spring``).
    alpha_start : array_like, shape (m,)
        The update's (or the baseline's) alpha: a start of the exact fit, and the centre of the alpha box
        when ``options.alpha_radius`` is set.
    noise : float, optional
        The measurement's relative noise: the loop stops when a run's mean ``|ln(|Z| / u)|`` is within 1.5
        times the noise's (``sqrt(2 / pi) noise``); without it the loop runs to its budgets.
    refine_moves : int
        Most moves of the fitted effect to a better location after the exact fit (0: none).

    The search adds the first effect (no earlier effects in the model).
    """
    t0 = time.perf_counter()
    freqs = np.asarray(freqs_hz, float)
    u = np.asarray(amplitude, float)
    a0 = np.asarray(alpha_start, float)
    m = model.n_segments
    lo, hi = np.full(m, alpha_bounds[0]), np.full(m, alpha_bounds[1])
    if options.alpha_radius is not None:
        lo, hi = np.maximum(lo, a0 - options.alpha_radius), np.minimum(hi, a0 + options.alpha_radius)
    space = EffectSpace(model, effect, lo, hi)
    level = noise if isinstance(noise, (int, float)) else None  # a noise model (not one level): run to the budgets
    threshold = 0.0 if level is None else 1.5 * np.sqrt(2.0 / np.pi) * float(level)
    zeros, ones = np.zeros(space.dim), np.ones(space.dim)
    loop = PaperLoop(options.paper(threshold), np.real, zeros, ones, (zeros, ones))
    history, fe_runs, best = [], 0, np.inf

    def evaluate(batch: Batch) -> list[Outcome]:
        """The batch's FE runs; an outcome says where the run ended (the local steps' end point)."""
        nonlocal fe_runs, best
        points, rows, solves = _evaluate(model, freqs, u, space, batch.points, options.n_jobs,
                                         options.local_steps, alpha_bounds)
        fe_runs += solves
        errors = np.mean(np.abs(rows), axis=1)  # NaN for a failed run, which the loop excludes
        best = min(best, float(np.nanmin(errors))) if np.isfinite(errors).any() else best
        history.append((batch.iteration, best, fe_runs))
        log.info("emulated search, iteration %d: %d FE runs, best mean |r| %.4g", batch.iteration, fe_runs, best)
        return [Outcome(r.astype(complex), at=t) for r, t in zip(rows, points)]

    run_loop(loop, evaluate)
    t_best, e_best = loop.best()
    alpha, location, values = space.decode(t_best)
    log.info("emulated search: the loop's best run has %s at %s = %.4g, alpha %s (mean |r| %.4g); %s",
             effect.kind, location, values[0], np.round(alpha, 3), e_best, loop.stop().reason)
    starts = {"emulator": np.clip(alpha, *alpha_bounds), "update": np.clip(a0, *alpha_bounds)}
    fit = joint_fit(model, freqs, u, starts, effect, location, values, multiples=SIZE_MULTIPLES, primary=values,
                    alpha_bounds=alpha_bounds)
    evaluations = fit.evaluations
    moves: list[str] = []
    if refine_moves > 0:
        from fe_core.closure.selection import refine  # selection imports the screening; imported here, where it is used

        moved, moves = refine(model, freqs, u, fit, max_moves=refine_moves, alpha_bounds=alpha_bounds)
        evaluations = moved.evaluations
        fit = moved
        fit.start = fit.start or "emulator alpha, the emulator's size"
    fit.evaluations = evaluations
    result = EmulatedSearch(fit=fit, location=fit.location, values=np.asarray(fit.values, float), best_alpha=alpha,
                            best_location=location, best_values=values, best_error=e_best, fe_runs=fe_runs,
                            fit_evaluations=evaluations, iterations=loop.iteration, stop_reason=loop.stop().reason,
                            seconds=time.perf_counter() - t0, history=history, moves=moves)
    log.info("%s", result.summary())
    return result


def emulated_candidate(found: EmulatedSearch, effect: Effect) -> "Candidate":
    """The emulated search's fit as a checked candidate of the closure's first round (scored by
    :func:`fe_core.closure.decisions.decide` as any other)."""
    from fe_core.closure.screening import Candidate

    c = Candidate(effect=effect.kind, location=found.location, n_locations=len(effect.locations()),
                  linear_values=np.asarray(found.best_values, float), linear_rss=np.nan, linear_explained=np.nan,
                  fit=found.fit, moved_from=[m.split(" at ", 1)[1].split(" -> ")[0] for m in found.moves])
    found.fit.start = (f"emulated search ({found.fe_runs} FE solves, {found.iterations} iterations; its best run "
                       f"{found.best_location} = {found.best_values[0]:.4g}), then the exact joint fit")
    found.fit.evaluations = found.fe_runs + found.fit_evaluations  # the search's FE solves count as the check's
    return c


def first_round(model: ParametricModel, freqs_hz, amplitude, base: Fit, before, library: Sequence[Effect], *,
                options: EmulatorOptions = EmulatorOptions(), kinds: Sequence[str] = ("point_mass",),
                noise: float | None = None, significance: float = 0.01, per_type: int = 2, max_moves: int = 6,
                alpha_bounds: tuple[float, float] = ALPHA_BOUNDS,
                always: Sequence[str] = ("sensor_mass",)) -> dict:
    """The closure's first round with the emulated search's candidates among the checked ones.

    The round of :func:`fe_core.closure.selection.forward_select` (screen at ``base``, check the best of each kind
    in full, decide by extended BIC) plus, for each effect kind of ``kinds`` in ``library`` whose locations have
    positions, the emulated search's fit. Returns the keyword arguments that hand the round to
    ``forward_select`` (``start``, ``analysis``, ``steps``, ``rounds``; empty when nothing is added) and
    ``searches``, the :class:`EmulatedSearch` of each kind.
    """
    from fe_core.closure.decisions import decide, dedupe_counting, merge, rank
    from fe_core.closure.far.plausible import mark_first_negligible
    from fe_core.closure.fits import checks_per_type
    from fe_core.closure.screening import check_in_waves, pick_in_waves, screen
    from fe_core.inference.residual import analyse_residual

    freqs, u = np.asarray(freqs_hz, float), np.asarray(amplitude, float)
    by_kind = {e.kind: e for e in library}
    always = [k for k in always if k in by_kind]
    screened = screen(model, freqs, base, library)
    first, rest = pick_in_waves(screened, per_type, checks_per_type(base, per_type), always=always)
    checked = check_in_waves(model, freqs, u, base, by_kind, first, rest, max_moves, alpha_bounds, 100)
    searches = {}
    for kind in kinds:
        effect = by_kind.get(kind)
        if effect is None or effect.position(effect.locations()[0]) is None:
            continue
        searches[kind] = emulated_search(model, freqs, u, effect, base.alpha, options=options, noise=noise,
                                         alpha_bounds=alpha_bounds, refine_moves=max_moves)
        checked.append(emulated_candidate(searches[kind], effect))
    checked = dedupe_counting(checked)
    if before.structured:  # the first effect's size rule, as the flow's first round
        mark_first_negligible(model, freqs, base, checked, before.sigma)
    chosen = decide(base, before, checked)
    out: dict = {"searches": searches}
    if chosen is None:
        return out
    sigma = before.next_noise
    fit = chosen.fit
    analysis = analyse_residual(fit.residual, freqs, fit.n_parameters, sigma, significance, fit.relative(u))
    log.info("first round with the emulated search: added %s at %s = %s (start: %s)", chosen.effect, chosen.location,
             fit.values, fit.start)
    out.update(start=fit, analysis=analysis, steps=[chosen], rounds=[rank(merge(checked, screened))])
    return out


def emulator(options: EmulatorOptions = EmulatorOptions()):
    """The closure's first round with the emulated search, as :func:`fe_core.closure.loop.close_loop` takes it
    (``close_loop(..., emulator=emulator(options))``)."""
    import functools

    return functools.partial(first_round, options=options)
