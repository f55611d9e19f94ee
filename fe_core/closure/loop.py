"""The closure in one call: baseline fit, residual analysis, forward selection of effects.

:func:`close_loop` chains the pieces of :mod:`.fits`, :mod:`.screening`, :mod:`.decisions` and
:mod:`.selection` (forward selection with moves and swaps) for an in-memory closure; the flow
(``flows.diagnose``) runs the same pieces as stages with their results stored.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import numpy as np

from ..model import ParametricModel
from ..model_error import floor_of
from .effects import Effect, build_library
from .decisions import ClosureResult, verdict
from .fits import ALPHA_BOUNDS, baseline, far_off
from .far.misfit import judge_misfit
from .far.shifts import own_error, unclaimed
from .far.search import alpha_restarts
from .selection import forward_select

__all__ = ["close_loop"]

log = logging.getLogger(__name__)


def close_loop(model: ParametricModel, freqs_hz, amplitude, alpha_start, library: Sequence[Effect] | None = None,
               noise: float | None = None, significance: float = 0.01, per_type: int = 2,
               max_moves: int = 6, restarts: int = 0, seed: int = 0, check_noise: bool = False,
               alpha_bounds: tuple[float, float] = ALPHA_BOUNDS, max_effects: int = 3,
               swaps: bool = True, emulator=None, max_minutes: float | None = None) -> ClosureResult:
    """Baseline fit, residual analysis, then forward selection: screening, checks and a decision per step.

    Parameters
    ----------
    model : ParametricModel
    freqs_hz : ndarray, shape (p,)
    amplitude : ndarray, shape (p, n)
        Measured amplitudes, m/N.
    alpha_start : array_like, shape (m,)
        The earlier updated parameters (from an MRGP run, say).
    library : sequence of Effect, optional
        Candidates; all registered effects by default.
    noise : float, optional
        Relative noise level of the amplitudes; estimated when None.
    significance : float
        Of the chi-square test "noise or structure".
    per_type : int
        Candidates per effect type given a full FE check.
    max_moves : int
        Moves of a searched location to a neighbour after its fit.
    restarts : int
        Extra starts of the alpha-only baseline fit when its residual is
        structure (:func:`baseline`).
    seed : int
        Of the restarts' Sobol points.
    check_noise : bool
        Make the full checks even when the residual is noise (no effect can
        be added then; the checks only refine the candidates' scores).
    alpha_bounds : (float, float)
        Box of the stiffness factors.
    max_effects : int
        Most effects added (forward selection stops earlier at noise or when
        no effect improves the extended BIC).
    swaps : bool
        Swap passes after each addition (:func:`fe_core.closure.selection.swap_pass`).
    emulator : callable, optional
        Where the baseline is structure and far off (:func:`fe_core.closure.fits.far_off`), the first round is
        ``emulator(model, freqs, u, base, before, library, noise=, significance=, per_type=, max_moves=,
        alpha_bounds=)``, which also checks a global search (the MRGP's over alpha, point mass position and log
        size: :func:`strategies.closure_emulator.first_round`, handed in since this package knows no MRGP);
        an explicit option, off by default.
    max_minutes : float, optional
        Time limit of the closure from this call: the forward selection starts a round or swap only while it and
        the backward check after it fit (:func:`fe_core.closure.selection.forward_select`'s ``out_of_time``,
        :class:`fe_core.closure.budget.Budget`); the baseline and a check under way finish first.
    """
    times = {"baseline": 0.0, "screen": 0.0, "check": 0.0}
    t = time.perf_counter()
    deadline = None if max_minutes is None else t + 60.0 * max_minutes
    library = build_library(model) if library is None else list(library)
    freqs = np.asarray(freqs_hz, float)
    u = np.asarray(amplitude, float)
    base, before = baseline(model, freqs, u, alpha_start, noise, significance, restarts, seed, alpha_bounds,
                            far_restarts=alpha_restarts)
    times["baseline"] = time.perf_counter() - t
    log.info("baseline: %s", before.summary())
    # Structure no larger than one mode half a per cent off: the model's own error, unless effects take it to the noise.
    floor = floor_of(model, freqs, base.alpha, log=log) if before.structured else None
    shifts = (own_error(model, freqs, u, base, before.sigma, None if floor is None else floor.rms)
              if before.structured else None)
    if shifts is not None:
        log.info("baseline: %s", shifts.reason())
    handed = {}
    if emulator is not None and before.structured and far_off(base):
        t = time.perf_counter()
        handed = emulator(model, freqs, u, base, before, library, noise=noise, significance=significance,
                          per_type=per_type, max_moves=max_moves, alpha_bounds=alpha_bounds)
        handed.pop("searches")
        times["emulator"] = time.perf_counter() - t
    sel = forward_select(model, freqs, u, handed.pop("start", base), handed.pop("analysis", before), library,
                         significance=significance, per_type=per_type, max_moves=max_moves, check_noise=check_noise,
                         alpha_bounds=alpha_bounds, max_effects=max_effects, times=times, swaps=swaps, baseline=base,
                         out_of_time=None if deadline is None else
                         (lambda margin=0.0: time.perf_counter() + margin > deadline), **handed)
    for c in (handed.get("rounds") or [[]])[0]:  # the implausible fits of a first round made with the emulator
        if c.fit is not None and c.implausible and all(c is not d for d in sel.implausible):
            sel.implausible.insert(0, c)
    left, not_claimed = unclaimed(shifts is not None and shifts.within, len(sel.steps), sel.after.structured,
                                   sel.stopped != "time limit"), []
    if left:   # nothing claimed: the alpha-only fit is the model after, the effects fitted are listed as not claimed
        log.info("closure: %s; %s", shifts.reason(), "no effect stands out" if not sel.steps else
                 f"the {len(sel.steps)} effect(s) fitted leave structure: not claimed")
        not_claimed, sel.steps, sel.final, sel.after = sel.steps, [], base, before
        sel.weights, sel.rivals, sel.spreads, sel.located = [], [], [], []
        sel.stopped = "the model's own error"
    misfit = judge_misfit(base.residual, sel.final.residual, sel.after.sigma, sel.stopped == "nothing stands out",
                          bar=shifts.bar if shifts is not None and floor is not None else None)
    result = ClosureResult(base, before, sel.rounds[0] if sel.rounds else [], sel.steps[0] if sel.steps else None,
                           sel.final, sel.after, times, sel.steps,
                           verdict(before, sel.after, len(sel.steps), sel.identified, misfit.own, left),
                           sel.implausible, sel.rounds, sel.weights, sel.rivals, sel.swaps, sel.moves, sel.spreads,
                           sel.located)
    result.misfit, result.searches, result.stopped = misfit, sel.searches, sel.stopped
    result.own_error, result.unclaimed = shifts, not_claimed
    return result
