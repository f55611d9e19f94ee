"""What the adaptive loop's MRGP emulates by default: the model's modes, not its error.

The paper emulates the response errors. Near a resonance the FRF amplitude, and every error made from
it, changes over a small fraction of a parameter's range (a resonance moves by its half-power band for a
few per cent of stiffness), so an emulator of errors from 20-240 samples in six parameters sees a rough
surface and the loop stalls at 2-22 % on the benchmark (measured at 31854ac: git show 0cbca1f:docs/update-results.md). The modes behind the
FRF are smooth functions of the parameters: ``w_r^2`` is a Rayleigh quotient, linear in a segment's
stiffness factor at a fixed mode shape. With Rayleigh damping (``C = a M + b K``) the receptance of a
channel c at the circular frequency w is exactly ::

    Z_c(w) = sum_{r <= n} P[r, c] / (w_r^2 - w^2 + i w (a + b w_r^2))  +  R_c(w)

with ``P[r, c]`` the participation of mode r (:meth:`fe_core.model.ParametricModel.modal_terms`) and
``R_c(w)`` the remainder of the modes above the n lowest (smooth in w and in the parameters). The MRGP
emulates ``[w_r^2, P[r, c], Re R, Im R]`` and the error of a candidate is computed from the receptance
they give (a composite objective: Astudillo and Frazier, ICML 2019). The split is exact for every FE run
whatever the model's damping (``R`` is what the n modes leave), so the emulator interpolates the FE
receptances; only its smoothness depends on how well the lowest modes carry the band.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ModalLayout", "modes_to_emulate", "BAND_FACTOR", "CLOSE_GAP"]

#: Modes below this factor times the highest measured frequency (nominal model) are emulated, plus one.
BAND_FACTOR = 1.5
#: ... and the modes after those closer than this (relative frequency gap) to the last one taken: a close pair
#: swaps order as the parameters change, and only the pair together is smooth.
CLOSE_GAP = 0.1


def modes_to_emulate(nominal_hz: np.ndarray, highest_hz: float, available: int) -> int:
    """How many of the lowest modes to emulate.

    Those of the nominal model below ``BAND_FACTOR`` times the highest measured frequency, plus the next one
    (a mode may enter the band as parameters change), plus every following mode within ``CLOSE_GAP`` of the
    last one taken (a close pair is taken whole); at least 1 and at most ``available``. ``nominal_hz``: the
    model's lowest modes, ascending; give more than the band needs so the gap after the last can be seen.
    """
    f = np.asarray(nominal_hz, float)
    n = int(np.count_nonzero(f < BAND_FACTOR * float(highest_hz))) + 1
    while n < min(available, f.size) and f[n] < (1.0 + CLOSE_GAP) * f[n - 1]:
        n += 1
    return int(min(max(n, 1), available))


@dataclass(frozen=True)
class ModalLayout:
    """Where the kept values sit: circular frequency and channel of each, the damping and the mode count.

    ``omega`` (k,) rad/s and ``channel`` (k,) 0-based, one entry per kept value (the run's cells,
    frequency-major); ``n_channels`` the channels of the participations; ``damping`` (a, b) of
    ``C = a M + b K``; ``n_modes`` the modes emulated. Outputs, shape (..., n_outputs) with
    ``n_outputs = n_modes + n_modes * n_channels + 2 k``: ``w_r^2``, then ``P`` mode-major, then the
    real and the imaginary parts of the remainder at the kept values.
    """

    omega: np.ndarray
    channel: np.ndarray
    n_channels: int
    damping: tuple[float, float]
    n_modes: int

    @property
    def n_modal(self) -> int:
        """The leading outputs that describe the modes (``w_r^2`` and ``P``); the remainder's follow."""
        return self.n_modes * (1 + self.n_channels)

    @property
    def n_outputs(self) -> int:
        return self.n_modal + 2 * len(self.omega)

    def terms(self, omega2: np.ndarray, participation: np.ndarray) -> np.ndarray:
        """The n modes' part of the receptance at the kept values: (..., n), (..., n, n_channels) -> (..., k)."""
        a, b = self.damping
        w = np.asarray(self.omega, float)
        w2 = np.asarray(omega2, float)[..., None, :]  # (..., 1, n)
        den = w2 - w[:, None] ** 2 + 1j * w[:, None] * (a + b * w2)  # (..., k, n)
        P = np.swapaxes(np.asarray(participation, float), -1, -2)[..., self.channel, :]  # (..., k, n)
        return np.sum(P / den, axis=-1)

    def outputs(self, omega2: np.ndarray, participation: np.ndarray, Z: np.ndarray) -> np.ndarray:
        """Emulated outputs of FE runs: ``omega2`` (..., n), ``participation`` (..., n, n_channels) and the
        receptance ``Z`` (..., k) complex at the kept values -> (..., n_outputs) real."""
        omega2, participation = np.asarray(omega2, float), np.asarray(participation, float)
        R = np.asarray(Z, complex) - self.terms(omega2, participation)
        lead = omega2.shape[:-1]
        return np.concatenate([omega2, participation.reshape(lead + (-1,)), R.real, R.imag], axis=-1)

    def receptance(self, Y: np.ndarray) -> np.ndarray:
        """The receptance at the kept values of emulated outputs: (..., n_outputs) -> (..., k) complex."""
        Y = np.asarray(Y, float)
        if Y.shape[-1] != self.n_outputs:
            raise ValueError(f"expected {self.n_outputs} outputs per row ({self.n_modes} modes, {self.n_channels} "
                             f"channels, {len(self.omega)} values), got {Y.shape[-1]}")
        n, c, k = self.n_modes, self.n_channels, len(self.omega)
        omega2 = Y[..., :n]
        P = Y[..., n:n + n * c].reshape(Y.shape[:-1] + (n, c))
        R = Y[..., n + n * c:n + n * c + k] + 1j * Y[..., n + n * c + k:]
        return self.terms(omega2, P) + R
