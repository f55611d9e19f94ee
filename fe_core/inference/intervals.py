"""Intervals on the FE model: the log-amplitude least squares (:func:`fit_log_amplitudes`) and Gauss-Newton
steps from an update's result to the optimum with the exact Jacobian, then the Laplace intervals there
(:func:`parameter_intervals`).

The error model (multiplicative amplitude noise, a Gaussian log residual) and the intervals at an optimum
are in :mod:`fe_core.inference.laplace`. Plain numpy/scipy.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy import optimize

from .laplace import WIDTH_THRESHOLD, Intervals, laplace_intervals

__all__ = [
    "LogFit",
    "fit_log_amplitudes",
    "RefinedIntervals",
    "parameter_intervals",
]

log = logging.getLogger(__name__)


def _log_problem(model, freqs_hz, measured_amplitude, lower, upper, m: int | None = None):
    """Checked inputs: ``(freqs (p,), lower (m,), upper (m,), residual)``; ``residual(alpha)``: log residual (p n,).

    ``m``: the box's length, the model's parameters (alpha and updated mass factors) by default.
    """
    freqs = np.asarray(freqs_hz, float)
    u = np.asarray(measured_amplitude, float)
    if u.shape != (freqs.size, model.n_sensors):
        raise ValueError(f"measured amplitude has shape {u.shape}, expected (frequencies, sensors) = "
                         f"({freqs.size}, {model.n_sensors})")
    if not np.all(np.isfinite(u) & (u > 0)):
        raise ValueError("measured amplitudes must be finite and positive (the residual is logarithmic)")
    m = model.n_parameters if m is None else m
    lo = np.broadcast_to(np.asarray(lower, float), (m,)).copy()
    hi = np.broadcast_to(np.asarray(upper, float), (m,)).copy()
    if np.any(lo <= -1.0) or np.any(lo >= hi):
        raise ValueError(f"the box [{lower}, {upper}] must lie inside (-1, inf) with lower < upper")
    log_u = np.log(u).ravel()

    def residual(a):
        return np.log(np.abs(model.parameter_frf(a, freqs))).ravel() - log_u

    return freqs, lo, hi, residual


@dataclass(frozen=True)
class LogFit:
    """A least-squares fit of log-amplitudes on the FE model (:func:`fit_log_amplitudes`).

    Attributes
    ----------
    alpha : ndarray, shape (m,)
    residual : ndarray, shape (p * n,)
        ``ln|Z(alpha)| - ln u``, frequency-major, sensors fastest.
    jacobian : ndarray, shape (p * n, m)
        Exact (adjoint) ``d residual / d alpha`` at ``alpha``.
    fe_runs : int
        FRF evaluations (Krylov) of the fit, finite-difference ones included.
    jacobians : int
        Exact Jacobian evaluations (each about 2 Krylov FRFs of time on the
        benchmark), the final one at ``alpha`` included.
    status : str
        scipy's message.
    """

    alpha: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    fe_runs: int
    jacobians: int
    status: str


def fit_log_amplitudes(model, freqs_hz, measured_amplitude, alpha0, lower, upper, max_fe_runs: int = 20,
                       xtol: float = 1e-8, search_jacobian: str = "exact") -> LogFit:
    """Least squares of the log residual on the FE model, from ``alpha0``; exact Jacobian at the end.

    ``scipy.optimize.least_squares`` (trust region reflective, bounds
    ``[lower, upper]``). The search's Jacobian is the exact adjoint one
    (:func:`fe_core.solvers.sensitivity.log_amplitude_jacobian` on a Krylov space,
    about 2 Krylov FRFs of time on the benchmark) or, with ``search_jacobian =
    "2-point"``, forward differences of step 1e-6 (m Krylov FRFs; the same
    optimum to the accuracy of the differences).
    The returned Jacobian is always the exact one at the optimum.
    A local search: start it in the basin (the update's result).

    Parameters
    ----------
    model : ParametricModel
    freqs_hz : array_like, shape (p,), Hz
    measured_amplitude : array_like, shape (p, n), m/N, all > 0
    alpha0 : array_like, shape (m,)
        Start (clipped into the box).
    lower, upper : float or array_like (m,)
        Search box; ``lower`` must be > -1.
    max_fe_runs : int
        Budget of residual evaluations (scipy's ``max_nfev``; each
        iteration costs one, plus one Jacobian).
    xtol : float
        scipy's step tolerance (relative to ``x_scale = "jac"``).
    search_jacobian : {"exact", "2-point"}

    Returns
    -------
    LogFit
    """
    from ..solvers.sensitivity import log_amplitude_jacobian

    freqs, lo, hi, log_residual = _log_problem(model, freqs_hz, measured_amplitude, lower, upper)
    counts = {"fe": 0, "jac": 0}
    cache: dict[bytes, np.ndarray] = {}

    def fun(a):
        counts["fe"] += 1
        return log_residual(a)

    def jac(a):
        key = np.asarray(a, float).tobytes()
        if key not in cache:
            counts["jac"] += 1
            cache.clear()
            cache[key] = log_amplitude_jacobian(model, a, freqs)
        return cache[key]

    if search_jacobian not in ("exact", "2-point"):
        raise ValueError(f"search_jacobian must be 'exact' or '2-point', got {search_jacobian!r}")
    x0 = np.clip(np.asarray(alpha0, float), lo, hi)
    extra = {"jac": jac} if search_jacobian == "exact" else {"jac": "2-point", "diff_step": 1e-6}
    res = optimize.least_squares(fun, x0, bounds=(lo, hi), method="trf", x_scale="jac", xtol=xtol, ftol=1e-12,
                                 gtol=1e-12, max_nfev=max_fe_runs, **extra)
    J = jac(res.x)  # cached when scipy's last Jacobian was at the optimum
    log.info("log-amplitude least squares: %s after %d FE runs and %d Jacobians", res.message, counts["fe"],
             counts["jac"])
    return LogFit(alpha=res.x, residual=res.fun, jacobian=J, fe_runs=counts["fe"], jacobians=counts["jac"],
                  status=str(res.message))


@dataclass(frozen=True)
class RefinedIntervals:
    """Intervals after Gauss-Newton steps from an update's result (:func:`parameter_intervals`).

    Attributes
    ----------
    intervals : Intervals
        Centred on the refined least-squares estimate.
    start : ndarray, shape (m,)
        The update's result the steps started from.
    residual : ndarray, shape (p * n,)
        Log residual at ``intervals.estimate``.
    last_step_in_std : float
        Largest ``|step_i| / std_i`` of the last Gauss-Newton step computed
        (taken or not): below ``step_tolerance`` the estimate is at the
        optimum as far as the intervals can tell.
    at_optimum : bool
    fe_runs : int
        FRF evaluations besides the Jacobians (each Jacobian brings its FRF): the chord steps' (:data:`CHORD_STD`)
        that were not first-order expansions.
    first_order_frfs : int
        Chord steps whose FRF was the Jacobian point's first-order expansion (:data:`LINEAR_STD`): no FE run.
    jacobians : int
        Exact Jacobians (with their FRF) the intervals cost.
    jacobian : ndarray, shape (p * n, m)
        ``d residual / d alpha`` at ``jacobian_at``: the estimate, or after a chord step the point a step of at
        most :data:`CHORD_STD` standard deviations before it.
    weights : ndarray, shape (p * n,), or None
        With a noise per line and channel (``noise_model``): ``residual`` and ``jacobian`` are divided by it
        (whitened, unit noise); None: one relative level.
    noise_model : NoiseModel or None
        The noise per line and channel the intervals used (measured, or estimated at the start).
    frf_at_estimate : ndarray, shape (p, n), or None
        After a chord step: the receptance at ``intervals.estimate`` its FRF computed or expanded to first order
        (the caller's measure of the run's own error at the optimum needs no second one); else None.
    """

    intervals: Intervals
    start: np.ndarray
    residual: np.ndarray
    last_step_in_std: float
    at_optimum: bool
    fe_runs: int
    jacobians: int
    jacobian: np.ndarray | None = None
    weights: np.ndarray | None = None
    noise_model: object = None
    #: Where ``jacobian`` was computed: the estimate, or the point one chord step before it (:data:`CHORD_STD`).
    jacobian_at: np.ndarray | None = None
    frf_at_estimate: np.ndarray | None = None
    first_order_frfs: int = 0


def parameter_intervals(model, freqs_hz, measured_amplitude, alpha0, lower, upper, noise: float | None = None,
                        level: float = 0.95, width_threshold: float = WIDTH_THRESHOLD, max_jacobians: int = 3,
                        step_tolerance: float = 0.1, channels=None, chord_std: float | None = None,
                        known=None) -> RefinedIntervals:
    """Laplace intervals at the log-amplitude least-squares optimum near an update's result.

    The update's result (the polish's best FE run) is within a fraction of
    an interval of the optimum, but it minimised the relative residual and
    stopped when it stalled, so Gauss-Newton steps with the exact Jacobian
    (:func:`fe_core.solvers.sensitivity.log_amplitude_jacobian`) finish the job:
    ``step = -(J^T J)^-1 J^T r``, taken (clipped to the box) while it lowers
    ``||r||^2``, until the step is below ``step_tolerance`` standard
    deviations in every parameter or ``max_jacobians`` Jacobians are spent.
    The intervals (:func:`laplace_intervals`) then use the Jacobian and the
    residual at the final estimate. Each point costs one Jacobian, whose
    Krylov space gives the FRF (hence the residual) too: one Jacobian (about
    2 FE runs of time on the benchmark) when the start is already at the
    optimum, one more per step; a step within ``chord_std`` standard deviations costs an FRF instead (a chord
    step: the Jacobian of the point before it kept, see :data:`CHORD_STD`).

    Parameters
    ----------
    model, freqs_hz, measured_amplitude, alpha0, lower, upper
        As in :func:`fit_log_amplitudes`.
    noise : float, NoiseModel or Estimated, optional
        Relative amplitude noise (standard deviation); or the noise per line and channel of the (p, n) values
        (:class:`fe_core.inference.noise.NoiseModel`), or :class:`fe_core.inference.noise.Estimated` (that model
        estimated from the residual at the start): the residual and its Jacobian are then divided by it (weighted
        least squares, unit noise); one relative level estimated from the residual when None.
    level, width_threshold : float
        As in :func:`laplace_intervals`.
    max_jacobians : int
        At least 1.
    step_tolerance : float
        In standard deviations.
    channels : (responses, references), optional
        (sensor, excitation) channels of ``measured_amplitude``'s columns (:meth:`ParametricModel.parameter_frf`):
        several references (roving hammer, MIMO) are stacked in one residual, every (line, channel) amplitude
        with the same relative noise; one Krylov space per point carries all their loads. None = the model's
        sensors under its load.
    chord_std : float, optional
        Largest step (in standard deviations) taken as a chord step; by default :data:`CHORD_STD` for a model of
        at least :data:`CHORD_MIN_DOFS` free DOFs, else 0 (every point gets its Jacobian).
    known : (Z, dZ), optional
        The receptance (p, n) and its derivative (p, n, m) at ``alpha0`` on these lines and channels, from an FE
        run already made there (a large model's confirmed local centre): the first point's Jacobian is not
        computed again (nor counted in ``jacobians``).

    Returns
    -------
    RefinedIntervals
    """
    from ..solvers.sensitivity import frf_jacobian

    freqs, lo, hi, _ = _log_problem(model, freqs_hz, measured_amplitude, lower, upper)
    log_u = np.log(np.asarray(measured_amplitude, float)).ravel()
    given = {} if known is None else {np.clip(np.asarray(alpha0, float), lo, hi).tobytes(): known}

    jacobian_point = {}
    linear = (chord_std if chord_std is not None else _chord_default(model)) > 0.0

    def at(alpha):  # residual and Jacobian from one Krylov space (d log|Z| = Re(dZ / Z))
        alpha = np.asarray(alpha, float)
        Z, dZ = given.pop(alpha.tobytes()) if alpha.tobytes() in given else \
            frf_jacobian(model, alpha, freqs, channels=channels)
        Z, dZ = np.asarray(Z), np.asarray(dZ)
        r = np.log(np.abs(Z)).ravel() - log_u
        if linear:  # a chord step's FRF may be this point's first-order expansion (LINEAR_STD)
            jacobian_point.update(alpha=alpha, Z=Z, dZ=dZ, r=r)
        return r, np.real(dZ / Z[:, :, None]).reshape(-1, dZ.shape[-1])

    last_frf, first_order = {}, []

    def frf_only(alpha):  # the residual alone: one FRF, no Jacobian (kept: the chord step's point may be the optimum)
        Z = _first_order(jacobian_point, alpha, weights if weights is not None else noise)  # the noise (below)
        if Z is None:
            Z = np.asarray(model.parameter_frf(alpha, freqs, channels))
        else:
            first_order.append(True)
        last_frf.clear()
        last_frf[np.asarray(alpha, float).tobytes()] = Z
        return np.log(np.abs(Z)).ravel() - log_u

    at, noise, weights, noise_model = _weighted(at, alpha0, lo, hi, freqs, noise)
    residual_at = frf_only if weights is None else (lambda alpha: frf_only(alpha) / weights)
    refined = _gauss_newton_intervals(at, alpha0, lo, hi, model.parameter_names, noise, level, width_threshold,
                                      max_jacobians, step_tolerance, residual_at=residual_at,
                                      chord_std=_chord_default(model) if chord_std is None else chord_std)
    reused = known is not None and not given  # the start's Jacobian was the one given
    at_estimate = last_frf.get(np.asarray(refined.intervals.estimate, float).tobytes())
    return replace(refined, weights=weights, noise_model=noise_model, jacobians=refined.jacobians - reused,
                   frf_at_estimate=at_estimate, fe_runs=refined.fe_runs - len(first_order),
                   first_order_frfs=len(first_order))


def _weighted(at, start, lo, hi, freqs, noise):
    """``(at, noise, weights, model)`` for the Gauss-Newton steps: with a noise per line and channel, ``at``
    divides the residual and the Jacobian by it and the noise is 1 (known); an :class:`Estimated` model is fitted
    to the residual at the start (``at`` called once more there)."""
    from .noise import Estimated, judged_by, one_level

    if one_level(noise, freqs):  # as the residual's test (:func:`analyse_residual`)
        return at, (None if isinstance(noise, Estimated) else noise), None, None
    first = {}
    if isinstance(noise, Estimated) or noise.source in ("coherence", "records"):  # judged at the start's residual
        x0 = np.clip(np.asarray(start, float), lo, hi)
        first[x0.tobytes()] = at(x0)  # the start's Jacobian serves the first step too
        shape = np.shape(noise.amplitude) if isinstance(noise, Estimated) else noise.sigma.shape
        noise = judged_by(noise, first[x0.tobytes()][0].reshape(shape), freqs)
        log.info("intervals: the noise per line and channel %s", noise.describe())
    weights = np.asarray(noise.sigma, float).ravel()

    def weighted(alpha):
        alpha = np.asarray(alpha, float)
        r, J = first.pop(alpha.tobytes()) if alpha.tobytes() in first else at(alpha)
        return r / weights, J / weights[:, None]

    return weighted, 1.0, weights, noise


#: A Gauss-Newton step (in the parameters) below which the point counts as the optimum: the FRF's own accuracy.
RESOLVABLE_STEP = 1e-8
#: A step of at most this many standard deviations is a **chord step**: taken with the Jacobian of the point before
#: it, the new point costs an FRF, not a Jacobian, and it is the optimum when the next step with that same Jacobian
#: is below the step tolerance. The intervals take the model as linear over their width (the linearity check of
#: :mod:`.posterior` looks two standard deviations out), so within one the Jacobian moves by less than they can
#: tell. The usual case: an update's result lies a fraction of a standard deviation from the log-amplitude optimum
#: (it minimised another residual); on the 500k-DOF panel the second Jacobian took 4.4 min, an FRF 1.4.
CHORD_STD = 1.0
#: Chord steps only for models of at least this many free DOFs (those whose Krylov spaces are recycled,
#: :data:`fe_core.solvers.recycle.MIN_DOFS`): a smaller model's Jacobian costs seconds, and its intervals stay those
#: of the Jacobian at the estimate (on the benchmark at 1 % noise, one taken half a standard deviation away makes
#: them 2.4 % wider or narrower).
CHORD_MIN_DOFS = 50_000


#: A chord step's FRF is the first-order expansion ``Z + dZ step`` at the Jacobian's point when the term it leaves
#: out cannot move the estimate by more than this many standard deviations (half the step tolerance that settles
#: the optimum). That term, in ``ln|Z|``, is at most ``|x|^2 / 2`` for each value's relative change ``x = dZ step / Z``;
#: whitened by the noise, its norm bounds the estimate's move in standard deviations (the least-squares step of a
#: whitened residual ``e`` is ``e`` projected on the Jacobian's columns). On the 500k-DOF panel (7,200 values, 0.68 %
#: noise, changes of at most 0.18 %) the bound is 0.02 standard deviations; the FE run it saves was 40 s there and
#: 198 s at 1M DOFs (the step, 0.1-1 standard deviation, is too far for the held factor to serve).
LINEAR_STD = 0.05
#: And no value changes by more than this (the expansion's next term, |x|^3 / 3, stays below a thousandth of it).
LINEAR_CHANGE = 0.1


def _first_order(point: dict, alpha, sigma) -> np.ndarray | None:
    """``Z + dZ (alpha - a)`` from the Jacobian's point ``a`` (``point``: alpha, Z, dZ, r), or None when there is
    none or the term it leaves out could move the estimate by more than :data:`LINEAR_STD` standard deviations
    (``sigma``: the noise of each value or one level; None: the rms of the residual ``r`` at the point)."""
    if not point:
        return None
    change = point["dZ"] @ (np.asarray(alpha, float) - point["alpha"])
    x = np.abs(change) / np.maximum(np.abs(point["Z"]), np.finfo(float).tiny)
    level = np.sqrt(np.mean(point["r"] ** 2)) if sigma is None else np.asarray(sigma, float).reshape(-1)
    bound = float(np.linalg.norm(0.5 * x.ravel() ** 2 / level))
    if bound > LINEAR_STD or float(x.max()) > LINEAR_CHANGE:
        log.info("intervals: the chord step's FRF to first order could be %.2g standard deviations off (largest "
                 "change %.2g of a value): an FE run there", bound, float(x.max()))
        return None
    log.info("intervals: the chord step's FRF from the Jacobian's point to first order (largest change %.2g of a "
             "value; the term left out moves the estimate by at most %.2g standard deviations)", float(x.max()), bound)
    return point["Z"] + change


def _chord_default(model) -> float:
    return CHORD_STD if getattr(model, "n_dofs", 0) >= CHORD_MIN_DOFS else 0.0


def _gauss_newton_intervals(at, start, lo, hi, names, noise, level, width_threshold, max_jacobians, step_tolerance,
                            absent_at_zero=None, residual_at=None, chord_std: float = 0.0) -> RefinedIntervals:
    """Gauss-Newton steps from ``start`` (``at(theta) -> (residual, jacobian)``), then Laplace intervals; with
    ``residual_at(theta) -> residual`` (one FRF) a step within ``chord_std`` standard deviations is a chord step
    (:data:`CHORD_STD`)."""
    if max_jacobians < 1:
        raise ValueError(f"max_jacobians must be at least 1, got {max_jacobians}")
    start = np.clip(np.asarray(start, float), lo, hi)
    a = start
    r, J = at(a)
    a_J, jacobians, fe_runs = a, 1, 0

    def intervals(r, J, a):
        iv = laplace_intervals(r, J, a, names=names, noise=noise, level=level, lower=lo, upper=hi,
                               width_threshold=width_threshold)
        if absent_at_zero is None:
            return iv
        absent = np.asarray(absent_at_zero, bool)
        unpinned = np.where(absent, (iv.low <= 0) & (0 <= iv.high), iv.unpinned)
        return replace(iv, unpinned=unpinned, absent_at_zero=absent)

    while True:
        iv = intervals(r, J, a)
        step, in_std, settled = _gauss_newton_step(J, r, iv, step_tolerance)
        if settled or jacobians >= max_jacobians:
            break
        a_new = np.clip(a + step, lo, hi)
        if residual_at is not None and in_std <= chord_std:
            chord = _chord_step(residual_at, intervals, a_new, r, J, step_tolerance)
            fe_runs += 1
            if chord is not None:  # the optimum, with the Jacobian of the point before
                a, r, iv, in_std = a_new, *chord
                settled = True
                break
        r_new, J_new = at(a_new)
        jacobians += 1
        if not r_new @ r_new < r @ r:
            log.warning("intervals: a Gauss-Newton step of %.3g standard deviations did not lower the residual; "
                        "the linearisation is poor here", in_std)
            break
        a, r, J, a_J = a_new, r_new, J_new, a_new
    log.info("intervals: %d Jacobians (each with its FRF) and %d FRFs, last Gauss-Newton step %.3g standard "
             "deviations%s", jacobians, fe_runs, in_std, " (a chord step)" if a_J is not a else "")
    return RefinedIntervals(intervals=iv, start=start, residual=r, last_step_in_std=in_std,
                            at_optimum=bool(settled), fe_runs=fe_runs, jacobians=jacobians, jacobian=J,
                            jacobian_at=np.array(a_J, float))


def _chord_step(residual_at, intervals, a_new, r, J, step_tolerance):
    """The residual at ``a_new`` (one FRF) and, with the Jacobian ``J`` of the point before, the intervals there
    and the next step in standard deviations: ``(r_new, intervals, step)`` when the residual fell and that step
    is below ``step_tolerance`` (``a_new`` is the optimum), else None (the caller takes the Jacobian at
    ``a_new``)."""
    r_new = residual_at(a_new)
    if not r_new @ r_new < r @ r:
        return None
    iv = intervals(r_new, J, a_new)
    _, in_std, settled = _gauss_newton_step(J, r_new, iv, step_tolerance)
    return (r_new, iv, in_std) if settled else None


def _gauss_newton_step(J, r, iv, step_tolerance):
    """``(step, its largest size in standard deviations, settled)``: the step ``-(J^T J)^-1 J^T r`` and whether
    it is below ``step_tolerance`` standard deviations or beneath what the FRF resolves (the FE core's 1e-9
    between methods: on noise-free data the standard deviations are round-off and so is the step)."""
    step = np.linalg.lstsq(J, -r, rcond=None)[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        in_std = float(np.nanmax(np.abs(step) / iv.std)) if np.isfinite(iv.std).any() else float("inf")
    return step, in_std, in_std <= step_tolerance or float(np.max(np.abs(step))) <= RESOLVABLE_STEP
