"""A closure state moved to where the exact search's alpha-only fit ends, when that is far lower.

Every exact search (:func:`fe_core.closure.far.search.exact_search`) starts by fitting alpha alone, with the state's
effects as they are, on the reduced model (exact at the state's own point): from the state's alpha and from the
nominal model. When that fit ends far below the state's own sum of squares, the state's full-order fit stopped short
of its optimum: on held-out hg07 (session 27) the joint fit that placed the right point mass from far off (1.5 % off in
size) stopped with alpha_5 and alpha_6 0.05-0.07 from the truth at a sum of squares of 175.5, and a full-order fit from
there stops again at once (two evaluations: the trust region finds no descent), while the second round's search went
on from that very point, alpha alone, to 24.2 on the reduced model; a full-order fit from there ends at 22.3, every
factor within 0.012 of the truth and the mass within 0.6 %. That point was found, then dropped when the time limit
cut the round short.

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

#: The search's alpha-only fit (reduced sum of squares) must end below this share of the state's own (full order) for
#: the full refit to be tried: clearly lower, not the reduced model's approximation of the same point.
REBASE_SHARE = 0.5
#: ... and its alpha this far from the state's (largest factor change): another point, not the same one.
REBASE_MOVED = 0.02


def rebase(model, freqs_hz, amplitude, fit: Fit, record: dict, *, alpha_bounds=ALPHA_BOUNDS,
           max_evaluations: int = 100) -> Fit:
    """``fit`` refitted on the full model from the search's alpha-only point (``record``: ``alpha_only``,
    ``rss_alpha``) when that point is clearly lower than the fit and the refit ends lower; else ``fit`` itself. The
    refit's evaluations are added to the fit's."""
    start, best = record.get("alpha_only"), record.get("rss_alpha")
    if start is None or best is None or not best < REBASE_SHARE * fit.rss:
        return fit
    start = np.asarray(start, float)
    if np.max(np.abs(start - fit.alpha), initial=0.0) <= REBASE_MOVED:
        return fit
    u = np.asarray(amplitude, float)
    applied = fit.applied
    if applied:
        last = applied[-1]
        trial = fit_update(model, freqs_hz, u, start, last.effect, last.location, np.asarray(last.values, float),
                           prior=applied[:-1], alpha_bounds=alpha_bounds, max_evaluations=max_evaluations, tol=1e-6)
    else:
        trial = fit_update(model, freqs_hz, u, start, alpha_bounds=alpha_bounds, max_evaluations=max_evaluations,
                           tol=1e-6)
    trial.evaluations += fit.evaluations
    kept = trial.rss < fit.rss
    log.info("closure: the search's alpha-only fit ended far below the state (reduced sum of squares %.4g against "
             "%.4g); the state refitted from there: %.6g -> %.6g, %s", best, fit.rss, fit.rss, trial.rss,
             "kept" if kept else "not kept")
    if not kept:
        fit.evaluations = trial.evaluations
        return fit
    trial.start = "rebased"
    return trial
