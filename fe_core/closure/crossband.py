"""Does an effect carry over to the lines it was not fitted on? The closure's check of an effect against the model's
own error.

An effect the structure carries (a mass, a mount) changes the response over the whole band in the way its physics
says: fitted on the lower half of the lines, it also improves the prediction of the upper half, and the other way
round. An effect fitted to the model's own error (a coarse mesh a little too stiff in its higher modes, a
parametrisation too coarse for the stiffness's real distribution) takes out a part of that misfit where it was
fitted and has nothing to say elsewhere: on the three-plate benchmark fitted to a mesh twice as fine carrying a
0.12 kg mass, a spring of 3.7e4 N/m to the ground and a segment mass factor of -0.26 each take out more than half
of the misfit left after the mass and stand out by the extended BIC, yet the segment mass fitted on the lower lines
is +0.42 and on the upper lines -0.33, and either effect fitted on one half predicts the other half worse than the
mass alone (``tests/fe_core/test_crossband.py``).

:func:`carries_over` is that cross-validation: alpha and the effects refitted on one half of the lines (split at
the median frequency) with and without the effect, each prediction of the other half weighed by the noise; the
effect carries over when it improves both predictions. No threshold is set: an effect that makes the unseen half
worse is not supported by the data, whatever it does on the half it was fitted on.

The refits on a half are one Gauss-Newton step from the fit on all lines, with the exact Jacobian
(:func:`fe_core.closure.jacobian.extended_log_jacobian`; the step's least squares in columns scaled to unit norm,
directions the half does not determine left alone): the effects the check is for are small (an effect that
carries the structure is not in doubt), so one step is the refit, and the check costs two Jacobians (about two FRF
solves) where full refits on each half cost hundreds.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .effects import Applied
from .jacobian import extended_log_jacobian

__all__ = ["carries_over", "half_step", "weighed", "MIN_LINES"]

#: Fewest lines on each side of the split for the check to be made (fewer cannot fix the model's factors).
MIN_LINES = 4


def weighed(model, freqs, amplitude, alpha, applied, sigma) -> tuple[np.ndarray, np.ndarray]:
    """``(Jw, r)``: the log-amplitude Jacobian of alpha and the effects' values and the residual, both over the noise
    ``sigma``; rows frequency-major, channels fastest."""
    J, Z = extended_log_jacobian(model, alpha, freqs, applied)
    return J / sigma.reshape(-1)[:, None], (np.log(np.abs(Z) / amplitude) / sigma).reshape(-1)


def half_step(Jw: np.ndarray, r: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(step, norms)``: the Gauss-Newton step fitted on ``rows`` alone, in columns scaled to unit norm there
    (``norms``; directions those rows do not determine left alone): the parameters move by ``step / norms``."""
    norms = np.linalg.norm(Jw[rows], axis=0)
    norms[norms == 0] = 1.0
    step, *_ = np.linalg.lstsq(Jw[rows] / norms, -r[rows], rcond=1e-10)
    return step, norms


def _predicted(model, freqs, amplitude, alpha, applied, sigma, splits) -> list[float]:
    """For each ``train`` of ``splits``: the weighed sum of squares on the other lines after one Gauss-Newton step
    fitted on ``train`` (one Jacobian for all the splits: the point is the same)."""
    Jw, r = weighed(model, freqs, amplitude, alpha, applied, sigma)
    out = []
    for train in splits:
        rows = np.repeat(train, amplitude.shape[1])  # rows frequency-major, channels fastest
        step, norms = half_step(Jw, r, rows)
        out.append(float(np.sum((r[~rows] + (Jw[~rows] / norms) @ step) ** 2)))
    return out


def carries_over(model, freqs_hz, amplitude, alpha, applied: Sequence[Applied], j: int, noise=None) -> tuple[bool, str]:
    """``(carries, note)``: whether effect ``j`` of ``applied`` (with alpha, a fit on all lines) improves the
    prediction of each half of the lines when fitted, with alpha and the other effects, on the other half only.

    ``noise``: a level or per-value levels (shape of ``amplitude``) that weigh the residual; None weighs every value
    alike. With fewer than :data:`MIN_LINES` lines on a side the check is not made (carries)."""
    f = np.asarray(freqs_hz, float)
    u = np.asarray(amplitude, float)
    sigma = np.ones_like(u) if noise is None else np.broadcast_to(np.asarray(noise, float), u.shape)
    low = f <= np.median(f)
    if min(int(low.sum()), int((~low).sum())) < MIN_LINES:
        return True, "too few lines to split"
    applied = list(applied)
    others = applied[:j] + applied[j + 1:]
    splits = (low, ~low)
    gains = list(zip(_predicted(model, f, u, alpha, others, sigma, splits),
                     _predicted(model, f, u, alpha, applied, sigma, splits)))
    carries = all(w < wo for wo, w in gains)
    (up_wo, up_w), (lo_wo, lo_w) = gains
    note = (f"fitted on the lower lines, the upper's weighed sum of squares {up_wo:.4g} without it, {up_w:.4g} with "
            f"it; fitted on the upper lines, the lower's {lo_wo:.4g} and {lo_w:.4g}")
    return carries, note
