"""Response errors of Zhou & Tang: the relative residuals of Eq. (5), the overall error of Eq. (6b), the
per-sensor error of Eq. (15).

Response layout (Eq. 5): for ``n`` sensors and ``p`` frequencies the error vector is frequency-major,
``[du_11 .. du_n1, du_12 .. du_n2, ..., du_np]``, so a (p, n) amplitude array flattens to it with
``reshape(-1)``.

Complex data (beyond the paper): :func:`complex_relative_residuals` gives the real and imaginary parts of
``(Z - H) / |H|``, real parts first; Eq. (6b) applied to that vector is the overall error, and it is Eq. (6b)
itself when only amplitudes are measured (then the vector is the amplitude residuals).
"""

from __future__ import annotations

import numpy as np

__all__ = ["relative_residuals", "complex_relative_residuals", "overall_error", "per_sensor_error"]


def relative_residuals(model_amplitude: np.ndarray, measured_amplitude: np.ndarray) -> np.ndarray:
    """Signed relative residuals ``(|Z_model| - u_meas) / u_meas`` in the layout of Eq. (5).

    Parameters
    ----------
    model_amplitude : ndarray, shape (..., p, n), m/N
        Model amplitudes for one or many samples.
    measured_amplitude : ndarray, shape (p, n), m/N
        Positive measured amplitudes.

    Returns
    -------
    ndarray, shape (..., p * n)
        Frequency-major, sensors fastest.
    """
    model_amplitude = np.asarray(model_amplitude, dtype=float)
    measured_amplitude = np.asarray(measured_amplitude, dtype=float)
    rel = (model_amplitude - measured_amplitude) / measured_amplitude
    return rel.reshape(rel.shape[:-2] + (-1,))


def complex_relative_residuals(model_frf: np.ndarray, measured_frf: np.ndarray) -> np.ndarray:
    """Real and imaginary parts of ``(Z_model - H_meas) / |H_meas|``, real parts first.

    The phase carries what the amplitude drops (the sign of a mode's
    contribution, which side of a resonance a line is on); dividing by
    ``|H_meas|`` keeps the relative weighting of Eq. (5), and the two parts
    are smooth in the parameters where the amplitude residual has a kink.

    Parameters
    ----------
    model_frf : ndarray, shape (..., c), complex
        Model FRF at ``c`` measured values (lines x channels, flattened).
    measured_frf : ndarray, shape (c,), complex, non-zero

    Returns
    -------
    ndarray, shape (..., 2 c)
        ``[Re r_1 .. Re r_c, Im r_1 .. Im r_c]``.
    """
    measured_frf = np.asarray(measured_frf, dtype=complex)
    r = (np.asarray(model_frf, dtype=complex) - measured_frf) / np.abs(measured_frf)
    return np.concatenate([r.real, r.imag], axis=-1)


def overall_error(residuals: np.ndarray) -> np.ndarray:
    """Eq. (6b): mean absolute relative residual, shape (...,) from (..., p * n)."""
    return np.mean(np.abs(residuals), axis=-1)


def per_sensor_error(residuals: np.ndarray, n_sensors: int) -> np.ndarray:
    """Eq. (15): mean absolute relative residual per sensor, shape (..., n) from (..., p * n)."""
    r = np.asarray(residuals)
    return np.mean(np.abs(r.reshape(r.shape[:-1] + (-1, n_sensors))), axis=-2)
