"""A closure state moved to a better basin of its own effects, when the exact search finds one.

Every exact search (:func:`fe_core.closure.far.search.exact_search`) starts by fitting alpha alone, with the state's
effects as they are, on the reduced model: from the state's alpha and from the nominal model. When the nominal start
ends far lower, the state's alpha is in a poorer basin than its effects allow: a joint fit that placed an effect from
far off can stop at a stationary point of alpha and the effect together (held-out hg07, session 27: the right point
mass, 1.5 % off in size, with alpha_5 and alpha_6 0.05-0.07 from the truth; the full-order fit from there stops at
once, sum of squares 175.5, and from the second round's alpha-only point it ends at 22.3, every factor within 0.012
of the truth and the mass within 0.6 %). That point was found, then dropped when the time limit cut the round short.

:func:`rebase` refits the state on the full FE model from the search's alpha-only point (the same effects at the same
places, their values and alpha together) and keeps that fit when its sum of squares is lower: the forward selection
then checks the round's candidates from the better state, and a round cut short keeps it.
"""

from __future__ import annotations

import logging

import numpy as np

from ..fits import ALPHA_BOUNDS, Fit, fit_update

__all__ = ["rebase", "REBASE_SHARE", "REBASE_MOVED"]

log = logging.getLogger(__name__)

#: The nominal start's alpha-only fit must end below this share of the one from the state's alpha (reduced sums of
#: squares) for the full refit to be tried: a clearly better basin, not the same one found twice.
REBASE_SHARE = 0.5
#: ... and its alpha this far from the state's (largest factor change): another basin, not the same point.
REBASE_MOVED = 0.02


def rebase(model, freqs_hz, amplitude, fit: Fit, record: dict, *, alpha_bounds=ALPHA_BOUNDS,
           max_evaluations: int = 100) -> Fit:
    """``fit`` refitted on the full model from the search's alpha-only point (``record``: ``alpha_only``,
    ``rss_alpha``, ``rss_from_point``) when that point is in a clearly better basin and the refit ends lower;
    else ``fit`` itself. The refit's evaluations are added to the fit's."""
    start, best, here = record.get("alpha_only"), record.get("rss_alpha"), record.get("rss_from_point")
    if start is None or best is None or here is None or not best < REBASE_SHARE * here:
        return fit
    start = np.asarray(start, float)
    if np.max(np.abs(start - fit.alpha), initial=0.0) <= REBASE_MOVED:
        return fit
    u = np.asarray(amplitude, float)
    applied = list(fit.prior) + ([fit.added] if fit.added is not None else [])
    if applied:
        last = applied[-1]
        trial = fit_update(model, freqs_hz, u, start, last.effect, last.location, np.asarray(last.values, float),
                           prior=applied[:-1], alpha_bounds=alpha_bounds, max_evaluations=max_evaluations, tol=1e-6)
    else:
        trial = fit_update(model, freqs_hz, u, start, alpha_bounds=alpha_bounds, max_evaluations=max_evaluations,
                           tol=1e-6)
    trial.evaluations += fit.evaluations
    kept = trial.rss < fit.rss
    log.info("closure: the search's alpha-only fit ended in another basin (reduced sum of squares %.4g from the "
             "nominal model against %.4g from the state's alpha); the state refitted from there: %.6g -> %.6g, %s",
             best, here, fit.rss, trial.rss, "kept" if kept else "not kept")
    if not kept:
        fit.evaluations = trial.evaluations
        return fit
    trial.start = "rebased"
    return trial
