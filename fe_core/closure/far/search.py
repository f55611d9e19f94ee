"""The exact search for a sizeable effect far from the model's basin: every candidate evaluated nonlinearly in a
reduced model, with its size scanned and the stiffness factors refitted, instead of trusted to a linearisation.

Why: linearised at a point far from the truth (a 24 % error, a 4 % point mass that moves modes by several
half-power bandwidths), the screen's first-order prediction ranks the true place anywhere, and a joint fit started
from the wrong place, or from the right place at the linearised size, ends in another basin. Here:

1. **Scan** (:meth:`.reduced.ReducedModel.scan`): the model projected once on the Krylov space of the current
   point; every location of every low-rank kind (point masses, springs to ground, the transducers' mass) on a
   spread of at most :data:`SPREAD` places (then every place near the best), each at :data:`SIZES` sizes across
   its plausible range plus a golden-section refinement, solved exactly in that space (Woodbury: a q x q solve
   per line) with its local flexibility added (:mod:`.local`: the drive-point flexibility the space lacks), alpha
   refitted linearly (the scan's sums of squares are of the residual with the reduced model's alpha derivatives
   projected out). Kinds that are not low-rank (patches, segment masses, damping, gains) are
   scanned by a generalised eigenproblem of the reduced pencil per place and size, on fewer places.
2. **Joint fits** (:func:`reduced_fit`): the best :data:`TOP` candidates (at most :data:`PER_KIND` of a kind)
   get a bounded least squares of alpha and the effect's value together, on the reduced model with its exact
   derivatives (a low-rank candidate's with the static vectors of its rows joined: :func:`local_space`).
3. **Passes**: the scan is repeated at the best joint fit's alpha (the place and size of a large effect are
   clearer where alpha no longer makes up for it), until the best candidate stays (at most :data:`PASSES`).

Returns :class:`Found` candidates, best first; the closure checks the best of them on the full FE model
(:func:`fe_core.closure.screening.check` from the found alpha and value).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ...threads import thread_map
from ..effects import Applied, Effect
from ..fits import ALPHA_BOUNDS, ALPHA_SCALE, log_sized
from .misfit import effective_values
from .reduced import ReducedModel, Smoother, lowrank_factors

__all__ = ["Found", "exact_search", "local_space", "alpha_restarts", "reduced_fit", "size_grid", "spread", "SPREAD",
           "TOP", "PER_KIND", "PASSES", "LOCAL"]

log = logging.getLogger(__name__)

#: Places of a searched kind scanned at first (spread over the structure), then every place within
#: :data:`NEAR` of the structure's size round the best :data:`REFINE` of them.
SPREAD = 300
NEAR, REFINE = 0.06, 6
#: The scan's lines: at most this many (every k-th line of more); the joint fits take them all.
SCAN_LINES = 360
#: Places of a kind that is not low-rank (a patch: an eigenproblem per place and size) scanned at first, and
#: at most this many more near the best.
SPREAD_DENSE = 60
#: Sizes of the scan per place (plus golden-section steps round the best: 3 for a low-rank kind, 1 else); a
#: kind that is not low-rank gets :data:`SIZES_DENSE`.
SIZES, SIZES_DENSE = 12, 8
#: At most this many places near the best of a low-rank kind are added to a scan.
NEAR_MAX = 160
#: Joint reduced fits per pass, and at most this many of one kind.
TOP, PER_KIND = 16, 8
PASSES = 5
#: The joint fits' continuation: both sides smoothed (:class:`.reduced.Smoother`) by these relative widths in
#: turn, the last (0) the raw residual; and the starts of the size (multiples of the scan's). On the tet10 plate with
#: a 4 % mass, from the scan's point at the true node a raw fit ended at a sum of squares of 55 (alpha 0.04 off in
#: two segments), from 0.3 times the size or through the continuation at 1.6 (the noise: the truth).
WIDTHS = (0.05, 0.02, 0.0)
#: Where alpha alone moves farther than this (in any factor) from the given point, the reduced model is rebuilt
#: there (one full FE evaluation): far from its point the space reproduces the model less well.
MOVED = 0.03
START_SIZES = (1.0,)
#: Whether the scan adds each low-rank candidate's local flexibility and its joint fit joins its static vectors
#: (:mod:`.local`: on hk07 of the eleventh held-out set the true node's reduced fit went from 259 to the full
#: model's 15.1).
LOCAL = True
#: Above this many free DOFs the search goes without the local flexibility: its factor of K beside the flow's
#: (2.1 GB at 500k DOFs, where the closure's search already passed 21 GB) and a block solve per 96 places' rows
#: (minutes a pass there).
LOCAL_MAX_DOFS = 150_000


@dataclass
class Found:
    """A candidate of the exact search: kind, place, its fitted value(s) and alpha, and sums of squares (of
    ``ln(|Z| / u)`` on the reduced model): ``scan`` with alpha refitted linearly, ``rss`` the joint reduced fit's."""

    effect: str
    location: str
    values: np.ndarray
    alpha: np.ndarray
    scan: float
    rss: float = np.inf
    n_locations: int = 1
    passes: int = 0


def size_grid(effect: Effect, location: str, n: int = SIZES) -> np.ndarray:
    """Sizes across an effect's plausible range (one parameter): geometric from a thousandth of a finite upper
    bound (or its scale) for a non-negative size, both signs for a factor."""
    lo, hi = (float(v[0]) for v in effect.bounds_at(location))
    scale = float(effect.scale_at(location)[0])
    top = hi if np.isfinite(hi) else 100.0 * scale
    if lo >= 0:
        start = max(lo, 1e-3 * top, 1e-6 * scale) if not log_sized(effect)[0] else max(lo, 1e-5 * top, 1e-3 * scale)
        return np.geomspace(start, 0.98 * top, n)
    bottom = lo if np.isfinite(lo) else -100.0 * scale
    half = max(n // 2, 2)
    neg = -np.geomspace(0.02 * min(-bottom, top), 0.98 * -bottom, half)[::-1]
    pos = np.geomspace(0.02 * min(-bottom, top), 0.98 * top, n - half)
    return np.concatenate([neg, pos])


def spread(effect: Effect, locations: Sequence[str], n: int) -> list[str]:
    """At most ``n`` of ``locations`` spread over the structure (the one nearest the mean of each box of a grid,
    boxes shrunk until there are ``n``); every ``k``-th without positions."""
    locations = list(locations)
    if len(locations) <= n:
        return locations
    pos = [effect.position(loc) for loc in locations]
    if any(p is None for p in pos):
        return locations[:: int(np.ceil(len(locations) / n))]
    xyz = np.array(pos)
    lo = xyz.min(axis=0)
    h = float(np.ptp(xyz, axis=0).max())
    which = None
    while h > 0:
        boxes, which = np.unique(np.floor((xyz - lo) / h).astype(np.int64), axis=0, return_inverse=True)
        if boxes.shape[0] >= n:
            break
        h /= 1.15
    which = which.ravel()
    mean = np.zeros((which.max() + 1, 3))
    np.add.at(mean, which, xyz)
    mean /= np.bincount(which)[:, None]
    dist = np.linalg.norm(xyz - mean[which], axis=1)
    order = np.lexsort((dist, which))
    first = order[np.r_[True, np.diff(which[order]) != 0]]
    return [locations[k] for k in sorted(first)]


def _near(effect: Effect, locations: Sequence[str], centres: Sequence[str], radius: float) -> list[str]:
    """The locations within ``radius`` (m) of any of ``centres``."""
    cen = [effect.position(c) for c in centres]
    if not cen or any(c is None for c in cen):
        return list(centres)
    cen = np.array(cen)
    out = []
    for loc in locations:
        p = effect.position(loc)
        if p is not None and np.min(np.linalg.norm(cen - p, axis=1)) <= radius:
            out.append(loc)
    return out


def _nearest(effect: Effect, locations: Sequence[str], centres: Sequence[str], n: int) -> list[str]:
    """At most ``n`` of ``locations``, the nearest to any of ``centres`` first."""
    if len(locations) <= n:
        return list(locations)
    cen = np.array([effect.position(c) for c in centres])
    dist = [float(np.min(np.linalg.norm(cen - effect.position(loc), axis=1))) for loc in locations]
    return [locations[k] for k in np.argsort(dist)[:n]]


# -- the scan ---------------------------------------------------------------------------------------------------
def _scan_kind(rm: ReducedModel, effect: Effect, locations: list[str], alpha, log_u, project, lines) -> list[Found]:
    """Every location of one kind at its size grid and a golden refinement, on ``lines``; the best size of each."""
    if not locations:
        return []
    low = lowrank_factors(rm, effect, locations)
    grid = np.array([size_grid(effect, loc, SIZES if low is not None else SIZES_DENSE) for loc in locations])
    if low is not None:
        matrix, U = low
        residual = rm.local.residual(effect.diagonal(locations)[1]) if _local(rm) else None

        def rss_at(sizes):
            return rm.scan(alpha, U, matrix, sizes, log_u, project, lines=lines, residual=residual)
    else:
        def rss_at(sizes):
            def row(i):
                out = np.empty(sizes.shape[1])
                for j, s in enumerate(sizes[i]):
                    lnZ, _ = rm.evaluate(alpha, [Applied(effect, locations[i], np.array([s]))])
                    r = (lnZ - log_u)[lines].ravel()
                    r = r - project @ (project.T @ r)
                    out[j] = r @ r
                return out
            return np.array(thread_map(row, range(len(locations)))).reshape(sizes.shape)
    rss = rss_at(grid)
    k = np.argmin(rss, axis=1)
    rows = np.arange(len(locations))
    best_s, best_r = grid[rows, k], rss[rows, k]
    # golden-section refinement between the grid neighbours of the best size, in the grid's own spacing
    lo_s = grid[rows, np.maximum(k - 1, 0)]
    hi_s = grid[rows, np.minimum(k + 1, grid.shape[1] - 1)]
    same_sign = (lo_s > 0) & (hi_s > 0)
    to = np.where(same_sign, np.log(np.maximum(np.abs(lo_s), 1e-300)), lo_s)
    tb = np.where(same_sign, np.log(np.maximum(np.abs(hi_s), 1e-300)), hi_s)

    def back(t):
        return np.where(same_sign, np.exp(t), t)
    phi = (np.sqrt(5) - 1) / 2
    for _ in range(3 if low is not None else 1):
        t1, t2 = tb - phi * (tb - to), to + phi * (tb - to)
        r = rss_at(np.column_stack([back(t1), back(t2)]))
        left = r[:, 0] < r[:, 1]
        tb = np.where(left, t2, tb)
        to = np.where(left, to, t1)
        for j, t in ((0, t1), (1, t2)):
            better = r[:, j] < best_r
            best_s, best_r = np.where(better, back(t), best_s), np.where(better, r[:, j], best_r)
    n_loc = len(effect.locations())
    return [Found(effect.kind, loc, np.array([s]), np.asarray(alpha, float).copy(), float(r), n_locations=n_loc)
            for loc, s, r in zip(locations, best_s, best_r)]


def _searched(effect: Effect) -> bool:
    return effect.n_parameters == 1 and len(effect.locations()) > 1


def _scan(rm: ReducedModel, library: Sequence[Effect], alpha, log_u, taken: set, focus: dict | None = None,
          size_m: float | None = None) -> list[Found]:
    """One scan of every kind at ``alpha``; ``focus`` (kind -> locations) adds places near earlier bests."""
    lines = np.arange(rm.omegas.size)
    if lines.size > SCAN_LINES:  # every k-th line: the ranking, not the fit, is the scan's
        lines = lines[:: int(np.ceil(lines.size / SCAN_LINES))]
    project = rm.alpha_projector(alpha, lines)
    out = []
    for effect in library:
        if effect.n_parameters != 1:
            continue
        free = [loc for loc in effect.locations() if (effect.kind, loc) not in taken]
        dense = lowrank_factors(rm, effect, free[:1]) is None if free else True
        places = spread(effect, free, SPREAD_DENSE if dense else SPREAD)
        if focus and effect.kind in focus and size_m:
            extra = _near(effect, free, focus[effect.kind], NEAR * size_m * (0.5 if dense else 1.0))
            places = list(dict.fromkeys(places + extra))
        t0 = time.perf_counter()
        found = _scan_kind(rm, effect, places, alpha, log_u, project, lines)
        n_near = 0
        if found and size_m and _searched(effect):  # every place near the kind's best few, nearest first
            best = [f.location for f in sorted(found, key=lambda f: f.scan)[:REFINE]]
            held = set(places)
            near = [loc for loc in _near(effect, free, best, NEAR * size_m * (0.5 if dense else 1.0))
                    if loc not in held]
            near = _nearest(effect, near, best, SPREAD_DENSE if dense else NEAR_MAX)
            n_near = len(near)
            found += _scan_kind(rm, effect, near, alpha, log_u, project, lines)
        log.debug("scan of %s: %d + %d places, %.1f s", effect.kind, len(places), n_near, time.perf_counter() - t0)
        out += found
    out.sort(key=lambda f: f.scan)
    return out


# -- joint reduced fits ----------------------------------------------------------------------------------------
def _local(rm: ReducedModel) -> bool:
    return LOCAL and rm.W.shape[0] <= LOCAL_MAX_DOFS


def local_space(rm: ReducedModel, effect: Effect, location: str) -> ReducedModel:
    """The reduced model a candidate is fitted on: ``rm`` with the static vectors of its rows joined when it is a
    low-rank kind (:data:`LOCAL`, up to :data:`LOCAL_MAX_DOFS`; :meth:`.reduced.ReducedModel.with_local`), else
    ``rm``."""
    if not _local(rm) or rm.V is not None or effect.n_parameters != 1:
        return rm
    diag = effect.diagonal([location])
    return rm if diag is None else rm.with_local(diag[1])


def reduced_fit(rm: ReducedModel, log_u, alpha0, effect: Effect | None, location: str | None, value0=None,
                alpha_bounds=ALPHA_BOUNDS, max_nfev: int = 60, smooth: Smoother | None = None
                ) -> tuple[np.ndarray, np.ndarray, float]:
    """Bounded least squares of alpha (and one effect's values) on the reduced model, exact reduced derivatives;
    returns ``(alpha, values, rss)``. ``smooth``: both sides smoothed alike (:class:`.reduced.Smoother`)."""
    m = rm.model.n_segments
    alpha0 = np.clip(np.asarray(alpha0, float), alpha_bounds[0] + 1e-6, alpha_bounds[1] - 1e-6)
    scale = [np.full(m, ALPHA_SCALE)]
    lo, hi, x0 = [np.full(m, alpha_bounds[0])], [np.full(m, alpha_bounds[1])], [alpha0]
    logp = np.zeros(m, bool)
    if effect is not None:
        elo, ehi = effect.bounds_at(location)
        v0 = np.atleast_1d(np.asarray(value0, float))
        lg = log_sized(effect) | ((elo >= 0) & (v0 > 0))      # a non-negative size is searched in ln
        floor = np.where(lg, np.maximum(elo, 1e-6 * np.maximum(v0, effect.scale_at(location))), elo)
        with np.errstate(invalid="ignore"):  # both branches are evaluated; the infinite one is not taken
            inner_lo = np.where(np.isfinite(floor), floor + 1e-9 * np.abs(floor) + 1e-300, floor)
            inner_hi = np.where(np.isfinite(ehi), ehi - 1e-9 * np.abs(ehi), ehi)
        v0 = np.clip(v0, inner_lo, inner_hi)
        scale.append(effect.scale_at(location))
        lo.append(floor)
        hi.append(ehi)
        x0.append(v0)
        logp = np.concatenate([logp, lg])
    scale, lo, hi, x0 = (np.concatenate(v) for v in (scale, lo, hi, x0))
    z0 = np.where(logp, np.log(np.maximum(x0, 1e-300)), x0 / scale)
    zl = np.where(logp, np.log(np.maximum(lo, 1e-300)), lo / scale)
    zh = np.where(logp, np.log(np.where(np.isfinite(hi), hi, 1e300)), hi / scale)
    alpha_derivs = rm.alpha_derivatives()
    target = log_u if smooth is None else smooth.log_amplitude(log_u)

    def theta(z):
        return np.where(logp, np.exp(z), z * scale)

    cache = {}

    def evaluate(z):
        key = z.tobytes()
        if key not in cache:
            t = theta(z)
            extra = [] if effect is None else [Applied(effect, location, t[m:])]
            derivs = rm.alpha_derivatives(extra) if extra else list(alpha_derivs)
            if effect is not None:
                derivs += [_unit_terms(rm, effect, location, i, t[:m]) for i in range(effect.n_parameters)]
            lnZ, J = rm.evaluate(t[:m], extra, derivs)
            if smooth is not None and smooth.S is not None:
                J = smooth.jacobian(lnZ, J)
                lnZ = smooth.log_amplitude(lnZ)
            cache.clear()
            cache[key] = ((lnZ - target).ravel(), J * np.where(logp, t, scale)[None, :])
        return cache[key]

    z0 = np.clip(z0, zl + 1e-9, zh - 1e-9)
    res = least_squares(lambda z: evaluate(z)[0], z0, jac=lambda z: evaluate(z)[1], bounds=(zl, zh), method="trf",
                        max_nfev=max_nfev, ftol=1e-7, xtol=1e-7, gtol=1e-9)
    t = theta(res.x)
    return t[:m], t[m:], float(res.fun @ res.fun)


def _unit_terms(rm, effect, location, i, alpha):
    """Projected unit terms of parameter ``i`` (the terms are linear: the terms at the unit value)."""
    return rm.unit_terms(effect, location, i, alpha)


def joint_fit(rm: ReducedModel, log_u, alpha, effect: Effect | None, location: str | None, value,
              alpha_bounds, smoothers: Sequence[Smoother]) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`reduced_fit` through the continuation of ``smoothers`` (the last unsmoothed), from each of
    :data:`START_SIZES` times ``value``; the best raw fit ``(alpha, values, rss)``."""
    best = None
    starts = [None] if effect is None else [np.asarray(value, float) * k for k in START_SIZES]
    for v in starts:
        a = np.asarray(alpha, float)
        for sm in smoothers:
            a, v, rss = reduced_fit(rm, log_u, a, effect, location, v, alpha_bounds, smooth=sm)
        if best is None or rss < best[2]:
            best = (a, v, rss)
    return best


def alpha_restarts(model, freqs_hz, amplitude, alpha, n_starts: int, seed: int = 0, alpha_bounds=ALPHA_BOUNDS,
                   applied: Sequence[Applied] = (), keep: int = 2) -> list[tuple[np.ndarray, float]]:
    """Alpha-only fits from ``alpha``, the nominal model and ``n_starts`` scrambled-Sobol points on the reduced
    model of the spaces at ``alpha`` and at the nominal model (with the continuation of :data:`WIDTHS`): the best
    ``keep`` distinct ends ``[(alpha, reduced rss)]``, best first. The closure's baseline restarts far off, where
    each full fit from a Sobol point costs several FE evaluations of a large model."""
    from scipy.stats import qmc

    freqs = np.asarray(freqs_hz, float)
    log_u = np.log(np.asarray(amplitude, float))
    nominal = np.clip(np.zeros(model.n_segments), *alpha_bounds)
    rm = ReducedModel(model, freqs, alpha, applied, enrich=[(nominal, list(applied))])
    smoothers = [Smoother(freqs, w) for w in WIDTHS]
    lo, hi = max(alpha_bounds[0], -0.9), min(alpha_bounds[1], 0.9)
    starts = [np.asarray(alpha, float), nominal]
    if n_starts > 0:
        starts += list(lo + (hi - lo) * qmc.Sobol(model.n_segments, scramble=True, seed=seed).random(
            max(2, n_starts))[:n_starts])
    ends = sorted(thread_map(lambda a0: joint_fit(rm, log_u, a0, None, None, None, alpha_bounds, smoothers), starts),
                  key=lambda e: e[2])
    out: list[tuple[np.ndarray, float]] = []
    for a, _, rss in ends:
        if all(np.max(np.abs(a - b)) > MOVED for b, _ in out):
            out.append((a, rss))
        if len(out) >= keep:
            break
    return out


# -- the search -------------------------------------------------------------------------------------------------
def exact_search(model, freqs_hz, amplitude, alpha, library: Sequence[Effect], applied: Sequence[Applied] = (), *,
                 alpha_bounds=ALPHA_BOUNDS, top: int = TOP, per_kind: int = PER_KIND, passes: int = PASSES,
                 reduced: ReducedModel | None = None) -> tuple[list[Found], dict]:
    """The exact search from ``alpha`` (the module docstring); returns the fitted candidates, best first, and a
    record: the alpha-only reduced fit's least sum of squares (``rss_alpha``, at ``alpha_only``: where
    :func:`fe_core.closure.far.rebase.rebase` refits a stuck state from) and from the best candidate's alpha
    without it (``rss_without``: a basin the effect's fit may have led alpha to), the effectively independent values of the best candidate's residual (``n_effective``,
    :func:`.misfit.effective_values`), the passes, seconds."""
    t0 = time.perf_counter()
    freqs = np.asarray(freqs_hz, float)
    log_u = np.log(np.asarray(amplitude, float))
    rm = reduced if reduced is not None else ReducedModel(model, freqs, alpha, applied)
    taken = {(a.effect.kind, a.location) for a in applied}
    by_kind = {e.kind: e for e in library}
    size_m = getattr(model, "size_m", None)
    smoothers = [Smoother(freqs, w) for w in WIDTHS]
    # Alpha alone first, from the point and from the nominal model: the point may be a poor basin of the full model
    # (the hybrid's local fit on the tet10 plate: a factor on its bound, 3681 against 697 in the basin nearby)
    # where a candidate's joint fit cannot start well; the search starts where alpha alone ends.
    a_alpha, rss_alpha = None, np.inf
    for a0 in (np.asarray(alpha, float), np.clip(np.zeros(model.n_segments), *alpha_bounds)):
        a, _, r = joint_fit(rm, log_u, a0, None, None, None, alpha_bounds, smoothers)
        if r < rss_alpha:
            a_alpha, rss_alpha = a, r
    if np.max(np.abs(a_alpha - np.asarray(alpha, float))) > MOVED and reduced is None:
        rm = None   # freed first: at size a reduced model's space is a GB
        rm = ReducedModel(model, freqs, a_alpha, applied)   # the reduced model where the search starts
        a_alpha, _, rss_alpha = joint_fit(rm, log_u, a_alpha, None, None, None, alpha_bounds, smoothers[-1:])
    fitted: dict = {}
    record = {"rss_alpha": rss_alpha, "alpha_only": a_alpha.tolist(), "passes": [], "basis": rm.d}
    point = np.asarray(a_alpha, float)
    focus: dict = {}
    best_key = None
    for k in range(passes):
        t1 = time.perf_counter()
        scanned = _scan(rm, library, point, log_u, taken, focus, size_m)
        picks, count = [], {}
        for f in scanned:
            if len(picks) >= top:
                break
            if count.get(f.effect, 0) >= per_kind or (f.effect, f.location) in fitted:
                continue
            count[f.effect] = count.get(f.effect, 0) + 1
            picks.append(f)
        ends = thread_map(lambda f: joint_fit(local_space(rm, by_kind[f.effect], f.location), log_u, f.alpha,
                                              by_kind[f.effect], f.location, f.values, alpha_bounds, smoothers), picks)
        for f, (a, v, r) in zip(picks, ends):
            f.alpha, f.values, f.rss, f.passes = a, v, r, k + 1
            fitted[(f.effect, f.location)] = f
        best = min(fitted.values(), key=lambda f: f.rss)
        record["passes"].append({"alpha": point.tolist(), "scanned": len(scanned), "fitted": len(picks),
                                 "best": [best.effect, best.location, best.values.tolist(), best.rss],
                                 "scan_best": [scanned[0].effect, scanned[0].location, scanned[0].scan],
                                 "seconds": time.perf_counter() - t1})
        log.info("exact search pass %d at alpha %s: %d candidates scanned, %d fitted; best %s at %s = %s, rss %.4g "
                 "(alpha alone %.4g)", k + 1, np.round(point, 3), len(scanned), len(picks), best.effect,
                 best.location, np.round(best.values, 4), best.rss, rss_alpha)
        key = (best.effect, best.location)
        if key == best_key or np.allclose(best.alpha, point, atol=1e-3):
            break
        best_key, point = key, best.alpha.copy()
        if k + 1 < passes:  # the next pass on the spaces of the best fit's point, with and without its effect
            rm = None
            rm = ReducedModel(model, freqs, point, applied,
                              enrich=[(point, list(applied) + [Applied(by_kind[best.effect], best.location,
                                                                       np.asarray(best.values, float))])])
            again = list(fitted.values())  # the fitted candidates' sums of squares on the new reduced model
            ends = thread_map(lambda f: reduced_fit(local_space(rm, by_kind[f.effect], f.location), log_u, f.alpha,
                                                    by_kind[f.effect], f.location, f.values, alpha_bounds,
                                                    max_nfev=20), again)
            for f, (a, v, r) in zip(again, ends):
                f.alpha, f.values, f.rss = a, v, r
        focus = {}
        for f in sorted(fitted.values(), key=lambda f: f.rss)[:REFINE]:
            focus.setdefault(f.effect, []).append(f.location)
    found = sorted(fitted.values(), key=lambda f: f.rss)
    if found:
        best = found[0]
        own = local_space(rm, by_kind[best.effect], best.location)
        lnZ, _ = own.evaluate(best.alpha, [Applied(by_kind[best.effect], best.location, best.values)])
        record["n_effective"] = effective_values(lnZ - log_u)
        _, _, record["rss_without"] = joint_fit(rm, log_u, best.alpha, None, None, None, alpha_bounds, smoothers[-1:])
    record["seconds"] = time.perf_counter() - t0
    return found, record
