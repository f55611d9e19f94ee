"""The closure's least-squares fits on a reduced model that grows with the fit (issue 28: speed on real meshes).

A fit of the plain path (:func:`fe_core.closure.fits.fit_update`) builds, at every point the optimiser
asks for, a new Krylov space of the load and the sensor loads: one factorisation of ``K(theta)`` and
about ten block solves, 10-20 times per fit, for the baseline, every restart, every candidate's check
and every move. Here the fit runs on a Galerkin projection instead, in rounds:

1. the basis ``V`` (orthonormal; the segments' stiffness, the mass, the load and the outputs projected
   once per basis) is shared by the fits of one model and one set of lines and holds the full spaces
   of the points earlier rounds ended at (the first fit starts it with the space at its start);
2. the same ``fit_update`` runs with every evaluation on ``V``: ``K(theta)`` and ``M(theta)`` reduced
   (the segments' factors, the effects' terms projected through their few rows), a small generalised
   eigenproblem, and the exact derivatives of the reduced model (milliseconds, no factorisation);
3. at its optimum ``theta_{k+1}`` the full space is built again; if the reduced and the full ``ln|Z|``
   agree there to ``AGREE`` (1e-6) and the round, started from a point whose space the basis held,
   lowered the full sum of squares by no more than the fit's tolerance (its start was stationary for the
   full model too), the fit ends, with the full model's residual at ``theta_{k+1}``;
   otherwise the round repeats from ``theta_{k+1}`` with that space added (a basis beyond
   ``MAX_BASIS`` columns starts afresh from it).

A basis that holds the full space at a point reproduces there the full model's receptance and its
first derivatives (input and output spaces in the projection: Baur, Beattie, Feng & Gugercin 2011),
so a round from a point an earlier round ended at starts with the full model's value and gradient, and
the fit ends at a point whose
full residual the reduced model predicted to 1e-6 in ``ln|Z|``: the plain fit's optimum to the
optimiser's tolerance (``tests/fe_core/test_closure_fast.py`` compares both paths' fits). A fit that
has not agreed after ``MAX_ROUNDS`` rounds finishes on the plain path from where it got to.

:func:`enabled` switches the closure's fits (baseline, restarts, checks, moves, swaps) to this path
for a block of code, :func:`install` (or ``MRGP_CLOSURE_FAST=1`` in the environment, which the flow's
worker processes inherit) for the process; :func:`fit_update` is the fit itself, with
``fits.fit_update``'s signature.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time

import numpy as np

from . import fits
from .effects import LinearisedResponse
from .fast_basis import ReducedBasis, _ReducedLinearised

__all__ = ["fit_update", "enabled", "disabled", "install", "uninstall", "ReducedBasis", "AGREE", "MAX_ROUNDS"]

log = logging.getLogger(__name__)

#: Largest |ln|Z_reduced| - ln|Z_full|| at a fit's end for the reduced fit to stand.
AGREE = 1e-6
#: A fit to this tolerance or looser is coarse (a restart, another start of a joint fit: ranked by its sum of
#: squares, the best refined after): it starts on the basis as it is and ends where the reduced and the full
#: sum of squares agree to its tolerance.
COARSE = 1e-5
#: Rounds (full evaluations that enlarge the basis) before the plain path takes over.
MAX_ROUNDS = 6
_PLAIN_FIT = fits.fit_update


@contextlib.contextmanager
def _responses(factory):
    """``fits.fit_update`` evaluating through ``factory`` instead of a full Krylov space, for a block."""
    saved = fits.LinearisedResponse
    fits.LinearisedResponse = factory
    try:
        yield
    finally:
        fits.LinearisedResponse = saved


def fit_update(model, freqs_hz, amplitude, alpha0, effect=None, location=None, value0=None, *,
               max_evaluations: int = 600, tol: float = 1e-8, alpha_bounds=fits.ALPHA_BOUNDS, prior=(),
               jacobian: str = "exact") -> fits.Fit:
    """:func:`fe_core.closure.fits.fit_update` in rounds on a growing reduced model (the module's docstring).

    Same arguments and result; ``Fit.evaluations`` counts the full FE evaluations (one per round),
    ``Fit.message`` adds the rounds and the basis size.
    """
    if jacobian != "exact":
        return _PLAIN_FIT(model, freqs_hz, amplitude, alpha0, effect, location, value0, max_evaluations=max_evaluations,
                          tol=tol, alpha_bounds=alpha_bounds, prior=prior, jacobian=jacobian)
    t0 = time.perf_counter()
    u = np.asarray(amplitude, float)
    freqs = np.asarray(freqs_hz, float)
    built = _BUILT[0]
    basis = shared_basis(model, freqs)
    alpha, value, applied = np.asarray(alpha0, float), value0, list(prior)
    reduced_evals = 0
    start = _held(model, alpha, freqs, _with(applied, effect, location, value))
    prev = None  # the fit that ended at ``start`` (a round's), if any
    if start is None and basis.V.shape[1] > 0:  # round 0: on the basis as it is, no full space at the start
        quick = _round0(basis, model, freqs, u, alpha, effect, location, value, applied, max_evaluations, tol,
                        alpha_bounds)
        if quick is not None:
            fit, full, n = quick
            reduced_evals += n
            if tol >= COARSE and _rss_agrees(fit.rss, full, u, tol):
                return _ended(fit, full, u, built, t0, 0, reduced_evals, basis, "coarse, sums of squares agree",
                              fine=False)
            alpha, value, applied = fit.alpha, (fit.values if effect is not None else None), list(fit.prior)
            start, prev = full, fit
    if start is None:
        start = full_response(model, alpha, freqs, _with(applied, effect, location, value))
    for k in range(1, MAX_ROUNDS + 1):
        if start.fast_key not in basis.holds:  # the round starts with the full model's value and gradient
            if basis.V.shape[1] + start.reduced.W.shape[1] > MAX_BASIS:  # start afresh from this point's space
                basis.reset()
            basis.add(start.reduced.W)
            basis.holds.add(start.fast_key)
        rss_start = float(np.sum(fits.log_residual(start.amplitude, u) ** 2))
        try:
            if prev is not None:  # the reduced model's own sum of squares at the start, its gain's reference
                held = _ReducedLinearised(basis, model, prev.alpha, freqs, prev.applied)
                rss_held = float(np.sum(fits.log_residual(held.amplitude, u) ** 2))
            fit, n = _reduced_fit(basis, model, freqs, u, alpha, effect, location, value, applied, max_evaluations,
                                  tol, alpha_bounds)
        except (np.linalg.LinAlgError, ValueError) as error:  # a reduced pencil that is not definite, say
            log.info("reduced fit failed (%s): the plain fit takes over", error)
            break
        reduced_evals += n
        # From a start the basis holds exactly (the full model's value and gradient there) the reduced fit
        # gains next to nothing: the start, the previous round's end, was (to the fit's tolerance) a
        # stationary point of the full model; the fit ends there, with the full residual already computed.
        if prev is not None and rss_held - fit.rss <= max(tol, 1e-9) * rss_held:
            return _ended(prev, start, u, built, t0, k - 1, reduced_evals, basis, "no gain from the held end",
                          fine=tol < COARSE)
        alpha, value, applied = fit.alpha, (fit.values if effect is not None else None), list(fit.prior)
        full = full_response(model, alpha, freqs, fit.applied)
        gap = float(np.max(np.abs(np.log(full.amplitude) - np.log(fit.model_amplitude))))
        log.debug("reduced fit round %d: basis %d, rss %.6g, gap to the full model %.2e", k, basis.V.shape[1],
                  fit.rss, gap)
        r = fits.log_residual(full.amplitude, u)
        # Done when the reduced model is right at the end and, from a start it held exactly, found next to
        # nothing to gain: the start was (to the fit's tolerance) a stationary point of the full model too.
        if gap <= AGREE and rss_start - float(np.sum(r**2)) <= max(tol, 1e-9) * rss_start:
            return _ended(fit, full, u, built, t0, k, reduced_evals, basis, "agreed, no gain", fine=tol < COARSE)
        if tol >= COARSE and _rss_agrees(fit.rss, full, u, tol):  # a coarse fit: its sum of squares is right
            return _ended(fit, full, u, built, t0, k, reduced_evals, basis, "coarse, sums of squares agree",
                          fine=False)
        start, prev = full, fit
    else:
        log.info("reduced fit did not agree with the full model after %d rounds: the plain fit finishes it",
                 MAX_ROUNDS)
    plain = _PLAIN_FIT(model, freqs, u, alpha, effect, location, value, max_evaluations=max_evaluations, tol=tol,
                       alpha_bounds=alpha_bounds, prior=applied)
    plain.evaluations += _BUILT[0] - built
    plain.seconds = time.perf_counter() - t0
    plain.message += f" (reduced model: ended by the plain fit, {reduced_evals} reduced evaluations)"
    log.debug("fast fit: %s", plain.message)
    return plain


def _reduced_fit(basis, model, freqs, u, alpha, effect, location, value, applied, max_evaluations, tol,
                 alpha_bounds):
    """``fits.fit_update`` with every evaluation on the basis; (fit, reduced evaluations)."""
    count = [0]

    def factory(model_, alpha_, freqs_, applied_=()):
        count[0] += 1
        return _ReducedLinearised(basis, model_, alpha_, freqs_, applied_)

    with _responses(factory):
        fit = _PLAIN_FIT(model, freqs, u, alpha, effect, location, value, max_evaluations=max_evaluations,
                         tol=tol, alpha_bounds=alpha_bounds, prior=applied)
    return fit, count[0]


def _round0(basis, model, freqs, u, alpha, effect, location, value, applied, max_evaluations, tol, alpha_bounds):
    """A fit's first round on the basis as it is, without its start's full space: (fit, the full response at
    its end, reduced evaluations), or None if the reduced fit failed or its end is, in full, no better than
    the reduced model's start (the basis was not good enough there: the rounds start from the start)."""
    try:
        at_start = _ReducedLinearised(basis, model, alpha, freqs, _with(applied, effect, location, value))
        rss0 = float(np.sum(fits.log_residual(at_start.amplitude, u) ** 2))
        fit, n = _reduced_fit(basis, model, freqs, u, alpha, effect, location, value, applied, max_evaluations,
                              tol, alpha_bounds)
    except (np.linalg.LinAlgError, ValueError) as error:
        log.info("reduced fit on the basis as it is failed (%s): rounds from its start", error)
        return None
    full = full_response(model, fit.alpha, freqs, fit.applied)
    if float(np.sum(fits.log_residual(full.amplitude, u) ** 2)) > rss0:
        log.info("reduced fit on the basis as it is ended worse than it started: rounds from its start")
        return None
    return fit, full, n + 1


def _rss_agrees(rss_reduced: float, full, u, tol: float) -> bool:
    """The reduced fit's sum of squares is the full model's at its end, to the fit's tolerance."""
    rss = float(np.sum(fits.log_residual(full.amplitude, u) ** 2))
    return abs(rss - rss_reduced) <= tol * rss


def _ended(fit, full, u, built, t0, rounds, reduced_evals, basis, why, fine=True):
    """The fit with the full model's residual at its end, its counts and its message (``why`` it ended);
    the full response at a fine fit's end is kept (a check's relocation screen is linearised there, after
    the joint fit's coarse starts)."""
    if fine:
        _keep(_ENDS, full.fast_key, full)
    r = fits.log_residual(full.amplitude, u)
    fit.residual, fit.model_amplitude = r, np.exp(r) * u
    fit.evaluations = _BUILT[0] - built
    fit.seconds = time.perf_counter() - t0
    fit.message += (f" (reduced model: {rounds} round(s), {reduced_evals} reduced evaluations, "
                    f"basis {basis.V.shape[1]}; {why})")
    log.debug("fast fit: %d full evaluation(s); %s", fit.evaluations, fit.message)
    return fit


#: Full evaluations built (Krylov spaces), for the fits' counts.
_BUILT = [0]
#: Largest basis kept across fits (columns; 34k DOFs x 480 is 130 MB); beyond it a fit's basis restarts.
MAX_BASIS = 480
_BASES: dict = {}


def shared_basis(model, freqs_hz) -> ReducedBasis:
    """The basis the closure's fits on one model and one set of lines share and enlarge (the fits of a
    closure stay near each other: a later fit usually needs one full evaluation, at its end)."""
    key = (id(model), np.asarray(freqs_hz, float).tobytes())
    basis = _BASES.get(key)
    if basis is None or basis.model is not model:
        _BASES.clear()
        _BASES[key] = basis = ReducedBasis(model, freqs_hz)
    return basis


#: The last full evaluations (key -> LinearisedResponse): a check's relocation screen is linearised at the
#: point its fit ended, where the fit's last round built the same full space.
_FULL: dict = {}
_FULL_SIZE = 2
#: The full responses at the last fine fits' ends (as many).
_ENDS: dict = {}


def _held(model, alpha, freqs_hz, applied=()):
    """The full response of a point if it is held (no new evaluation), else None."""
    held = _lookup(_key(model, alpha, freqs_hz, applied))
    return held if held is not None and held.model is model else None


def _keep(cache: dict, key, value):
    """``value`` under ``key`` in ``cache``, which keeps the last ``_FULL_SIZE`` entries (the oldest go first)."""
    cache.pop(key, None)
    cache[key] = value
    while len(cache) > _FULL_SIZE:
        cache.pop(next(iter(cache)))
    return value


def _lookup(key):
    held = _FULL.get(key)
    return _ENDS.get(key) if held is None else held


def _key(model, alpha, freqs, applied) -> tuple:
    return (id(model), np.asarray(alpha, float).tobytes(), np.asarray(freqs, float).tobytes(),
            tuple((a.effect.kind, a.location, np.asarray(a.values, float).tobytes()) for a in applied))


def full_response(model, alpha, freqs_hz, applied=()) -> LinearisedResponse:
    """:class:`LinearisedResponse` (a full Krylov space), the same object again for the same point."""
    key = _key(model, alpha, freqs_hz, applied)
    held = _lookup(key)
    if held is None or held.model is not model:
        held = _keep(_FULL, key, LinearisedResponse(model, alpha, freqs_hz, applied))
        held.fast_key = key
        _BUILT[0] += 1
    return held


def _with(applied, effect, location, value):
    from .effects import Applied

    if effect is None:
        return list(applied)
    v = np.zeros(effect.n_parameters) if value is None else np.atleast_1d(np.asarray(value, float))
    return list(applied) + [Applied(effect, location, v)]


#: Modules whose ``fit_update`` the closure calls through their own name.
_USERS = ("fe_core.closure.fits", "fe_core.closure.screening", "fe_core.closure.selection")


def by_default() -> bool:
    """Whether the closure's fits run on the reduced model in this process: yes unless
    ``MRGP_CLOSURE_FAST=0`` (the plain path)."""
    return os.environ.get("MRGP_CLOSURE_FAST", "1") != "0"


def install():
    """Switch the closure's fits to the reduced model for the rest of the process (the default: importing
    :mod:`fe_core.closure` does it unless ``MRGP_CLOSURE_FAST=0``, in the flow's worker processes too)."""
    _set(fit_update, full_response)


def uninstall():
    """Switch the closure's fits back to the plain path for the rest of the process."""
    _set(_PLAIN_FIT, LinearisedResponse)


def _set(fit, response) -> tuple:
    """Set the closure's fit and the screen's full response; returns what was there."""
    import importlib

    mods = [importlib.import_module(name) for name in _USERS]
    screening = importlib.import_module("fe_core.closure.screening")
    saved = ([m.fit_update for m in mods], screening.LinearisedResponse)
    for m in mods:
        m.fit_update = fit
    screening.LinearisedResponse = response
    return saved


@contextlib.contextmanager
def _switched(fit, response):
    import importlib

    saved_fits, saved_response = _set(fit, response)
    try:
        yield
    finally:
        for name, f in zip(_USERS, saved_fits):
            importlib.import_module(name).fit_update = f
        importlib.import_module("fe_core.closure.screening").LinearisedResponse = saved_response
        _FULL.clear()
        _ENDS.clear()
        _BASES.clear()


def enabled():
    """Within the block, the closure's fits (``fit_update`` as the fits, screening and selection modules
    call it) run on the reduced model; what was there before is restored after."""
    return _switched(fit_update, full_response)


def disabled():
    """Within the block, the closure's fits run on the plain path (a full Krylov space per evaluation);
    what was there before is restored after."""
    return _switched(_PLAIN_FIT, LinearisedResponse)
