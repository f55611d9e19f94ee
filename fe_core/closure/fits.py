"""Least-squares fits of alpha on the FE model, with or without effects: :class:`Fit`, :func:`fit_update`
(exact Krylov Jacobian or forward differences), :func:`multistart_update`, :func:`baseline` (the alpha-only
fit and its residual analysis, the closure's first step) and :func:`error_summary`.

The closure's steps are listed in :mod:`fe_core.closure`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .effects import Applied, Effect, LinearisedResponse, extended_frf
from ..model import ParametricModel, check_parameters
from ..inference.residual import (
    ResidualAnalysis,
    analyse_residual,
    log_residual,
    overall_error,
    per_sensor_error,
    relative_residual,
)

__all__ = [
    "Fit",
    "fit_update",
    "joint_fit",
    "alpha_starts",
    "far_off",
    "checks_per_type",
    "size_starts",
    "log_sized",
    "multistart_update",
    "baseline",
    "error_summary",
]


log = logging.getLogger(__name__)

#: Scale of the stiffness factors in fits.
ALPHA_SCALE = 0.1
#: Forward-difference step of fit_update, relative to each parameter's scale (see its docstring).
FD_STEP = 1e-4
#: Floor of a log-parameterised size, relative to its scale (a spring of 1e-3 x 1e5 N/m is no spring).
LOG_FLOOR = 1e-3
#: Default fit bounds of alpha: the updating flow's default box [-1, 1], kept 0.05 off -1, where
#: a segment's stiffness vanishes and the least-squares landscape turns steep and ill-conditioned.
ALPHA_BOUNDS = (-0.95, 1.0)


@dataclass
class Fit:
    """A least-squares fit of alpha, with or without one effect.

    Attributes
    ----------
    alpha : ndarray, shape (m,)
    effect : str or None
        Effect kind.
    location : str or None
    values : ndarray, shape (k,)
        Effect parameters (empty without an effect).
    model_amplitude : ndarray, shape (p, n), m/N
    residual : ndarray, shape (p, n)
        ``ln(|Z_model| / u)``.
    evaluations : int
        FE FRF evaluations made by the fit.
    seconds : float
    message : str
    """

    alpha: np.ndarray
    effect: str | None
    location: str | None
    values: np.ndarray
    model_amplitude: np.ndarray
    residual: np.ndarray
    evaluations: int
    seconds: float = 0.0
    message: str = ""
    #: Effects added at earlier steps, with their values refitted in this fit.
    prior: list = field(default_factory=list)
    #: The newest effect as an :class:`fe_core.closure.effects.Applied` (None without one).
    added: Applied | None = None
    #: Which start of a multi-start joint fit won (:func:`joint_fit`; empty for a single start).
    start: str = ""

    @property
    def rss(self) -> float:
        return float(np.sum(self.residual**2))

    @property
    def n_parameters(self) -> int:
        return self.alpha.size + self.values.size + sum(a.values.size for a in self.prior)

    @property
    def applied(self) -> list:
        """All effects of the fit, in the order added (earlier ones, then the newest)."""
        return list(self.prior) + ([] if self.added is None else [self.added])

    def relative(self, amplitude: np.ndarray) -> np.ndarray:
        return relative_residual(self.model_amplitude, amplitude)


# -- fitting ------------------------------------------------------------------------------------------
def log_sized(effect: Effect) -> np.ndarray:
    """Which of an effect's parameters a fit searches in ln(value) (``Effect.log_sizes``; none by default):
    sizes that span decades, non-negative, such as a spring from soft to nearly rigid."""
    flags = tuple(getattr(effect, "log_sizes", ()) or ())
    return np.array([bool(flags[i]) if i < len(flags) else False for i in range(effect.n_parameters)], bool)


def _amplitudes(model, alpha, freqs, applied) -> np.ndarray:
    return np.abs(extended_frf(model, alpha, freqs, applied))


def fit_update(model: ParametricModel, freqs_hz, amplitude, alpha0, effect: Effect | None = None,
               location: str | None = None, value0=None, *, max_evaluations: int = 600, tol: float = 1e-8,
               alpha_bounds: tuple[float, float] = ALPHA_BOUNDS, prior: Sequence[Applied] = (),
               jacobian: str = "exact") -> Fit:
    """Least squares on the FE model over alpha (and the effects' parameters) from a start point.

    Minimises ``sum ln(|Z_model| / u)^2`` with scipy's trust-region
    reflective method (``least_squares``, ``trf``) in parameters scaled by
    their typical size, by default (``jacobian="exact"``) with the exact Jacobian of
    :class:`fe_core.closure.effects.LinearisedResponse` (one Krylov space of the load
    and the sensor loads per point gives the FRF and its derivatives with
    respect to every parameter, about 1.3 FRF costs, where forward
    differences cost one FRF per parameter); the parameters stay inside their
    valid domains. The exact derivatives are those of the reduced model whose
    FRF is returned, so they carry no difference error at all.

    ``jacobian="difference"`` is the reference: forward differences of step
    ``FD_STEP`` = 1e-4 of each parameter's scale (1e-5 in alpha). That step is
    set by the FRF's accuracy, not by round-off of one CPU: the Krylov FRF
    agrees with the direct solve to 1e-10 on the benchmark's banded path but
    only to ~1e-8 on PARDISO's (``fe_core.solvers.frf.STAGNATION_RTOL``), and a forward
    difference over a step h carries that error divided by h. At 1e-7 in alpha
    the Jacobian of the cantilever example was 0.4 % wrong, and on another
    CPU's BLAS kernels the fit stopped early (``xtol``) at a cost 42 % above
    the optimum; at 1e-5 the error is 3e-4 (truncation and round-off balanced;
    2e-5 on the benchmark) and the fit reaches the same optimum from either CPU.

    Parameters
    ----------
    model : ParametricModel
    freqs_hz : ndarray, shape (p,)
    amplitude : ndarray, shape (p, n)
        Measured amplitudes, m/N.
    alpha0 : array_like, shape (m,)
    effect, location : Effect and one of its locations, optional
    value0 : array_like, shape (k,), optional
        Start of the effect's parameters (zero by default).
    max_evaluations : int
        Budget of FE evaluations (each a Krylov space that gives the FRF and the Jacobian; with
        ``jacobian="difference"`` one FRF, difference columns included).
    tol : float
        ``ftol``, ``xtol`` and ``gtol`` of the optimiser.
    alpha_bounds : (float, float)
        Box of every alpha_i; the lower edge must be above -1.
    prior : sequence of Applied
        Effects added before: refitted together with alpha (and ``effect``),
        from their values. Their refitted values are in ``Fit.prior``.
    jacobian : {"exact", "difference"}
        The derivatives: exact on the Krylov space (default) or forward differences of step ``FD_STEP``.
    """
    t0 = time.perf_counter()
    if jacobian not in ("exact", "difference"):
        raise ValueError(f"unknown Jacobian {jacobian!r}; choose 'exact' or 'difference'")
    if not alpha_bounds[0] > -1.0:
        raise ValueError(f"the lower bound of alpha must be above -1, got {alpha_bounds[0]}")
    freqs = np.asarray(freqs_hz, float)
    u = np.asarray(amplitude, float)
    m = model.n_segments
    alpha0 = check_parameters(alpha0, m, "alpha")
    parts = [(np.full(m, ALPHA_SCALE), np.full(m, alpha_bounds[0]), np.full(m, alpha_bounds[1]), alpha0.copy(),
              np.zeros(m, bool))]
    items = [(a.effect, a.location, np.atleast_1d(np.asarray(a.values, float))) for a in prior]
    if effect is not None:
        items.append((effect, location, np.zeros(effect.n_parameters) if value0 is None
                      else np.atleast_1d(np.asarray(value0, float))))
    for eff, loc, v0 in items:
        elo, ehi = eff.bounds_at(loc)
        parts.append((eff.scale_at(loc), elo, ehi, v0, log_sized(eff)))
    scale, lo, hi, theta0, logp = (np.concatenate(x) for x in zip(*parts))
    logp = logp.astype(bool)
    sizes = np.cumsum([m] + [eff.n_parameters for eff, _, _ in items])

    def applied_at(theta):
        return [Applied(eff, loc, theta[a:b]) for (eff, loc, _), a, b in zip(items, sizes[:-1], sizes[1:])]
    # Strictly inside the box (least_squares' requirement), by a hair of each scale.
    theta0 = np.clip(theta0, lo + 1e-6 * scale, hi - 1e-6 * scale)
    # Log-parameterised sizes (springs from soft to nearly rigid in one search): the fit's coordinate is
    # ln(value / scale), one unit an e-fold; from zero (the effect's absence, where the log has no slope)
    # they start at their scale, and their floor is LOG_FLOOR of it.
    floor = np.maximum(lo, LOG_FLOOR * scale)
    theta0 = np.where(logp & (theta0 <= floor), np.maximum(scale, floor * (1 + 1e-6)), theta0)
    z0 = np.where(logp, np.log(np.maximum(theta0, floor) / scale), 0.0)

    def theta_at(x):
        with np.errstate(over="ignore"):
            return np.where(logp, np.clip(scale * np.exp(z0 + x), floor, hi), np.clip(theta0 + scale * x, lo, hi))

    def dtheta(theta):
        return np.where(logp, theta, scale)
    count = [0]
    last: dict = {}

    def response(x) -> LinearisedResponse:
        """The FRF and its derivatives at x (the last point is kept: trf asks for the Jacobian where it
        has just evaluated the residual)."""
        if last.get("x") is None or not np.array_equal(last["x"], x):
            theta = theta_at(x)
            count[0] += 1
            last["x"] = np.array(x, copy=True)
            last["lin"] = LinearisedResponse(model, theta[:m], freqs, applied_at(theta))
        return last["lin"]

    def fun(x):
        return log_residual(response(x).amplitude, u).ravel()

    def fun_difference(x):
        theta = theta_at(x)
        count[0] += 1
        return log_residual(_amplitudes(model, theta[:m], freqs, applied_at(theta)), u).ravel()

    def jac(x):
        lin = response(x)
        cols = [lin.alpha_derivatives()] + [lin.effect_derivatives(a.effect, a.location) for a in lin.applied]
        return np.column_stack(cols) * dtheta(theta_at(x))[None, :]

    with np.errstate(invalid="ignore", divide="ignore"):
        lb = np.where(logp, np.log(floor / scale) - z0, (lo - theta0) / scale)
        ub = np.where(logp, np.log(hi / scale) - z0, (hi - theta0) / scale)
    if jacobian == "exact":
        result = least_squares(fun, np.zeros(theta0.size), jac=jac, bounds=(lb, ub), method="trf",
                               ftol=tol, xtol=tol, gtol=tol, max_nfev=max(1, max_evaluations // 2))
    else:
        result = least_squares(fun_difference, np.zeros(theta0.size), bounds=(lb, ub), method="trf",
                               diff_step=FD_STEP, ftol=tol, xtol=tol, gtol=tol,
                               max_nfev=max(1, max_evaluations // (theta0.size + 1)))
    theta = theta_at(result.x)
    r = result.fun.reshape(u.shape)
    applied = applied_at(theta)
    added = applied.pop() if effect is not None else None
    return Fit(alpha=theta[:m], effect=None if effect is None else effect.kind, location=location,
               values=np.array([]) if added is None else added.values, model_amplitude=np.exp(r) * u, residual=r,
               evaluations=count[0], seconds=time.perf_counter() - t0, message=str(result.message),
               prior=applied, added=added)


#: A residual whose rms (of ln |Z_model| / u) exceeds this is far off (:func:`far_off`): 5 %, ten times the
#: 0.5 % noise of the data sets. The base fits of the benchmark's effect data sets leave 0.4-2.7 %, where one
#: start suffices (and the extra starts cost 3.7 x the closure's CPU time on the two-effect data); those
#: where the single start ended in a wrong basin leave 46-103 % (cantilever: 6 kg mass, 5e7 N/m spring).
FAR_RMS = 0.05
#: Candidates per kind checked where the residual is far off (:func:`checks_per_type`). Linearised at zero,
#: a large effect's location ranks low: on the plate with a patch at 10 % of its stiffness the true patch
#: screens 5th of its kind (behind its neighbours fitted at -0.24 to -0.29, one at the bound -1).
FAR_PER_TYPE = 5
#: Multiples of the linearised size tried as starts of a joint fit (:func:`joint_fit`): the screen linearises at
#: zero effect and underestimates large effects (a 19 % point mass screened at 3.6 kg for 6.0 kg).
SIZE_MULTIPLES = (1.0, 3.0, 10.0)
#: Coarse fits of the other starts: budget of FE evaluations and tolerance (the best is refined after).
COARSE_EVALUATIONS = 40
COARSE_TOL = 1e-4
#: Another start replaces the first only if its fit lowers the sum of squares by this share (a different
#: basin, not the optimiser's tolerance: the fits converge to 1e-6).
BETTER_START = 1e-3


def far_off(fit: Fit, far: float | None = None) -> bool:
    """The residual says the model is far off: the rms of the fit's log residual exceeds ``far``
    (:data:`FAR_RMS`). There the linear screen's sizes and the update's factors are poor starts, and a joint
    fit tries several (:func:`joint_fit`); nearer, one start does."""
    far = FAR_RMS if far is None else far
    return bool(np.sqrt(np.mean(fit.residual**2)) > far)


def checks_per_type(base: Fit, per_type: int) -> int:
    """Candidates of each kind given a full check: ``per_type``, at least :data:`FAR_PER_TYPE` where the
    residual is far off (:func:`far_off`): the linear screen ranks large effects poorly."""
    return max(per_type, FAR_PER_TYPE) if far_off(base) else per_type


def alpha_starts(model: ParametricModel, alpha, alpha_bounds: tuple[float, float] = ALPHA_BOUNDS) -> dict:
    """The starts of alpha of a joint fit: the update's (``alpha``) and the nominal model's (zero, inside the
    box), one of them only when they coincide."""
    update = np.asarray(alpha, float)
    nominal = np.clip(np.zeros(model.n_segments), alpha_bounds[0], alpha_bounds[1])
    return {"update": update} if np.allclose(update, nominal, atol=1e-3) else {"update": update, "nominal": nominal}


def size_starts(effect: Effect, location: str, linear, multiples: Sequence[float] = SIZE_MULTIPLES) -> list:
    """Start values of an effect's size: ``multiples`` of the linearised ``linear``, inside the plausible box
    (kept a tenth of the way off a finite bound that is not zero, which is no start; a bound at zero keeps its
    sign), duplicates dropped; ``[(label, values)]``."""
    lo, hi = effect.bounds_at(location)
    scale = effect.scale_at(location)
    v = np.atleast_1d(np.asarray(linear, float))
    span = np.where(np.isfinite(hi - lo), hi - lo, np.abs(v) * max(multiples, default=1.0) + scale)
    inner_lo = np.where(np.isfinite(lo) & (lo != 0), lo + 0.1 * np.minimum(span, np.abs(lo)), lo)
    inner_hi = np.where(np.isfinite(hi) & (hi != 0), hi - 0.1 * np.minimum(span, np.abs(hi)), hi)
    out, seen = [], []
    for k in multiples:
        w = np.clip(k * v, inner_lo, inner_hi)
        if any(np.allclose(w, x, rtol=0.05, atol=1e-3 * float(np.min(scale))) for x in seen):
            continue
        seen.append(w)
        out.append((f"{k:g} x the linearised size", w))
    return out


def joint_fit(model: ParametricModel, freqs_hz, amplitude, alpha_starts, effect: Effect, location: str,
              linear=None, *, prior: Sequence[Applied] = (), multiples: Sequence[float] = SIZE_MULTIPLES,
              primary=None, alpha_bounds: tuple[float, float] = ALPHA_BOUNDS, max_evaluations: int = 600,
              tol: float = 1e-6, coarse_evaluations: int = COARSE_EVALUATIONS, coarse_tol: float = COARSE_TOL,
              base_rss: float | None = None, contender: float = 0.5) -> Fit:
    """Segment factors and one effect's parameters fitted together (one bounded least squares with the exact
    Jacobians: the model's for alpha, the effect's for its parameters), from several starts.

    ``alpha_starts`` maps a label to a start of alpha (the update's and the nominal model's, say);
    each is combined with the effect sizes of :func:`size_starts` (``multiples`` of the linearised
    ``linear``). The first start (the first alpha with ``primary``, or else the first size) is fitted to
    ``tol`` with ``max_evaluations``; the others coarsely (``coarse_tol``, ``coarse_evaluations``), and
    the best of them is refined to ``tol`` if it beats the first. Returns the best fit, with
    ``Fit.start`` naming its start and ``Fit.evaluations`` counting every start's FE solves. With
    ``base_rss`` (the sum of squares without the effect) the other starts are tried only for a contender,
    a first fit that explains at least ``contender`` of it (as a check moves only a contender).
    """
    labels = list(alpha_starts)
    if not labels:
        raise ValueError("joint_fit needs at least one start of alpha")
    sizes = size_starts(effect, location, np.zeros(effect.n_parameters) if linear is None else linear, multiples)
    if primary is not None:
        sizes = [("the linearised size", np.atleast_1d(np.asarray(primary, float)))] + [
            (lab, w) for lab, w in sizes if not np.allclose(w, primary, rtol=0.05)]
    if not sizes:
        sizes = [("the linearised size", np.zeros(effect.n_parameters) if linear is None
                  else np.atleast_1d(np.asarray(linear, float)))]
    starts = [(f"{a} alpha, {lab}", np.asarray(alpha_starts[a], float), w) for a in labels for lab, w in sizes]
    kw = dict(alpha_bounds=alpha_bounds, prior=prior)
    label, a0, w0 = starts[0]
    best = fit_update(model, freqs_hz, amplitude, a0, effect, location, w0, max_evaluations=max_evaluations,
                      tol=tol, **kw)
    best.start = label
    total = best.evaluations
    coarse = None
    if base_rss is not None and best.rss > (1.0 - contender) * base_rss:
        starts = starts[:1]
    for label, a0, w0 in starts[1:]:
        trial = fit_update(model, freqs_hz, amplitude, a0, effect, location, w0, max_evaluations=coarse_evaluations,
                           tol=coarse_tol, **kw)
        trial.start = label
        total += trial.evaluations
        if coarse is None or trial.rss < coarse.rss:
            coarse = trial
    if coarse is not None and coarse.rss < best.rss:
        refined = fit_update(model, freqs_hz, amplitude, coarse.alpha, effect, location, coarse.values,
                             max_evaluations=max_evaluations, tol=tol, **{**kw, "prior": coarse.prior})
        total += refined.evaluations
        refined.start = coarse.start
        if refined.rss < (1.0 - BETTER_START) * best.rss:
            log.info("joint fit of %s at %s: the start '%s' won (rss %.4g against %.4g from '%s')", effect.kind,
                     location, refined.start, refined.rss, best.rss, best.start)
            best = refined
    best.evaluations = total
    return best


def multistart_update(model: ParametricModel, freqs_hz, amplitude, alpha_start=None, n_starts: int = 4,
                      seed: int = 0, alpha_bounds: tuple[float, float] = ALPHA_BOUNDS, coarse_tol: float = 1e-4,
                      **kwargs) -> Fit:
    """Alpha-only least squares from ``alpha_start`` (if given) and ``n_starts`` scrambled-Sobol points.

    The stiffness factors' least-squares landscape has more than one basin
    (a fit from the nominal model can end with factors on the box's edge), so
    a cheap update tries several starts in the box, each to the loose
    tolerance ``coarse_tol``, and refines the best one.
    """
    from scipy.stats import qmc

    m = model.n_segments
    starts = [] if alpha_start is None else [np.asarray(alpha_start, float)]
    if n_starts > 0:
        lo, hi = max(alpha_bounds[0], -0.9), min(alpha_bounds[1], 0.9)
        pts = qmc.Sobol(m, scramble=True, seed=seed).random(max(2, n_starts))[:n_starts]
        starts += list(lo + (hi - lo) * pts)
    if not starts:
        raise ValueError("no start point: give alpha_start or n_starts > 0")
    best = None
    total = 0
    for k, x0 in enumerate(starts, start=1):  # coarse fits from every start, then the best one to full tolerance
        fit = fit_update(model, freqs_hz, amplitude, x0, alpha_bounds=alpha_bounds,
                         **{**kwargs, "tol": coarse_tol} if len(starts) > 1 else kwargs)
        total += fit.evaluations
        if best is None or fit.rss < best.rss:
            best = fit
        log.info("alpha-only fit %d of %d starts: rss %.4g after %d FE solves (best %.4g)", k, len(starts), fit.rss,
                 fit.evaluations, best.rss)
    if len(starts) > 1:
        best = fit_update(model, freqs_hz, amplitude, best.alpha, alpha_bounds=alpha_bounds, **kwargs)
        total += best.evaluations
    best.evaluations = total
    return best


def baseline(model: ParametricModel, freqs_hz, amplitude, alpha_start, noise: float | None = None,
             significance: float = 0.01, restarts: int = 0, seed: int = 0,
             alpha_bounds: tuple[float, float] = ALPHA_BOUNDS, far_restarts=None) -> tuple[Fit, ResidualAnalysis]:
    """The alpha-only fit from the earlier updated point, and its residual analysis.

    If the residual is structure and ``restarts > 0``, alpha-only fits from
    ``restarts`` Sobol points follow (:func:`multistart_update`): a structured
    residual may be a local minimum of the updating rather than a missing
    effect, and the best alpha-only fit is what an effect must beat. Far off
    (:func:`far_off`) and given ``far_restarts``
    (:func:`fe_core.closure.far.search.alpha_restarts`, handed in: the far
    package builds on this module), the starts run on the reduced model at the
    fit and only their best ends are fitted in full.
    """
    u = np.asarray(amplitude, float)
    base = fit_update(model, freqs_hz, u, alpha_start, alpha_bounds=alpha_bounds)
    before = analyse_residual(base.residual, freqs_hz, base.n_parameters, noise, significance, base.relative(u))
    log.info("alpha-only fit from the run's parameters: %d FE solves; %s", base.evaluations, before.summary())
    if before.structured and restarts > 0:
        log.info("the residual is structure: alpha-only fits from %d more starts", restarts)
        if far_restarts is not None and far_off(base):  # the starts on the reduced model, the best ends in full
            other = None
            for start, _ in far_restarts(model, freqs_hz, u, base.alpha, restarts, seed, alpha_bounds):
                trial = fit_update(model, freqs_hz, u, start, alpha_bounds=alpha_bounds)
                if other is not None:
                    trial.evaluations += other.evaluations
                other = trial if other is None or trial.rss < other.rss else _spent(other, trial)
        else:
            other = multistart_update(model, freqs_hz, u, None, restarts, seed, alpha_bounds)
        other.evaluations += base.evaluations
        if other.rss < base.rss:
            base = other
            before = analyse_residual(base.residual, freqs_hz, base.n_parameters, noise, significance,
                                      base.relative(u))
        else:
            base.evaluations = other.evaluations
    return base, before


def _spent(kept: Fit, other: Fit) -> Fit:
    """``kept`` with ``other``'s FE evaluations counted (``other`` carries the running count)."""
    kept.evaluations = other.evaluations
    return kept


def error_summary(fit: Fit, amplitude: np.ndarray) -> tuple[float, np.ndarray]:
    """Overall (Eq. 6b) and per-sensor (Eq. 15) errors of a fit."""
    rel = fit.relative(amplitude)
    return overall_error(rel), per_sensor_error(rel)
