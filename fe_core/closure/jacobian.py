"""The exact Jacobian of a model with effects added, ``d ln|Z| / d [alpha, effect values]``
(:func:`extended_log_jacobian`): every column a direction of the dynamic stiffness on one Krylov space,
a sensor gain's analytic. The closure's intervals (:mod:`fe_core.closure.intervals`) use it."""

from __future__ import annotations

import numpy as np

from ..model import ParametricModel, check_parameters
from ..solvers.frf import hz_to_rad
from ..solvers.frf_derivatives import Direction, direct_frf_derivatives, krylov_frf_derivatives
from ..solvers.sensitivity import JACOBIAN_METHODS, segment_directions
from .effects import extended_matrices, sensor_gain

__all__ = ["extended_log_jacobian"]


def extended_log_jacobian(model: ParametricModel, alpha, freqs_hz, applied=(), method: str = "krylov"):
    """``d ln|Z| / d [alpha, effect values]`` of a model with effects added (:mod:`fe_core.closure.effects`), exact.

    Every column is a direction of the dynamic stiffness on one Krylov space
    (:func:`fe_core.solvers.frf_derivatives.krylov_frf_derivatives`): ``alpha_i``
    moves ``K_i`` plus any alpha-dependence of the applied effects (an element
    band scales with its segments' factors); an effect parameter moves the
    effect's terms at a unit value (``Effect.derivative``: effects are linear
    in their values), whatever they touch (K, M, the Rayleigh coefficients).
    A sensor gain ``|Z_s| (1 + g)`` changes no matrix: its column is
    ``gain_s / (1 + g_s)``, analytic.

    Parameters
    ----------
    model : ParametricModel
    alpha : array_like, shape (m,)
    freqs_hz : array_like, shape (p,), Hz
    applied : sequence of fe_core.closure.effects.Applied
        The effects in the model, each with its values (the point of linearisation).
    method : {"krylov", "direct"}

    Returns
    -------
    J : ndarray, shape (p * n_sensors, m + k)
        Columns: alpha_1..alpha_m, then each applied effect's parameters in order
        (k in all); rows frequency-major, sensors fastest.
    Z : ndarray, shape (p, n_sensors), complex, m/N
        The extended model's receptance as compared with the data (gains applied),
        as :func:`fe_core.closure.effects.extended_frf`.
    """
    if method not in JACOBIAN_METHODS:
        raise ValueError(f"unknown Jacobian method {method!r}; choose one of {JACOBIAN_METHODS}")
    alpha = check_parameters(alpha, model.n_segments, "alpha")
    freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    if freqs.ndim != 1 or freqs.size == 0 or np.any(~np.isfinite(freqs)) or np.any(freqs <= 0):
        raise ValueError(f"frequencies must be a non-empty 1-D array of positive values in Hz, got {freqs_hz!r}")
    applied = list(applied)
    K, M, a, b = extended_matrices(model, alpha, applied)
    dirs = []
    for i, base in enumerate(segment_directions(model)[:model.n_segments]):  # alpha only: the closure does not move gamma
        dK = base.stiffness
        for item in applied:
            extra = item.effect.alpha_derivative(alpha, item.location, item.values, i)
            if extra is not None and extra.stiffness is not None:
                dK = dK + extra.stiffness
        dirs.append(Direction(stiffness=dK))
    gains = {}  # column -> d(gain) per unit value, shape (n_sensors,)
    for item in applied:
        for j in range(item.effect.n_parameters):
            t = item.effect.derivative(alpha, item.location, j)
            if getattr(t, "gain", None) is not None:
                gains[len(dirs)] = np.asarray(t.gain, float)
            dirs.append(t)
    args = (K, M, a, b, model.combined_load(), model.outputs, dirs, hz_to_rad(freqs))
    Z, dZ = krylov_frf_derivatives(*args) if method == "krylov" else direct_frf_derivatives(*args)
    Z, dZ = Z[:, :, 0], dZ[:, :, 0, :]
    g = sensor_gain(model, alpha, applied)
    J = np.real(dZ / Z[:, :, None])  # the gain factor cancels in d ln|Z| of a structural change
    for col, dg in gains.items():
        J[:, :, col] += (dg / (1.0 + g))[None, :]
    return J.reshape(-1, J.shape[-1]), Z * (1.0 + g)[None, :]
