"""The extended model: the model's matrices and FRF with effects applied (:func:`extended_matrices`,
:func:`extended_frf`), the sensor gains (:func:`sensor_gain`) and the first-order change of ln|Z| for any
candidate (:class:`LinearisedResponse`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from ...model import ParametricModel, check_parameters
from ...solvers.frf import direct_frf, hz_to_rad, krylov_frf
from .base import Applied, Effect, Terms

__all__ = ["extended_matrices", "extended_frf", "segment_stiffness", "sensor_gain", "LinearisedResponse"]


def extended_matrices(model: ParametricModel, alpha, applied: Sequence[Applied] = ()):
    """``K, M, a, b`` of the model at ``alpha`` with the applied effects added."""
    alpha = check_parameters(alpha, model.n_segments, "alpha")
    K = model.stiffness(alpha)
    M = getattr(model, "_effects_mass", None)
    if M is None:  # M(gamma = 0) never changes: assemble it once per model
        M = model._effects_mass = model.mass()
    a, b = model.damping
    for item in applied:
        t = item.terms(alpha)
        if t.gain is not None:
            continue
        if t.stiffness is not None:
            K = K + t.stiffness
        if t.mass is not None:
            M = M + t.mass
        a += t.damping_a
        b += t.damping_b
    return sp.csr_matrix(K), sp.csr_matrix(M), a, b


def extended_frf(model: ParametricModel, alpha, freqs_hz, applied: Sequence[Applied] = (),
                 method: str = "krylov") -> np.ndarray:
    """Receptance at the sensors (the model's output vectors) under its load, with effects; shape (p, n_sensors),
    m/N (the benchmark's load is the combined one)."""
    freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    if freqs.ndim != 1 or freqs.size == 0 or np.any(~(freqs > 0)):
        raise ValueError(f"frequencies must be a non-empty 1-D array of positive values in Hz, got {freqs_hz!r}")
    K, M, a, b = extended_matrices(model, alpha, applied)
    F = model.combined_load()
    omegas = hz_to_rad(freqs)
    rows = model._out_rows  # the DOFs the output vectors read
    if method == "direct":
        Z = direct_frf(K, M, a * M + b * K, F, omegas, rows)[:, :, 0]
    elif method == "krylov":
        Z = krylov_frf(K, M, a, b, F, omegas, rows)[:, :, 0]
    else:
        raise ValueError(f"unknown FRF method {method!r}; choose 'krylov' or 'direct'")
    return (Z @ model._out_weights) * (1.0 + sensor_gain(model, alpha, applied))[None, :]


def segment_stiffness(model: ParametricModel, i: int) -> sp.csr_matrix:
    """Segment ``i``'s stiffness at alpha = 0 without the common pattern's explicit zeros (cached on the
    model): a derivative with respect to alpha_i touches only the segment's rows."""
    cache = model.__dict__.setdefault("_segment_stiffness_cache", {})
    if i not in cache:
        cache[i] = model.stiffness_segments.own(i)
    return cache[i]


def sensor_gain(model: ParametricModel, alpha, applied: Sequence[Applied] = ()) -> np.ndarray:
    """Sum of the applied sensor gains, shape (n_sensors,) (zero without any)."""
    g = np.zeros(model.n_sensors)
    for item in applied:
        t = item.terms(alpha)
        if t.gain is not None:
            g = g + t.gain
    return g


class LinearisedResponse:
    """First-order change of ln|Z| at the sensors for any change of (K, M, a, b).

    With ``D(w) = K - w^2 M + j w (a M + b K)``, the model's load F and output
    vectors ``l_s``, the field is ``h = D^-1 F``, ``Z_s = l_s^T h`` and
    ``dZ_s = -l_s^T D^-1 dD h``. D is complex symmetric, so ``l_s^T D^-1`` is
    the response ``X_s`` to a unit load along ``l_s`` (reciprocity), and
    ``dZ_s = -X_s^T (dD h)``: one Krylov space of F and the sensor loads
    (:class:`fe_core.solvers.adjoint.ReducedResponse`) gives the sensitivity to *every*
    candidate, e.g. a point mass at each of hundreds of nodes, without a solve
    per candidate.

    Parameters
    ----------
    model : ParametricModel
    alpha : array_like
    freqs_hz : array_like, shape (p,)
    applied : sequence of Applied
        Effects already in the model (the point of linearisation).
    """

    def __init__(self, model: ParametricModel, alpha, freqs_hz, applied: Sequence[Applied] = ()):
        from ...solvers.adjoint import ReducedResponse

        self.model = model
        self.alpha = check_parameters(alpha, model.n_segments, "alpha")
        self.freqs_hz = np.asarray(freqs_hz, float)
        self.omegas = hz_to_rad(self.freqs_hz)
        self.applied = list(applied)
        # K and M are not kept: their space and projections are (a response is cached, and at 500k DOFs the two
        # matrices are over a GB beside the space's 0.6 GB)
        K, M, self.a, self.b = extended_matrices(model, alpha, applied)
        self.gain = sensor_gain(model, self.alpha, self.applied)
        self.reduced = ReducedResponse(K, M, self.a, self.b, model.combined_load(), model.outputs,
                                       self.omegas, self.gain)
        self.Z = self.reduced.Z  # (p, n_s), without the gains

    @property
    def amplitude(self) -> np.ndarray:
        """The compared amplitude ``|Z| (1 + gain)``, shape (p, n_sensors), m/N."""
        return self.reduced.amplitude

    def derivative(self, terms: Terms) -> np.ndarray:
        """``d ln|Z_s(f)|`` per unit of the change described by ``terms``, shape (p, n_sensors)."""
        return self.reduced.dlog(terms.stiffness, terms.mass, terms.damping_a, terms.damping_b, terms.gain)

    def alpha_derivatives(self) -> np.ndarray:
        """``d ln|Z| / d alpha_i``, shape (p * n_sensors, n_segments), frequency-major rows.

        Includes the alpha-dependence of the applied effects (an element band
        scales with its segments' factors).
        """
        cols = []
        for i in range(self.model.n_segments):
            dK = segment_stiffness(self.model, i)
            for item in self.applied:
                extra = item.effect.alpha_derivative(self.alpha, item.location, item.values, i)
                if extra is not None and extra.stiffness is not None:
                    dK = dK + extra.stiffness
            cols.append(self.derivative(Terms(stiffness=dK)).ravel())
        return np.column_stack(cols)

    def batch_derivatives(self, effect: Effect, locations: Sequence[str]) -> np.ndarray:
        """``d ln|Z| / d values`` of an effect at many locations, shape (L, p * n_sensors, k): in one
        product for a diagonal effect (:meth:`Effect.diagonal`), else location by location."""
        diag = effect.diagonal(locations) if effect.n_parameters == 1 else None
        if diag is not None:
            d = self.reduced.diagonal_dlog(*diag)
            return d.reshape(len(locations), -1, 1)
        return np.stack([self.effect_derivatives(effect, loc) for loc in locations]) if locations else \
            np.zeros((0, self.Z.size, effect.n_parameters))

    def effect_derivatives(self, effect: Effect, location: str) -> np.ndarray:
        """``d ln|Z| / d values`` of an effect at a location, shape (p * n_sensors, k)."""
        return np.column_stack([self.derivative(effect.derivative(self.alpha, location, i)).ravel()
                                for i in range(effect.n_parameters)])
