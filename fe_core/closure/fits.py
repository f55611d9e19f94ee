"""Closing the loop: trace a structured residual to a missing effect, add it, update again.

Steps (each a plain function, so a flow can store and resume them one by one):

1. :func:`fit_update` without an effect: the best stiffness factors alpha
   alone (least squares on the FE model from the earlier updated point), and
   :func:`fe_core.inference.residual.analyse_residual` of what remains.
2. :func:`screen`: every candidate (effect type x location) linearised at
   that point. With ``r`` the log residual and ``J_alpha`` its Jacobian, a
   candidate with sensitivity ``j`` (from :class:`fe_core.closure.effects.LinearisedResponse`,
   one field solve for all candidates) explains
   ``||P r||^2 - min_d ||P (r + j d)||^2`` of the residual sum of squares,
   where ``P`` projects out ``J_alpha`` (alpha is re-fitted with the effect)
   and ``d`` respects the effect's bounds (a mass cannot be negative).
3. :func:`check`: full FE least squares on ``[alpha, effect]`` for the best
   few candidates of each type, started from the updated alpha and the
   linear estimate; a searched location (a node) is then moved to a
   neighbour while the linearised prediction at the fitted point says that
   helps and the full fit confirms it.
4. :func:`decide`: scores charge for parameters. ``BIC = N ln(RSS/N) +
   k ln N`` and the extended BIC of Chen & Chen (2008) adds ``2 ln L`` for an
   effect searched over ``L`` locations (choosing the best of 585 nodes is a
   fit too). An effect is added only if the residual before it is
   structure (chi-square test) and its extended BIC beats the model without it.

5. Forward selection (:func:`fe_core.closure.selection.forward_select`): steps 2-4
   repeat with the effects added so far in the model, all of them refitted
   together with alpha at every step, while the residual is structure and an
   effect improves the extended BIC (up to ``max_effects``); with two or more
   effects, each is swapped for the best alternative in its place while that
   improves the extended BIC. A fit that ends on an effect's plausibility
   bound (:meth:`fe_core.closure.effects.Effect.bounds_at`) is reported implausible
   and never added.
6. The verdict: ``noise`` (the residual before was noise, nothing to add),
   ``explained`` (effects were added, the residual after them is noise and
   each effect's kind holds at least 95 % of the evidence among the kinds
   checked in its place, its location pinned down), ``ambiguous`` (noise
   after, but a rival kind or a distant location fits about as well: listed,
   not a finding), ``partly
   explained`` (structure remains: what was added and the best candidates
   are candidates, not findings).

The candidates' ranking is by extended BIC for checked candidates, then by
the extended BIC predicted by the linearisation.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, lsq_linear

from .effects import Applied, Effect, LinearisedResponse, build_library, extended_frf
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
    "Candidate",
    "ClosureResult",
    "fit_update",
    "multistart_update",
    "baseline",
    "screen",
    "pick_for_check",
    "check",
    "decide",
    "score",
    "scores",
    "rank",
    "dedupe",
    "merge",
    "error_summary",
    "at_bound",
    "verdict",
    "VERDICTS",
]

log = logging.getLogger(__name__)

#: Scale of the stiffness factors in fits.
ALPHA_SCALE = 0.1
#: Forward-difference step of fit_update, relative to each parameter's scale (see its docstring).
FD_STEP = 1e-4
#: Default fit bounds of alpha: the updating flow's default box [-1, 1], kept 0.05 off -1, where
#: a segment's stiffness vanishes and the least-squares landscape turns steep and ill-conditioned.
ALPHA_BOUNDS = (-0.95, 1.0)
#: The three verdicts of a closure.
VERDICTS = ("noise", "explained", "ambiguous", "partly explained")


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


@dataclass
class Candidate:
    """One effect at one location, as screened and (maybe) checked."""

    effect: str
    location: str
    n_locations: int
    linear_values: np.ndarray
    linear_rss: float
    linear_explained: float
    linear_delta_bic: float = 0.0
    linear_delta_ebic: float = 0.0
    fit: Fit | None = None
    bic: float | None = None
    ebic: float | None = None
    delta_bic: float | None = None
    delta_ebic: float | None = None
    explained: float | None = None
    moved_from: list[str] = field(default_factory=list)
    #: The full fit ended on a plausibility bound (of this or an earlier effect): never added.
    implausible: bool = False


@dataclass
class ClosureResult:
    """Everything :func:`close_loop` found.

    ``steps`` are the added effects in order (``chosen`` is the first, kept for
    one-effect readers); ``candidates`` is the ranking of the first round and
    ``rounds`` that of every round (the last one lists what remains);
    ``implausible`` the checked candidates of every round whose fit ended on a
    plausibility bound.
    """

    baseline: Fit
    before: ResidualAnalysis
    candidates: list[Candidate]
    chosen: Candidate | None
    final: Fit
    after: ResidualAnalysis
    seconds: dict
    steps: list[Candidate] = field(default_factory=list)
    verdict: str = "noise"
    implausible: list[Candidate] = field(default_factory=list)
    rounds: list[list[Candidate]] = field(default_factory=list)
    #: Per added effect: its kind's share of the evidence among the kinds checked in its place, and
    #: the rivals (:class:`fe_core.closure.selection.Rival`) holding at least 1 % of it.
    weights: list[float] = field(default_factory=list)
    rivals: list[list] = field(default_factory=list)
    #: Swaps made by the swap passes and moves of earlier effects (joint relocation), as text.
    swaps: list[str] = field(default_factory=list)
    moves: list[str] = field(default_factory=list)
    #: Per added effect: the locations of its kind holding 95 % of the linearised evidence, with weights,
    #: and whether they lie close together (:func:`fe_core.closure.selection.located`).
    spreads: list[list[tuple[str, float]]] = field(default_factory=list)
    located: list[bool] = field(default_factory=list)


# -- fitting ------------------------------------------------------------------------------------------
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
    parts = [(np.full(m, ALPHA_SCALE), np.full(m, alpha_bounds[0]), np.full(m, alpha_bounds[1]), alpha0.copy())]
    items = [(a.effect, a.location, np.atleast_1d(np.asarray(a.values, float))) for a in prior]
    if effect is not None:
        items.append((effect, location, np.zeros(effect.n_parameters) if value0 is None
                      else np.atleast_1d(np.asarray(value0, float))))
    for eff, loc, v0 in items:
        elo, ehi = eff.bounds_at(loc)
        parts.append((eff.scale_at(loc), elo, ehi, v0))
    scale, lo, hi, theta0 = (np.concatenate(x) for x in zip(*parts))
    sizes = np.cumsum([m] + [eff.n_parameters for eff, _, _ in items])

    def applied_at(theta):
        return [Applied(eff, loc, theta[a:b]) for (eff, loc, _), a, b in zip(items, sizes[:-1], sizes[1:])]
    # Strictly inside the box (least_squares' requirement), by a hair of each scale.
    theta0 = np.clip(theta0, lo + 1e-6 * scale, hi - 1e-6 * scale)
    count = [0]
    last: dict = {}

    def response(x) -> LinearisedResponse:
        """The FRF and its derivatives at x (the last point is kept: trf asks for the Jacobian where it
        has just evaluated the residual)."""
        if last.get("x") is None or not np.array_equal(last["x"], x):
            theta = np.clip(theta0 + scale * x, lo, hi)
            count[0] += 1
            last["x"] = np.array(x, copy=True)
            last["lin"] = LinearisedResponse(model, theta[:m], freqs, applied_at(theta))
        return last["lin"]

    def fun(x):
        return log_residual(response(x).amplitude, u).ravel()

    def fun_difference(x):
        theta = np.clip(theta0 + scale * x, lo, hi)
        count[0] += 1
        return log_residual(_amplitudes(model, theta[:m], freqs, applied_at(theta)), u).ravel()

    def jac(x):
        lin = response(x)
        cols = [lin.alpha_derivatives()] + [lin.effect_derivatives(a.effect, a.location) for a in lin.applied]
        return np.column_stack(cols) * scale[None, :]

    with np.errstate(invalid="ignore"):
        lb, ub = (lo - theta0) / scale, (hi - theta0) / scale
    if jacobian == "exact":
        result = least_squares(fun, np.zeros(theta0.size), jac=jac, bounds=(lb, ub), method="trf",
                               ftol=tol, xtol=tol, gtol=tol, max_nfev=max(1, max_evaluations // 2))
    else:
        result = least_squares(fun_difference, np.zeros(theta0.size), bounds=(lb, ub), method="trf",
                               diff_step=FD_STEP, ftol=tol, xtol=tol, gtol=tol,
                               max_nfev=max(1, max_evaluations // (theta0.size + 1)))
    theta = np.clip(theta0 + scale * result.x, lo, hi)
    r = result.fun.reshape(u.shape)
    applied = applied_at(theta)
    added = applied.pop() if effect is not None else None
    return Fit(alpha=theta[:m], effect=None if effect is None else effect.kind, location=location,
               values=np.array([]) if added is None else added.values, model_amplitude=np.exp(r) * u, residual=r,
               evaluations=count[0], seconds=time.perf_counter() - t0, message=str(result.message),
               prior=applied, added=added)


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
    for x0 in starts:  # coarse fits from every start, then the best one to full tolerance
        fit = fit_update(model, freqs_hz, amplitude, x0, alpha_bounds=alpha_bounds,
                         **{**kwargs, "tol": coarse_tol} if len(starts) > 1 else kwargs)
        total += fit.evaluations
        if best is None or fit.rss < best.rss:
            best = fit
    if len(starts) > 1:
        best = fit_update(model, freqs_hz, amplitude, best.alpha, alpha_bounds=alpha_bounds, **kwargs)
        total += best.evaluations
    best.evaluations = total
    return best


def baseline(model: ParametricModel, freqs_hz, amplitude, alpha_start, noise: float | None = None,
             significance: float = 0.01, restarts: int = 0, seed: int = 0,
             alpha_bounds: tuple[float, float] = ALPHA_BOUNDS) -> tuple[Fit, ResidualAnalysis]:
    """The alpha-only fit from the earlier updated point, and its residual analysis.

    If the residual is structure and ``restarts > 0``, alpha-only fits from
    ``restarts`` Sobol points follow (:func:`multistart_update`): a structured
    residual may be a local minimum of the updating rather than a missing
    effect, and the best alpha-only fit is what an effect must beat.
    """
    u = np.asarray(amplitude, float)
    base = fit_update(model, freqs_hz, u, alpha_start, alpha_bounds=alpha_bounds)
    before = analyse_residual(base.residual, freqs_hz, base.n_parameters, noise, significance, base.relative(u))
    if before.structured and restarts > 0:
        other = multistart_update(model, freqs_hz, u, None, restarts, seed, alpha_bounds)
        other.evaluations += base.evaluations
        if other.rss < base.rss:
            base = other
            before = analyse_residual(base.residual, freqs_hz, base.n_parameters, noise, significance,
                                      base.relative(u))
        else:
            base.evaluations = other.evaluations
    return base, before


# -- screening ----------------------------------------------------------------------------------------
def _projector(J: np.ndarray) -> np.ndarray:
    q, _ = np.linalg.qr(J)
    return q


def _best_linear(r_perp: np.ndarray, q: np.ndarray, cols: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """min over d in [lo, hi] of ||r_perp + P cols d||^2; returns (d, rss)."""
    jp = cols - q @ (q.T @ cols)
    if cols.shape[1] == 1:
        j = jp[:, 0]
        jj = float(j @ j)
        if jj <= 0:
            return np.zeros(1), float(r_perp @ r_perp)
        d = np.clip(-(j @ r_perp) / jj, lo[0], hi[0])
        res = r_perp + d * j
        return np.array([d]), float(res @ res)
    sol = lsq_linear(jp, -r_perp, bounds=(lo, hi))
    res = r_perp + jp @ sol.x
    return sol.x, float(res @ res)


def screen(model: ParametricModel, freqs_hz, base: Fit, library: Sequence[Effect],
           linearised: LinearisedResponse | None = None) -> list[Candidate]:
    """Linearised explained share of every candidate at the updated point ``base``.

    The effects already in ``base`` (``base.applied``) stay in the model and
    are refitted with alpha (their columns are projected out with alpha's);
    their own (effect, location) pairs are not candidates again.

    Returns
    -------
    list of Candidate
        All candidates, sorted by ``linear_explained`` (largest first).
    """
    applied = base.applied
    lin = linearised or LinearisedResponse(model, base.alpha, freqs_hz, applied)
    r = base.residual.ravel()
    q = _projector(_refitted_columns(lin, applied))
    taken = {(a.effect.kind, a.location) for a in applied}
    r_perp = r - q @ (q.T @ r)
    rss0 = float(r_perp @ r_perp)
    n = r.size
    bic0, _ = scores(base.rss, n, base.n_parameters)
    out = []
    for effect in library:
        locations = effect.locations()
        free = [loc for loc in locations if (effect.kind, loc) not in taken]
        if not free:
            continue
        d, rss = _linear_fits(lin, effect, free, r_perp, q)
        bic = n * np.log(np.maximum(rss, 1e-300) / n) + (base.n_parameters + effect.n_parameters) * np.log(n)
        ebic = bic + 2.0 * np.log(len(locations))  # as scores()
        for k, loc in enumerate(free):
            out.append(Candidate(effect=effect.kind, location=loc, n_locations=len(locations),
                                 linear_values=d[k], linear_rss=float(rss[k]),
                                 linear_explained=1.0 - rss[k] / rss0 if rss0 > 0 else 0.0,
                                 linear_delta_bic=float(bic[k] - bic0), linear_delta_ebic=float(ebic[k] - bic0)))
    out.sort(key=lambda c: -c.linear_explained)
    return out


def _linear_fits(lin: LinearisedResponse, effect: Effect, locations: Sequence[str], r_perp: np.ndarray,
                 q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounded linear least squares of ``r_perp`` on each location's projected columns: values
    (L, k) in the effect's units and residual sums of squares (L,)."""
    scale = np.array([effect.scale_at(loc) for loc in locations])  # (L, k)
    bounds = [effect.bounds_at(loc) for loc in locations]
    lo = np.array([b[0] for b in bounds]) / scale
    hi = np.array([b[1] for b in bounds]) / scale
    cols = lin.batch_derivatives(effect, locations) * scale[:, None, :]  # (L, N, k)
    if effect.n_parameters == 1:
        j = cols[:, :, 0]
        j = j - (j @ q) @ q.T  # alpha (and the effects refitted with it) projected out
        jj = np.einsum("ln,ln->l", j, j)
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.where(jj > 0, -(j @ r_perp) / jj, 0.0)
        d = np.clip(d, lo[:, 0], hi[:, 0])
        res = r_perp[None, :] + d[:, None] * j
        return (d[:, None] * scale), np.einsum("ln,ln->l", res, res)
    out = [_best_linear(r_perp, q, cols[k], lo[k], hi[k]) for k in range(len(locations))]
    return np.array([v for v, _ in out]) * scale, np.array([r for _, r in out])


def _refitted_columns(lin: LinearisedResponse, applied: Sequence[Applied]) -> np.ndarray:
    """Jacobian columns of what a candidate's fit re-fits: alpha and the effects already added (scaled)."""
    cols = [lin.alpha_derivatives()]
    cols += [lin.effect_derivatives(a.effect, a.location) * a.effect.scale_at(a.location) for a in applied]
    return np.column_stack(cols)


def at_bound(effect: Effect, location: str, values, rtol: float = 1e-2) -> bool:
    """True if a fitted value ends on a plausibility bound of ``effect`` (within ``rtol`` of its scale).

    A bound at zero (the effect's absence: no mass, no spring) does not count:
    an effect fitted to nothing is not added anyway.
    """
    lo, hi = effect.bounds_at(location)
    tol = rtol * effect.scale_at(location)
    v = np.atleast_1d(np.asarray(values, float))
    with np.errstate(invalid="ignore"):  # infinite bounds compare False
        hit_lo = np.isfinite(lo) & (lo != 0) & (v <= lo + np.maximum(tol, 1e-3 * np.abs(lo)))
        hit_hi = np.isfinite(hi) & (hi != 0) & (v >= hi - np.maximum(tol, 1e-3 * np.abs(hi)))
    return bool(np.any(hit_lo | hit_hi))


def pick_for_check(candidates: Sequence[Candidate], per_type: int = 2, factor: float = 10.0,
                   always: Sequence[str] = ("sensor_mass",)) -> list[Candidate]:
    """Candidates worth a full FE check: the ``per_type`` best-screened of each effect type, of those
    whose linearised unexplained share is within ``factor`` of the best candidate's, and the best of
    each kind in ``always`` whatever its screening (the transducers' mass, the commonest effect of all:
    a linearisation far from its basin can hide it)."""
    if not candidates:
        return []
    best_left = min(1.0 - c.linear_explained for c in candidates)
    seen: dict[str, int] = {}
    picked = []
    for c in sorted(candidates, key=lambda c: -c.linear_explained):
        left = 1.0 - c.linear_explained
        if seen.get(c.effect, 0) < per_type and c.linear_explained > 0 and left <= factor * max(best_left, 1e-6):
            seen[c.effect] = seen.get(c.effect, 0) + 1
            picked.append(c)
    for kind in always:
        if kind not in seen:
            first = next((c for c in sorted(candidates, key=lambda c: -c.linear_explained) if c.effect == kind), None)
            if first is not None:
                picked.append(first)
    return picked


def _start_value(effect: Effect, location: str, linear: np.ndarray) -> np.ndarray:
    """A start for the full fit from the linear estimate, kept halfway from a finite bound:
    the linearisation at zero overshoots for factors that act like ``beta / (1 + beta)``."""
    lo, hi = effect.bounds_at(location)
    v = np.asarray(linear, float).copy()
    lo_half = np.where(np.isfinite(lo) & (lo < 0), 0.5 * lo, -np.inf)
    hi_half = np.where(np.isfinite(hi) & (hi > 0), 0.5 * hi, np.inf)
    return np.clip(v, lo_half, hi_half)


# -- full checks --------------------------------------------------------------------------------------
def scores(rss: float, n_values: int, n_parameters: int, n_locations: int = 1) -> tuple[float, float]:
    """``(BIC, extended BIC)`` with unknown noise variance: ``N ln(RSS/N) + k ln N (+ 2 ln L)``."""
    bic = n_values * np.log(rss / n_values) + n_parameters * np.log(n_values)
    return float(bic), float(bic + 2.0 * np.log(n_locations))


def _relocation_fits(model, freqs, fit: Fit, effect: Effect, candidates: list[str], index: int | None = None):
    """Linearised fits of one fitted effect moved to each of ``candidates``: values (L, k) and RSS (L,).

    ``index`` is the effect's place in ``fit.applied`` (the newest by default); the other effects
    and alpha are refitted in the prediction.
    """
    applied = fit.applied
    j = len(applied) - 1 if index is None else index
    here, others = applied[j], applied[:j] + applied[j + 1:]
    lin = LinearisedResponse(model, fit.alpha, freqs, applied)
    r = fit.residual.ravel()
    q = _projector(_refitted_columns(lin, others))
    # Take the effect away where it is (linear in its values), then add it at the candidate.
    r_moved = r - lin.effect_derivatives(here.effect, here.location) @ here.values
    r_perp = r_moved - q @ (q.T @ r_moved)
    return _linear_fits(lin, effect, candidates, r_perp, q)


def _relocation_target(model, freqs, fit: Fit, effect: Effect, candidates: list[str], index: int | None = None):
    """Linearised best move of one fitted effect to one of ``candidates``: (location, values, predicted RSS)."""
    d, rss = _relocation_fits(model, freqs, fit, effect, candidates, index)
    k = int(np.argmin(rss))
    return candidates[k], d[k], float(rss[k])


def check(model: ParametricModel, freqs_hz, amplitude, base: Fit, effect: Effect, candidate: Candidate,
          max_moves: int = 6, alpha_bounds: tuple[float, float] = ALPHA_BOUNDS,
          max_evaluations: int = 600, tol: float = 1e-6, contender: float = 0.5) -> Candidate:
    """Full FE fit of one candidate from the updated point; a searched location may then move.

    The screening linearises at zero effect; a sizeable effect is placed
    better once its size is known. So after the fit at the screened location,
    every other location of the effect is screened again, linearised at the
    fitted point with the effect taken away and put there (one field solve for
    all); the best is fitted in full and kept if it lowers the residual, up to
    ``max_moves`` times, if the candidate explains at least ``contender`` of
    the residual (moving a loser costs fits and changes nothing). ``tol`` is
    the optimiser's tolerance (1e-6: the decision compares sums of squares
    that differ by per cents). ``max_evaluations`` bounds each fit (FE runs,
    difference columns included) and is meant not to be reached: a fit cut off
    by its budget in the middle of a long walk (a joint weakening that the
    alpha-only fit had absorbed into a segment: alpha_2 from -0.48 back to
    -0.1) ends wherever the path had got to, and the path differs with the
    CPU's last bits: at 200 the joint's check ended at a sum of squares of
    0.0020-0.0026 (chi-square p 0.002-0.10) depending on the difference step;
    at 600 it converges (0.00193, p = 0.14, beta = -0.76 for the true -0.75).
    Fills ``candidate.fit`` (and ``moved_from``) and returns the candidate.
    """
    kw = dict(alpha_bounds=alpha_bounds, max_evaluations=max_evaluations, tol=tol, prior=base.applied)
    fit = fit_update(model, freqs_hz, amplitude, base.alpha, effect, candidate.location,
                     _start_value(effect, candidate.location, candidate.linear_values), **kw)
    if fit.rss > base.rss:  # the linear start led astray: start from the effect's absence
        again = fit_update(model, freqs_hz, amplitude, base.alpha, effect, candidate.location, None, **kw)
        again.evaluations += fit.evaluations
        fit = again
    moved = []
    visited = {fit.location} | {a.location for a in base.applied if a.effect.kind == effect.kind}
    # Only a contender is worth moving: one that explains at least ``contender`` of the residual.
    searched = len(effect.locations()) > 1 and effect.n_parameters == 1 and fit.rss <= (1 - contender) * base.rss
    for _ in range(max_moves if searched else 0):
        # Every other location, linearised at the fitted point with the effect moved there.
        others = [loc for loc in effect.locations() if loc not in visited]
        if not others:
            break
        loc, values, predicted = _relocation_target(model, freqs_hz, fit, effect, others)
        fit.evaluations += 1
        if predicted >= fit.rss:
            break
        visited.add(loc)
        trial = fit_update(model, freqs_hz, amplitude, fit.alpha, effect, loc, _start_value(effect, loc, values),
                           **{**kw, "prior": fit.prior})
        trial.evaluations += fit.evaluations
        trial.seconds += fit.seconds
        if trial.rss >= fit.rss:
            fit.evaluations, fit.seconds = trial.evaluations, trial.seconds
            break
        moved.append(fit.location)
        fit = trial
    candidate.fit = fit
    candidate.location = fit.location
    candidate.moved_from = moved
    return candidate


def score(base: Fit, checked: Sequence[Candidate]) -> None:
    """Set ``bic``, ``ebic``, their differences to ``base`` (the model without the candidate), the
    explained share and ``implausible`` (the fit ends on a plausibility bound of any of its effects)."""
    n = base.residual.size
    bic0, _ = scores(base.rss, n, base.n_parameters)
    for c in checked:
        c.bic, c.ebic = scores(c.fit.rss, n, c.fit.n_parameters, c.n_locations)
        c.delta_bic, c.delta_ebic = c.bic - bic0, c.ebic - bic0
        c.explained = 1.0 - c.fit.rss / base.rss if base.rss > 0 else 0.0
        c.implausible = any(at_bound(a.effect, a.location, a.values) for a in c.fit.applied)


def decide(base: Fit, before: ResidualAnalysis, checked: Sequence[Candidate]) -> Candidate | None:
    """Score the checked candidates against the model without the new effect; the chosen one, or None.

    Sets the scores of :func:`score` on each candidate; an implausible one is never chosen.
    """
    score(base, checked)
    plausible = [c for c in checked if not c.implausible]
    if not plausible or not before.structured:
        return None
    best = min(plausible, key=lambda c: c.ebic)
    return best if best.delta_ebic < 0 else None


def verdict(before: ResidualAnalysis, after: ResidualAnalysis, n_added: int, identified: bool = True) -> str:
    """``noise`` (nothing to explain), ``explained`` (effects added, noise after, each effect singled out
    by the data), ``ambiguous`` (noise after, but a rival explanation fits about as well) or
    ``partly explained`` (structure remains)."""
    if not before.structured:
        return "noise"
    if n_added > 0 and not after.structured:
        return "explained" if identified else "ambiguous"
    return "partly explained"


def rank(candidates: Sequence[Candidate]) -> list[Candidate]:
    """Checked candidates by extended BIC, then the rest by their linearised extended BIC."""
    checked = sorted((c for c in candidates if c.fit is not None), key=lambda c: c.ebic)
    rest = sorted((c for c in candidates if c.fit is None), key=lambda c: c.linear_delta_ebic)
    return checked + rest


def dedupe(checked: Sequence[Candidate]) -> list[Candidate]:
    """Checked candidates that ended at the same (effect, location): keep the best fit."""
    best: dict[tuple[str, str], Candidate] = {}
    for c in checked:
        key = (c.effect, c.location)
        if key not in best or c.fit.rss < best[key].fit.rss:
            best[key] = c
    return list(best.values())


def merge(checked: Sequence[Candidate], screened: Sequence[Candidate]) -> list[Candidate]:
    """Checked candidates plus the screened ones not checked (one entry per effect and location)."""
    keys = {(c.effect, c.location) for c in checked}
    return list(checked) + [c for c in screened if c.fit is None and (c.effect, c.location) not in keys]


def error_summary(fit: Fit, amplitude: np.ndarray) -> tuple[float, np.ndarray]:
    """Overall (Eq. 6b) and per-sensor (Eq. 15) errors of a fit."""
    rel = fit.relative(amplitude)
    return overall_error(rel), per_sensor_error(rel)
