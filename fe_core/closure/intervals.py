"""Laplace intervals of a closure's extended model: alpha and the values of the added effects
(:func:`extended_intervals`), by the Gauss-Newton steps of :mod:`fe_core.inference.intervals` with the
extended model's exact Jacobian (:func:`fe_core.closure.jacobian.extended_log_jacobian`)."""

from __future__ import annotations

import numpy as np

from ..inference.intervals import RefinedIntervals, _gauss_newton_intervals, _log_problem
from ..inference.laplace import WIDTH_THRESHOLD
from .effects import Applied
from .jacobian import extended_log_jacobian

__all__ = ["extended_intervals"]


def extended_intervals(model, freqs_hz, measured_amplitude, alpha0, applied, alpha_bounds=(-0.95, 1.0),
                       noise: float | None = None, level: float = 0.95, width_threshold: float = WIDTH_THRESHOLD,
                       max_jacobians: int = 3, step_tolerance: float = 0.1, names=None) -> RefinedIntervals:
    """Laplace intervals of alpha *and* the values of added effects (a closure's extended model).

    The same as :func:`parameter_intervals` on ``theta = [alpha, values of
    each applied effect in order]``, with the exact Jacobian of the extended
    model (:func:`fe_core.solvers.sensitivity.extended_log_jacobian`: every column,
    effects' included, a derivative on one Krylov space; a sensor gain's
    analytic). The box is ``alpha_bounds`` for alpha and each effect's
    plausible range (:meth:`fe_core.closure.effects.Effect.bounds_at`); an effect
    value whose interval contains zero is flagged (the data do not tell the
    effect from its absence), alpha as in :func:`laplace_intervals`.

    Parameters
    ----------
    model : ParametricModel
    freqs_hz : array_like, shape (p,), Hz
    measured_amplitude : array_like, shape (p, n), m/N
    alpha0 : array_like, shape (m,)
    applied : sequence of fe_core.closure.effects.Applied
        The effects with their fitted values (the start of the steps).
    alpha_bounds : (float, float)
    noise, level, width_threshold, max_jacobians, step_tolerance
        As in :func:`parameter_intervals`.
    names : list of str, optional
        Of the m + k parameters; ``alpha_i`` and ``<kind>.<parameter>`` by default.

    Returns
    -------
    RefinedIntervals
        ``intervals.estimate`` is the refined ``theta``.
    """
    applied = list(applied)
    m = model.n_segments  # the extended model's alpha; mass factors stay nominal there (extended_matrices)
    freqs, lo_a, hi_a, _ = _log_problem(model, freqs_hz, measured_amplitude, alpha_bounds[0], alpha_bounds[1], m)
    log_u = np.log(np.asarray(measured_amplitude, float)).ravel()
    sizes = np.cumsum([m] + [item.effect.n_parameters for item in applied])
    bounds = [item.effect.bounds_at(item.location) for item in applied]
    lo = np.concatenate([lo_a] + [b[0] for b in bounds])
    hi = np.concatenate([hi_a] + [b[1] for b in bounds])
    start = np.concatenate([np.asarray(alpha0, float)] + [np.atleast_1d(np.asarray(item.values, float))
                                                            for item in applied])
    if names is None:
        names = [f"alpha_{i + 1}" for i in range(m)] + [f"{item.effect.kind}.{p}" for item in applied
                                                        for p in item.effect.parameters]
    if len(names) != start.size:
        raise ValueError(f"{len(names)} names for {start.size} parameters")

    def at(theta):
        now = [Applied(item.effect, item.location, theta[a:b]) for item, a, b in zip(applied, sizes[:-1], sizes[1:])]
        J, Z = extended_log_jacobian(model, theta[:m], freqs, now)
        return np.log(np.abs(Z)).ravel() - log_u, J

    absent = np.arange(start.size) >= m
    return _gauss_newton_intervals(at, start, lo, hi, names, noise, level, width_threshold, max_jacobians,
                                   step_tolerance, absent_at_zero=absent)
