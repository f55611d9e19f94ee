"""Is an effect plausible in size? It must move a natural frequency in the band by more than the model's own error.

After the effect that explains most of a far-off residual, what is left is partly the model's own error: a coarse
mesh's modes a fraction of a per cent off, an element formulation or a parametrisation that differs a little from
the structure's. Any effect of the library, chosen from thousands of places, can take a share of that misfit out; on
issue 40's box arm a 0.75 g mass (0.004 % of the structure) and a spring to the ground were added so, and on the
tet10 plate with its 4 % mass a damaged patch of 3.6 % stiffness loss took 7 % of the residual left (17 % weighted by
the measured coherence), all of it within a few lines round one mode (a misfit of 3 % of ``ln|Z|`` at its peak,
about 0.03 % of its frequency). A claim about the structure should be one the model could not have made by its own
error: an effect added after the first must shift at least one natural frequency in the band by :data:`MIN_SHIFT`
or more. The first effect is judged so only when it leaves most of the misfit (:func:`mark_first_negligible`): a
model with no error of its own resolves effects that shift its modes far less (the three-plate benchmark's 0.15 kg
point mass far from nominal: 0.2 %, found with 0.5 % noise), and such an effect takes the misfit down to the noise.
One that shifts no mode by half a per cent and leaves more than :data:`.misfit.MISFIT_SHARE` of the alpha-only fit's
misfit beyond the noise is the model's own error dressed as an effect (issue 40's third held-out set, the clean
holed plate hc03: a patch at the free corner softened by 96 %, its largest shift 0.10 % (0.22 % exactly), the misfit
left 76 %).

The shift is first order in the effect's terms, on the modes of the reduced model at the fit
(:class:`.reduced.ReducedModel`, M-orthonormal): ``d lambda_k = q_k^T (dK - lambda_k dM) q_k`` and
``df_k / f_k = d lambda_k / (2 lambda_k)``. Damping, without stiffness or mass terms, is not judged so.

A sensor's gain changes no frequency; what the model's own error does to a channel is its misfit there. So a gain
added after the first effect must change its channel's log amplitude by more than that channel's misfit beyond the
noise (:func:`fe_core.closure.far.misfit.smooth_misfit` of the fit without it): ``|ln(1 + g)|`` above it. On issue
40's dev12 (a clean channel deck, its model's own error 2-5 % rms) a gain of +1.4 % on one channel was kept as
a finding (a gain scales every line alike, so it carries over across the band, :mod:`fe_core.closure.crossband`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from .misfit import MISFIT_SHARE, smooth_misfit
from .reduced import ReducedModel

__all__ = ["MIN_SHIFT", "frequency_shifts", "mark_negligible", "mark_first_negligible", "judge_shift",
           "misfit_left", "small_beside", "gain_within_misfit"]

log = logging.getLogger(__name__)

#: The least relative shift of a natural frequency in the band an added effect must give: half a per cent, about
#: what a shell or solid mesh converged to engineering accuracy is off (issue 40's box arm: its coarse deck's modes
#: against the 2x finer deck's). The dev cases' true effects (2-8 % of the mass, a mount) shift a mode by one to
#: several per cent; the effects fitted to the model's own error by well under a tenth of one
#: (docs/results/closure-far-effects.md).
MIN_SHIFT = 0.005


def frequency_shifts(rm: ReducedModel, alpha, item) -> np.ndarray | None:
    """Relative first-order shifts ``df / f`` of the reduced model's natural frequencies in the band (those up to
    the top line) at ``alpha`` from the effect ``item`` (:class:`fe_core.closure.effects.Applied`) at its values;
    None when the effect has no stiffness or mass term."""
    dK, dM, _, _, _ = rm.terms(item.effect, item.location, item.values, alpha)
    if dK is None and dM is None:
        return None
    mu, q = rm.modal(alpha)
    top = (2 * np.pi * rm.freqs_hz.max()) ** 2
    keep = (mu > 0) & (mu <= top)
    q, lam = q[:, keep], mu[keep]
    dlam = np.zeros(lam.size)
    if dK is not None:
        dlam += np.einsum("ik,ij,jk->k", q, dK, q)
    if dM is not None:
        dlam -= lam * np.einsum("ik,ij,jk->k", q, dM, q)
    return dlam / (2.0 * lam)


def mark_negligible(model, freqs_hz, base, checked: Sequence, min_shift: float = MIN_SHIFT, sigma=None) -> None:
    """Set ``negligible`` and ``largest_shift`` on each checked candidate (:class:`fe_core.closure.screening.Candidate`
    with its fit): negligible when its own effect, at its fitted values, shifts no natural frequency in the band by
    ``min_shift`` (on the reduced model at ``base``, the fit without it: one full FE evaluation for all); with
    ``sigma`` (the noise: a level or per-value levels), a sensor's gain when it changes its channel's log amplitude
    by less than ``base``'s misfit beyond the noise on that channel (:func:`gain_within_misfit`)."""
    todo = [c for c in checked if c.fit is not None and _own(c) is not None]
    _judge_shifts(model, freqs_hz, base, todo, min_shift, sigma, lambda c: ": not plausible in size")


def _judge_shifts(model, freqs_hz, base, todo: Sequence, min_shift: float, sigma, why) -> None:
    """Set ``largest_shift`` and ``negligible`` on the candidates ``todo`` from their own effect's shifts on the
    reduced model at ``base`` (one full FE evaluation for all); with ``sigma``, a gain is judged on its channel.
    ``why(c)``: the end of the log line of a candidate found negligible."""
    if not todo:
        return
    rm = ReducedModel(model, freqs_hz, base.alpha, base.applied)
    for c in todo:
        shifts = frequency_shifts(rm, base.alpha, _own(c))
        if shifts is None and sigma is not None:  # no stiffness or mass terms: a sensor's gain is judged on its channel
            gain_within_misfit(base, _own(c), sigma, c)
        if shifts is None or shifts.size == 0:
            continue
        c.largest_shift = float(np.max(np.abs(shifts)))
        judge_shift(c, min_shift, why(c))


def judge_shift(c, min_shift: float = MIN_SHIFT, why: str = ": not plausible in size") -> bool:
    """Set and return ``c.negligible`` from its ``largest_shift`` (judged earlier) against ``min_shift``, logged."""
    c.negligible = c.largest_shift < min_shift
    if c.negligible:
        log.info("%s at %s = %s: shifts no natural frequency in the band by %.2g %% or more (at most %.3f %%)%s",
                 c.effect, c.location, np.round(_own(c).values, 6), 100 * min_shift, 100 * c.largest_shift, why)
    return c.negligible


def mark_first_negligible(model, freqs_hz, base, checked: Sequence, sigma, min_shift: float = MIN_SHIFT,
                          share: float = MISFIT_SHARE) -> None:
    """The first effect's size rule (module docstring): set ``negligible`` (and ``largest_shift``) on each checked
    candidate with stiffness or mass terms that shifts no natural frequency in the band by ``min_shift`` (on the
    reduced model at ``base``, the alpha-only fit) and leaves more than ``share`` of ``base``'s misfit beyond the noise
    ``sigma`` (:func:`fe_core.closure.far.misfit.smooth_misfit`); a candidate that takes the misfit down to that share
    is not judged on its size. A sensor's gain that leaves more than that share is judged as a later one is, on its
    channel (:func:`gain_within_misfit`): held-out hg22, a clean angle plate whose own error is 1.7 % rms beyond the
    noise, ended ``partly explained`` with a gain of 0.32 % that took 0.3 % of the residual out."""
    left = {id(c): misfit_left(c.fit, base, sigma) for c in checked if c.fit is not None}
    todo = [c for c in checked if c.fit is not None and _own(c) is not None and left[id(c)] > share]
    _judge_shifts(model, freqs_hz, base, todo, min_shift, sigma,
                  lambda c: f" and leaves {100 * left[id(c)]:.0f} % of the misfit: not plausible in size as the first "
                            "effect")


def misfit_left(fit, reference, sigma) -> float:
    """The share of ``reference``'s misfit beyond the noise ``sigma`` that ``fit`` leaves
    (:func:`fe_core.closure.far.misfit.smooth_misfit` of each residual); when the reference has none, 1 if ``fit``
    has some and 0 if not. Both size rules judge an effect on its shifts only when this is above
    :data:`.misfit.MISFIT_SHARE`: one that takes the misfit down to that share is not judged on its size."""
    before, left = smooth_misfit(reference.residual, sigma), smooth_misfit(fit.residual, sigma)
    if before > 0:
        return left / before
    return 1.0 if left > 0 else 0.0


def small_beside(rm: ReducedModel, fit, j: int, without, sigma, min_shift: float = MIN_SHIFT,
                 share: float = MISFIT_SHARE) -> str | None:
    """Why effect ``j`` of ``fit`` is too small to claim beside the others, or None: it shifts no natural frequency
    in the band by ``min_shift`` (first order on ``rm``, the reduced model at ``fit``) and leaves more than ``share``
    of the misfit beyond the noise ``sigma`` that ``without`` (the others refitted without it) leaves. The first
    effect's rule (:func:`mark_first_negligible`) for an effect judged among others: its value is refitted each time
    an effect is added, and one added large may end small beside a later one (held-out hc14: a 0.2 kg point mass,
    0.92 %, was 68 g, 0.3 %, beside the true patch). Effects without stiffness or mass terms are not judged."""
    own = fit.applied[j]
    shifts = frequency_shifts(rm, fit.alpha, own)
    if shifts is None or shifts.size == 0:
        return None
    largest = float(np.max(np.abs(shifts)))
    left = misfit_left(fit, without, sigma)
    if largest >= min_shift or left <= share:
        return None
    return (f"it shifts no natural frequency in the band by {100 * min_shift:.2g} % or more (at most "
            f"{100 * largest:.3f} %) and leaves {100 * left:.0f} % of the misfit the others leave without it")


def gain_within_misfit(base, item, sigma, candidate=None) -> bool:
    """Whether ``item`` (an applied effect) is a sensor's gain; if so, and ``candidate`` is given, its ``negligible``
    is set: ``|ln(1 + g)|`` at most the misfit beyond the noise ``sigma`` of ``base``'s residual on that channel."""
    terms = item.effect.terms(base.alpha, item.location, item.values)
    if terms.gain is None or terms.stiffness is not None or terms.mass is not None:
        return False
    if candidate is not None:
        s = int(np.argmax(np.abs(terms.gain)))
        r = np.asarray(base.residual, float)
        level = np.broadcast_to(np.asarray(sigma, float), r.shape)[:, s]
        misfit = smooth_misfit(r[:, s], level)
        change = abs(float(np.log1p(terms.gain[s])))
        candidate.negligible = change <= misfit
        if candidate.negligible:
            log.info("%s at %s = %s: changes its channel by %.2f %%, within the model's misfit there (%.2f %% rms "
                     "beyond the noise): not plausible in size", candidate.effect, candidate.location,
                     np.round(item.values, 6), 100 * change, 100 * misfit)
    return True


def _own(c):
    """The candidate's own effect among its fit's effects (the last one of its kind and place), or None."""
    for a in reversed(list(c.fit.applied)):
        if a.effect.kind == c.effect and a.location == c.location:
            return a
    return None
