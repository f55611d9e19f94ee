"""Decisions on checked candidates: plausibility (:func:`at_bound`), scores against the model without the
candidate (:func:`score`), the chosen effect (:func:`decide`), the closure's verdict (:func:`verdict`,
:data:`VERDICTS`), the ranking (:func:`rank`, :func:`dedupe`, :func:`merge`) and everything a closure
found (:class:`ClosureResult`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .effects import Effect
from .fits import Fit
from .screening import Candidate, scores
from ..inference.residual import ResidualAnalysis

__all__ = [
    "ClosureResult",
    "decide",
    "score",
    "rank",
    "dedupe",
    "merge",
    "at_bound",
    "bound_hit",
    "verdict",
    "dedupe_counting",
    "VERDICTS",
]


#: The three verdicts of a closure.
VERDICTS = ("noise", "explained", "ambiguous", "partly explained", "not explained")


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
    #: the rivals (:class:`fe_core.closure.identify.Rival`) holding at least 1 % of it.
    weights: list[float] = field(default_factory=list)
    rivals: list[list] = field(default_factory=list)
    #: Swaps made by the swap passes and moves of earlier effects (joint relocation), as text.
    swaps: list[str] = field(default_factory=list)
    moves: list[str] = field(default_factory=list)
    #: Per added effect: the locations of its kind holding 95 % of the linearised evidence, with weights,
    #: and whether they lie close together (:func:`fe_core.closure.identify.located`).
    spreads: list[list[tuple[str, float]]] = field(default_factory=list)
    located: list[bool] = field(default_factory=list)
    #: What is left beyond the noise and whether it is the model's own (:class:`fe_core.closure.far.misfit.Misfit`),
    #: and the records of the exact searches made far off.
    misfit: object = None
    searches: list = field(default_factory=list)
    #: Why the forward selection stopped (:attr:`fe_core.closure.selection.Selection.stopped`): "noise",
    #: "nothing stands out", "most effects" or "time limit"; "the model's own error" when it did not start.
    stopped: str = ""
    #: The baseline's misfit as per-mode frequency shifts, and whether it is within the model's own error
    #: (:class:`fe_core.closure.far.shifts.ModeShifts`; None when the baseline is noise).
    own_error: object = None
    #: Effects the selection fitted but the closure does not claim (:func:`fe_core.closure.far.shifts.unclaimed`).
    unclaimed: list = field(default_factory=list)


def at_bound(effect: Effect, location: str, values, rtol: float = 1e-2) -> bool:
    """True if a fitted value ends on a plausibility bound of ``effect`` (within ``rtol`` of its scale).

    A bound at zero (the effect's absence: no mass, no spring) does not count:
    an effect fitted to nothing is not added anyway.
    """
    return bound_hit(effect, location, values, rtol) is not None


def bound_hit(effect: Effect, location: str, values, rtol: float = 1e-2) -> str | None:
    """Which plausibility bound a fit ends on (as :func:`at_bound`): ``"upper 6.28 kg"``-like text naming the
    parameter's bound and its value, or None."""
    lo, hi = effect.bounds_at(location)
    tol = rtol * effect.scale_at(location)
    v = np.atleast_1d(np.asarray(values, float))
    with np.errstate(invalid="ignore"):  # infinite bounds compare False
        hit_lo = np.isfinite(lo) & (lo != 0) & (v <= lo + np.maximum(tol, 1e-3 * np.abs(lo)))
        hit_hi = np.isfinite(hi) & (hi != 0) & (v >= hi - np.maximum(tol, 1e-3 * np.abs(hi)))
    for i in range(v.size):
        if hit_lo[i] or hit_hi[i]:
            which, b = ("lower", lo[i]) if hit_lo[i] else ("upper", hi[i])
            unit = effect.units[i] if i < len(effect.units) else ""
            return f"{which} {effect.parameters[i]} = {b:.4g} {unit}".rstrip()
    return None


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


def decide(base: Fit, before: ResidualAnalysis, checked: Sequence[Candidate], noise=None) -> Candidate | None:
    """Score the checked candidates against the model without the new effect; the chosen one, or None.

    Sets the scores of :func:`score` on each candidate; an implausible one is never chosen, nor a negligible one
    (:func:`fe_core.closure.far.plausible.mark_negligible`, set by the caller: too small to be told from the model's
    own error). The best by extended
    BIC is chosen only if its gain also stands out from a misfit correlated along frequency
    (:func:`stands_out`): the model's own error is not fitted with negligible effects. ``noise``: the noise level,
    a number or per-value levels (p, n) (the residual analysis's level when None); it weights the residual whose
    correlation is measured.
    """
    score(base, checked)
    plausible = [c for c in checked if not c.implausible and not c.negligible]
    if not plausible or not before.structured:
        return None
    best = min(plausible, key=lambda c: c.ebic)
    if best.delta_ebic >= 0:
        return None
    return best if stands_out(base, best, before.sigma if noise is None else noise) else None


def stands_out(base: Fit, candidate: Candidate, noise=None) -> bool:
    """The candidate's gain over ``base`` stands out from the misfit it leaves: the extended BIC with the
    effectively independent values of its residual in place of N is negative
    (:func:`fe_core.closure.far.misfit.effective_ebic`; sets ``candidate.n_effective`` and
    ``candidate.effective_ebic``)."""
    from .far.misfit import effective_ebic, effective_values

    sigma = None if noise is None or np.ndim(noise) == 0 else noise
    n_eff = effective_values(candidate.fit.residual, sigma)
    k = candidate.fit.n_parameters - base.n_parameters
    candidate.n_effective = n_eff
    candidate.effective_ebic = effective_ebic(candidate.fit.rss, base.rss, n_eff, max(k, 1), candidate.n_locations)
    return candidate.effective_ebic < 0


def verdict(before: ResidualAnalysis, after: ResidualAnalysis, n_added: int, identified: bool = True,
            own_misfit: bool = False, own_error: bool = False) -> str:
    """``noise`` (nothing to explain), ``explained`` (effects added, noise after, or a structure left that is the
    model's own misfit (``own_misfit``, :func:`fe_core.closure.far.misfit.judge_misfit`), each effect singled out
    by the data), ``ambiguous`` (explained so, but a rival explanation fits about as well), ``partly explained``
    (effects added, structure remains beyond the model's own misfit) or ``not explained`` (structure, and no effect
    of the library stands out from it: the model's own error or an effect outside the library; as the modal
    closure says, :mod:`fe_core.modal_update.closure`). ``own_error``: the structure before is within the model's
    own error and nothing is claimed (:func:`fe_core.closure.far.shifts.unclaimed`): ``noise``."""
    if not before.structured or (own_error and n_added == 0):
        return "noise"
    if n_added == 0:
        return "not explained"
    if not after.structured or own_misfit:
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


def dedupe_counting(checked: Sequence[Candidate]) -> list:
    """:func:`dedupe`, and a check that ended where an emulated search did (and kept
    its fit) counts the search's FE solves."""
    emulated = [c for c in checked if c.fit is not None and c.fit.start.startswith("emulated search")]
    kept = dedupe(checked)
    for e in emulated:
        if all(c is not e for c in kept):
            twin = next(c for c in kept if (c.effect, c.location) == (e.effect, e.location))
            twin.fit.evaluations += e.fit.evaluations
    return kept
