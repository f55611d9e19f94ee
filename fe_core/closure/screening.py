"""Screening and full checks of candidate effects: :class:`Candidate`, the linearised explained share of
every candidate at the updated point (:func:`screen`, one field solve for all of them), the candidates
worth a full FE fit (:func:`pick_for_check`), the BIC scores (:func:`scores`) and the full fit of one
candidate, whose searched location may then move (:func:`check`, with the linearised relocation)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear

from .effects import Applied, Effect, LinearisedResponse
from .effects.bands import REFINE_BEST
from .fits import ALPHA_BOUNDS, SIZE_MULTIPLES, Fit, alpha_starts, far_off, fit_update, joint_fit
from ..model import ParametricModel

__all__ = [
    "Candidate",
    "screen",
    "pick_for_check",
    "pick_in_waves",
    "second_wave",
    "check_in_waves",
    "check",
    "scores",
]


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
    #: Where a search that evaluated the candidate exactly (:func:`fe_core.closure.far.exact_search`) fitted alpha
    #: with it: the joint check starts there (with ``linear_values``, then the search's value), None otherwise.
    start_alpha: np.ndarray | None = None
    #: Effectively independent values of the residual the candidate's fit leaves, and its extended BIC with them
    #: (:func:`fe_core.closure.decisions.stands_out`); None until decided.
    n_effective: float | None = None
    effective_ebic: float | None = None
    #: Its own effect shifts no natural frequency in the band by :data:`fe_core.closure.far.plausible.MIN_SHIFT`
    #: (not plausible in size: never added), and the largest relative shift it gives; None until judged.
    negligible: bool = False
    largest_shift: float | None = None


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
        # An effect whose locations refine (patches on a large mesh: fe_core.closure.effects.PatchBands)
        # adds locations round its best-screened ones, screened in turn.
        refine = getattr(effect, "refine", None)
        added = refine([free[k] for k in np.argsort(rss)[:REFINE_BEST]]) if refine is not None else []
        added = [loc for loc in added if (effect.kind, loc) not in taken]
        if added:
            d2, rss2 = _linear_fits(lin, effect, added, r_perp, q)
            free, d, rss = free + added, np.concatenate([d, d2]), np.concatenate([rss, rss2])
            locations = effect.locations()
        bic = n * np.log(np.maximum(rss, 1e-300) / n) + (base.n_parameters + effect.n_parameters) * np.log(n)
        ebic = bic + 2.0 * np.log(len(locations))  # as scores()
        for k, loc in enumerate(free):
            out.append(Candidate(effect=effect.kind, location=loc, n_locations=len(locations),
                                 linear_values=d[k], linear_rss=float(rss[k]),
                                 linear_explained=1.0 - rss[k] / rss0 if rss0 > 0 else 0.0,
                                 linear_delta_bic=float(bic[k] - bic0), linear_delta_ebic=float(ebic[k] - bic0)))
    out.sort(key=lambda c: -c.linear_explained)
    return out


#: The screen's derivative columns are formed :data:`SCREEN_BYTES` at a time (each location's fit is its own): an
#: effect at every node of the 500k panel is an (L, N) array of 4.8 GB (167,500 nodes, 3,600 values), which made the
#: closure's second-round screen the peak of its process tree (19.1 GB).
SCREEN_BYTES = 2 ** 28


def _linear_fits(lin: LinearisedResponse, effect: Effect, locations: Sequence[str], r_perp: np.ndarray,
                 q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounded linear least squares of ``r_perp`` on each location's projected columns: values
    (L, k) in the effect's units and residual sums of squares (L,); :data:`SCREEN_BYTES` of columns at a time."""
    step = max(1, SCREEN_BYTES // (8 * max(r_perp.size, 1) * effect.n_parameters))
    if len(locations) > step:
        parts = [_linear_fits(lin, effect, locations[i:i + step], r_perp, q) for i in range(0, len(locations), step)]
        return np.concatenate([d for d, _ in parts]), np.concatenate([rss for _, rss in parts])
    bounds = [effect.bounds_at(loc) for loc in locations]
    if effect.n_parameters == 1:  # in the effect's own units: a scale changes nothing here
        d, rss = _linear_fits_1(lin.batch_derivatives(effect, locations)[:, :, 0], r_perp, q)
        d = np.clip(d, [b[0][0] for b in bounds], [b[1][0] for b in bounds])
        return d[:, None], rss(d)
    scale = np.array([effect.scale_at(loc) for loc in locations])  # (L, k)
    lo = np.array([b[0] for b in bounds]) / scale
    hi = np.array([b[1] for b in bounds]) / scale
    cols = lin.batch_derivatives(effect, locations) * scale[:, None, :]  # (L, N, k)
    out = [_best_linear(r_perp, q, cols[k], lo[k], hi[k]) for k in range(len(locations))]
    return np.array([v for v, _ in out]) * scale, np.array([r for _, r in out])


#: Below this share of a column's (or the residual's) squared norm, :func:`_linear_fits_1` recomputes a location's
#: projected column explicitly rather than trust a difference of squares (it would keep fewer than ~10 digits).
EXPLICIT = 1e-6


def _linear_fits_1(j: np.ndarray, r_perp: np.ndarray, q: np.ndarray):
    """One-value effects at L locations: the unbounded least-squares values ``d`` (L,) of ``r_perp`` on each row of
    ``j`` (L, N) with ``q``'s span (orthonormal; ``r_perp`` is orthogonal to it) projected out, and a function giving
    the sums of squares at any values. The projected rows are never formed: ``|P j|^2 = |j|^2 - |q^T j|^2``,
    ``(P j) . r_perp = j . r_perp - (q^T j) . (q^T r_perp)`` and ``|r_perp + d P j|^2 = |r_perp|^2 + 2 d (P j) . r_perp
    + d^2 |P j|^2`` (an (L, N) array is 0.5 GB on an 8,000-node plate with 8,000 values), except for the locations
    where a difference would lose digits (:data:`EXPLICIT`)."""
    jq = j @ q
    norm2 = np.einsum("ln,ln->l", j, j)
    jj = norm2 - np.einsum("lm,lm->l", jq, jq)
    g = j @ r_perp - jq @ (q.T @ r_perp)
    rss0 = float(r_perp @ r_perp)
    shallow = np.flatnonzero(jj <= EXPLICIT * norm2)
    if shallow.size:  # nearly in q's span: project those rows explicitly
        jp = j[shallow] - jq[shallow] @ q.T
        jj[shallow] = np.einsum("ln,ln->l", jp, jp)
        g[shallow] = jp @ r_perp
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(jj > 0, -g / jj, 0.0)

    def rss(values: np.ndarray) -> np.ndarray:
        out = rss0 + 2.0 * values * g + values * values * jj
        close = np.flatnonzero(out <= EXPLICIT * rss0)  # nearly all explained: the difference recomputed
        if close.size:
            jp = j[close] - jq[close] @ q.T
            res = r_perp[None, :] + values[close, None] * jp
            out[close] = np.einsum("ln,ln->l", res, res)
        return out

    return d, rss


def _refitted_columns(lin: LinearisedResponse, applied: Sequence[Applied]) -> np.ndarray:
    """Jacobian columns of what a candidate's fit re-fits: alpha and the effects already added (scaled)."""
    cols = [lin.alpha_derivatives()]
    cols += [lin.effect_derivatives(a.effect, a.location) * a.effect.scale_at(a.location) for a in applied]
    return np.column_stack(cols)


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


def pick_in_waves(candidates: Sequence[Candidate], per_type: int, far_per_type: int,
                  always: Sequence[str] = ("sensor_mass",)) -> tuple[list[Candidate], list[Candidate]]:
    """The checks in two waves: ``(first, rest)``. ``first`` is :func:`pick_for_check` with ``per_type``;
    ``rest`` the further candidates of ``far_per_type`` per kind (where the residual is far off), from which
    :func:`second_wave` takes those worth a full check once the first wave's fits are known."""
    first = pick_for_check(candidates, per_type, always=always)
    if far_per_type <= per_type:
        return first, []
    held = {id(c) for c in first}
    return first, [c for c in pick_for_check(candidates, far_per_type, always=always) if id(c) not in held]


def second_wave(rest: Sequence[Candidate], first_rss: Iterable[float], base_rss: float,
                contender: float = 0.5) -> list[Candidate]:
    """``rest`` where the first wave made no contender (no full fit's sum of squares in ``first_rss`` explains
    ``contender`` of ``base_rss``), else nothing. Far off, the linear screen (at zero effect) ranks a large
    effect's own place below its neighbours; a contender's check corrects that itself: its moves screen every
    location again at the fitted size and fit the best (:func:`check`). Only where no check got that far are
    the further candidates worth their fits (the own cases' frame with a -88 % patch: its fifth candidate is
    the true place); where one did, a kind's further candidates ended at its first's place
    (docs/results/performance.md)."""
    made = any(rss <= (1.0 - contender) * base_rss for rss in first_rss)
    return [] if made else list(rest)


def check_all(model: ParametricModel, freqs_hz, amplitude, base: Fit, pairs, max_moves: int,
              alpha_bounds: tuple[float, float], max_evaluations: int) -> list[Candidate]:
    """:func:`check` of each ``(effect, candidate)`` of ``pairs`` from ``base``, in order, in this process: what a
    caller's ``check_many`` (same arguments and result, the candidates filled) does on several
    (``tasks.closure.parallel``)."""
    return [check(model, freqs_hz, amplitude, base, effect, c, max_moves, alpha_bounds, max_evaluations=max_evaluations)
            for effect, c in pairs]


def check_in_waves(model: ParametricModel, freqs_hz, amplitude, base: Fit, by_kind: dict, first, rest,
                   max_moves: int, alpha_bounds: tuple[float, float], max_evaluations: int,
                   out_of_time=None, check_many=None) -> list[Candidate]:
    """:func:`check` of the candidates of ``first``, then of those :func:`second_wave` takes from ``rest``;
    no further check is started once ``out_of_time()`` is true (the checks made so far are returned).
    ``check_many`` (:func:`check_all`'s arguments): each wave in one call, all its checks started together."""
    if check_many is not None:
        late = out_of_time if out_of_time is not None else (lambda: False)
        done = [] if late() else check_many(model, freqs_hz, amplitude, base, [(by_kind[c.effect], c) for c in first],
                                            max_moves, alpha_bounds, max_evaluations)
        more = [] if late() else second_wave(rest, [c.fit.rss for c in done], base.rss)
        return done + (check_many(model, freqs_hz, amplitude, base, [(by_kind[c.effect], c) for c in more],
                                  max_moves, alpha_bounds, max_evaluations) if more else [])
    checked: list[Candidate] = []

    def waves():
        yield from first
        yield from second_wave(rest, [c.fit.rss for c in checked], base.rss)  # drawn once the first is checked

    for c in waves():
        if out_of_time is not None and out_of_time():
            break
        checked.append(check(model, freqs_hz, amplitude, base, by_kind[c.effect], c, max_moves, alpha_bounds,
                             max_evaluations=max_evaluations))
    return checked


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


#: Where the linearised relocation predicts that even the best other place loses more than this share of what the
#: fitted effect explains (``base.rss - fit.rss``), the linearisation at the fitted size is not trusted (a move to
#: a neighbour that overlaps the effect would keep most of it): the best :data:`FULL_MOVES` predicted places are
#: fitted in full instead. Issue 28's frame with a patch of -0.88 round node 132: fitted at node 131 it leaves 0.277
#: of 43.0; the linearisation predicts 28-58 for every move; the true patch, fourth of the predictions, leaves
#: 0.0052 fitted in full (the noise).
NONLINEAR = 0.5
FULL_MOVES = 4


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
    # Joint fit of alpha and the effect (fe_core.closure.fits.joint_fit): where the residual is far off, from
    # several starts (the update's and the nominal alpha, the linearised size kept halfway from a bound and
    # multiples of it); else from the update's alpha and the linearised size alone.
    far = far_off(base)
    starts = alpha_starts(model, base.alpha, alpha_bounds) if far else {"update": base.alpha}
    primary = _start_value(effect, candidate.location, candidate.linear_values)
    multiples = SIZE_MULTIPLES if far else ()
    if candidate.start_alpha is not None:  # the exact search's joint point: one start, where it ended
        starts, multiples = {"search": np.asarray(candidate.start_alpha, float)}, ()
        primary = np.asarray(candidate.linear_values, float)
    fit = joint_fit(model, freqs_hz, amplitude, starts, effect, candidate.location, candidate.linear_values,
                    multiples=multiples, base_rss=base.rss, contender=contender,
                    primary=primary, **kw)
    if fit.rss > base.rss:  # the linear start led astray: start from the effect's absence
        again = fit_update(model, freqs_hz, amplitude, base.alpha, effect, candidate.location, None, **kw)
        again.evaluations += fit.evaluations
        again.start = "update alpha, no effect"
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
        values, predicted = _relocation_fits(model, freqs_hz, fit, effect, others)
        fit.evaluations += 1
        order = np.argsort(predicted)
        if predicted[order[0]] - fit.rss <= NONLINEAR * (base.rss - fit.rss):  # its best move, if it predicts a gain
            if predicted[order[0]] >= fit.rss:
                break
            tries = [(others[order[0]], _start_value(effect, others[order[0]], values[order[0]]))]
        else:  # it does not at this size (a patch of -0.88): the best few predicted moves fitted in full
            tries = [(others[k], fit.values) for k in order[:FULL_MOVES]]
        best, spent, seconds = None, fit.evaluations, fit.seconds
        for loc, start in tries:
            visited.add(loc)
            trial = fit_update(model, freqs_hz, amplitude, fit.alpha, effect, loc, start, **{**kw, "prior": fit.prior})
            spent, seconds = spent + trial.evaluations, seconds + trial.seconds
            if trial.rss < (fit.rss if best is None else best.rss):
                best = trial
        if best is None:
            fit.evaluations, fit.seconds = spent, seconds
            break
        best.evaluations, best.seconds = spent, seconds
        best.start = f"{fit.start}; moved from {fit.location}" if fit.start else ""
        moved.append(fit.location)
        fit = best
    candidate.fit = fit
    candidate.location = fit.location
    candidate.moved_from = moved
    return candidate
