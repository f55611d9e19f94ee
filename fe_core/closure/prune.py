"""The backward check of a forward selection: every effect it kept must still stand out with the others fitted, and,
where structure is left, carry over to lines it was not fitted on.

The forward selection adds one effect at a time and then moves the earlier ones jointly (:func:`.selection.refine`).
Such a move may leave an earlier effect with nothing to do: on issue 40's development case dev10 (a channel deck
carrying an undeclared 46 g mass) the first effect, a 117 g mass at the neighbouring node found far off, was moved
to another node at 5.5 mg once the second effect, the mass at its place, had been added. Kept, it is listed first
and claims an effect the data do not show.

:func:`prune` refits the model without each effect in turn (alpha and the other effects from where they are) and
drops the effect when its gain over that refit does not stand out (:func:`.decisions.stands_out`: the extended BIC
on the residual's effectively independent values, the rule that admitted it). With ``across`` (the residual left is
structure: the model's own error remains) each effect must also carry over from one half of the lines to the other
(:func:`.crossband.carries_over`): an effect that only fits the model's own error where it was fitted is dropped
(dev10 again: a segment mass factor of -0.041 on the web's tip beside the true mass); after a drop the effects left
are judged again without it.
"""

from __future__ import annotations

import logging

import numpy as np

from .crossband import carries_over
from .decisions import stands_out
from .far.plausible import small_beside
from .far.reduced import ReducedModel
from .fits import ALPHA_BOUNDS, Fit, fit_update
from .screening import Candidate

__all__ = ["prune"]

log = logging.getLogger(__name__)


def _refit(model, freqs_hz, amplitude, alpha, applied, alpha_bounds, restart=None) -> Fit:
    """Alpha and the values of ``applied`` refitted from where they are (alpha alone when there are none); with
    ``restart`` (an alpha) also from there, the better of the two kept. Alpha where the dropped effect had taken it
    can lie in a worse basin than the closure's alpha-only fit (held-out hb20: 70 % rms against 47 %), and a refit
    worse than need be makes the effect left out look as if it stood out."""
    def from_(start) -> Fit:
        if not applied:
            return fit_update(model, freqs_hz, amplitude, start, alpha_bounds=alpha_bounds)
        last = applied[-1]
        return fit_update(model, freqs_hz, amplitude, start, last.effect, last.location, last.values,
                          prior=applied[:-1], alpha_bounds=alpha_bounds)
    best = from_(alpha)
    log.info("backward check: refit with %d effect(s): %d evaluations, %.1f s", len(applied), best.evaluations,
             best.seconds)   # the cost fe_core.closure.budget reserves for
    if restart is not None and not np.allclose(restart, alpha, rtol=0.0, atol=1e-9):
        other = from_(np.asarray(restart, float))
        log.info("backward check: refit from the alpha-only fit's alpha: %d evaluations, %.1f s", other.evaluations,
                 other.seconds)
        if other.rss < best.rss:
            log.info("backward check: the refit from the alpha-only fit's alpha is better (sum of squares %.4g "
                     "against %.4g)", other.rss, best.rss)
            best = other
    return best


def prune(model, freqs_hz, amplitude, fit: Fit, noise=None, alpha_bounds=ALPHA_BOUNDS,
          across: bool = False, restart=None) -> tuple[Fit, list[int], list[str]]:
    """``(fit, dropped, notes)``: ``fit`` without the effects (of at least two) whose gain does not stand out
    beside the others, and with ``across`` also without those (of any number) that do not carry over across the
    band, refitted; ``dropped`` their indices in ``fit.applied`` (ascending); a note for each.

    With ``across``, an effect that stands out must also be plausible in size beside the others
    (:func:`.far.plausible.small_beside`: a frequency shift of half a per cent, unless it takes out most of the
    misfit the others leave), as it was when it was added. At the noise it is not judged so: the benchmark's far
    point mass record ends at the noise with a segment mass factor shifting 0.2 % beside damping, and the misfit
    beyond a noise level estimated from that residual is no measure of the model's own error.

    ``noise``: the level (or per-value levels) the residual is weighed with, as for :func:`.decisions.decide`.
    ``restart``: a second alpha each refit without an effect also starts from (the alpha-only fit's), the better
    end kept.
    """
    kept = list(range(len(fit.applied)))
    dropped, notes = [], []
    rm = None  # the reduced model at ``fit``, for the size of its effects (built when first needed)

    def drop(j: int, note: str, refitted: Fit) -> Fit:
        log.info("backward check: %s", note)
        notes.append(note)
        dropped.append(j)
        kept.remove(j)
        return refitted

    for j in reversed(range(len(fit.applied))):
        if len(kept) < 2:
            break
        applied = fit.applied
        here = kept.index(j)
        refitted = _refit(model, freqs_hz, amplitude, fit.alpha, applied[:here] + applied[here + 1:], alpha_bounds,
                          restart)
        own = applied[here]
        candidate = Candidate(effect=own.effect.kind, location=own.location,
                              n_locations=len(own.effect.locations()), linear_values=own.values,
                              linear_rss=fit.rss, linear_explained=0.0, fit=fit)
        if stands_out(refitted, candidate, noise):
            if noise is None or not across:  # at the noise every effect kept was needed to get there
                continue
            if rm is None:
                rm = ReducedModel(model, freqs_hz, fit.alpha, fit.applied)
            why = small_beside(rm, fit, here, refitted, noise)
            if why is None:
                continue
            rm = None
            fit = drop(j, f"{own.label()} = {own.values} dropped: beside the other effects {why}: too small to tell "
                          "from the model's own error", refitted)
            continue
        rm = None
        fit = drop(j, f"{own.label()} = {own.values} dropped: with the other effects refitted its gain does not "
                      f"stand out (sum of squares {refitted.rss:.4g} without it, {fit.rss:.4g} with it)", refitted)
    # After a drop every effect left is judged again: one that carried over beside the dropped effect may not without
    # it (each effect kept carries over among the effects finally kept).
    while across and kept:
        for j in reversed(list(kept)):
            here = kept.index(j)
            applied = fit.applied
            carries, how = carries_over(model, freqs_hz, amplitude, fit.alpha, applied, here, noise)
            if carries:
                log.info("backward check: %s carries over across the band (%s)", applied[here].label(), how)
                continue
            own = applied[here]
            refitted = _refit(model, freqs_hz, amplitude, fit.alpha, applied[:here] + applied[here + 1:], alpha_bounds,
                          restart)
            fit = drop(j, f"{own.label()} = {own.values} dropped: it does not carry over across the band, the "
                          f"model's own error where it was fitted ({how})", refitted)
            break
        else:
            break
    return fit, sorted(dropped), notes
