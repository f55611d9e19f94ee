"""The backward check of a forward selection: every effect it kept must still stand out with the others fitted.

The forward selection adds one effect at a time and then moves the earlier ones jointly (:func:`.selection.refine`).
Such a move may leave an earlier effect with nothing to do: on issue 40's development case dev10 (a channel deck
carrying an undeclared 46 g mass) the first effect, a 117 g mass at the neighbouring node found far off, was moved
to another node at 5.5 mg once the second effect, the mass at its place, had been added. Kept, it is listed first
and claims an effect the data do not show.

:func:`prune` refits the model without each effect in turn (alpha and the other effects from where they are) and
drops the effect when its gain over that refit does not stand out (:func:`.decisions.stands_out`: the extended BIC
on the residual's effectively independent values, the rule that admitted it).
"""

from __future__ import annotations

import logging

from .decisions import stands_out
from .fits import ALPHA_BOUNDS, Fit, fit_update
from .screening import Candidate

__all__ = ["prune"]

log = logging.getLogger(__name__)


def prune(model, freqs_hz, amplitude, fit: Fit, noise=None, alpha_bounds=ALPHA_BOUNDS) -> tuple[Fit, list[int], list[str]]:
    """``(fit, dropped, notes)``: ``fit`` without the effects (of at least two) whose gain does not stand out
    beside the others, refitted; ``dropped`` their indices in ``fit.applied`` (ascending); a note for each.

    ``noise``: the level (or per-value levels) the residual is weighed with, as for :func:`.decisions.decide`.
    """
    kept = list(range(len(fit.applied)))
    dropped, notes = [], []
    for j in reversed(range(len(fit.applied))):
        if len(kept) < 2:
            break
        applied = fit.applied
        here = kept.index(j)
        others = [a for k, a in enumerate(applied) if k != here]
        last = others[-1]
        refit = fit_update(model, freqs_hz, amplitude, fit.alpha, last.effect, last.location, last.values,
                           prior=others[:-1], alpha_bounds=alpha_bounds)
        own = applied[here]
        candidate = Candidate(effect=own.effect.kind, location=own.location,
                              n_locations=len(own.effect.locations()), linear_values=own.values,
                              linear_rss=fit.rss, linear_explained=0.0, fit=fit)
        if stands_out(refit, candidate, noise):
            continue
        note = (f"{own.label()} = {own.values} dropped: with the other effects refitted its gain does not stand "
                f"out (sum of squares {refit.rss:.4g} without it, {fit.rss:.4g} with it)")
        log.info("backward check: %s", note)
        notes.append(note)
        dropped.append(j)
        kept.remove(j)
        fit = refit
    return fit, sorted(dropped), notes
