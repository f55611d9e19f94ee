"""The paper loop's emulation by default (``emulate = "modes"``): the MRGP learns the modes of the FE runs.

Each FE run gives its lowest modes (squared frequencies and the participation of every measured channel,
:class:`mrgp_core.modal_outputs.ModalLayout`) and the rest of its receptance; the MRGP (one length scale per
parameter, no Table 1 ``l~`` bound) emulates those outputs, a candidate's overall error (Eq. 6b) is that of
the receptance its emulated modes give (a composite objective), and Gauss-Newton end points on the
emulator's mean from the best FE runs and the best candidates join the candidates.

Why: the paper's loop on the benchmark, measured at 31854ac (git show 0cbca1f:docs/update-results.md). With many outputs (``outputs`` reduced) the
modes get an MRGP of their own (:func:`separate_modes`).
"""

from __future__ import annotations

import numpy as np

import mrgp_core

from mrgp_core.modal_outputs import ModalLayout
from .emulation import merge_duplicates, reduced_outputs, refine_on_emulator

__all__ = ["GN_STARTS", "BLOCK_BYTES", "separate_modes", "Emulator", "predict"]

#: Gauss-Newton runs on the emulator's mean per predict stage: from this many best FE samples and as many
#: best candidates.
GN_STARTS = 5

#: Bytes of working memory per block of candidates scored on the emulator (the receptance of each candidate
#: at every kept value, mode by mode, is built at once).
BLOCK_BYTES = 2e8


def separate_modes(outputs: str, layout: ModalLayout) -> bool:
    """Whether the modes get an MRGP of their own: when ``outputs`` puts all the outputs in a reduced basis,
    a basis of the standardised outputs would spend itself on the far more numerous remainder values and
    lose the modes (measured on the hammer data: 28 modal of 18,162 outputs, frequencies off by 36-187 Hz
    after projection). The modes then have a full MRGP (reduced only above
    :data:`.emulation.AUTO_REDUCED_ABOVE` of them), which the train stage fits; the remainder a reduced one
    at the same hyper-parameters."""
    return reduced_outputs(outputs, layout.n_outputs)


class Emulator:
    """The emulated outputs' mean at candidates, from stored hyper-parameters (see :func:`separate_modes`)."""

    def __init__(self, X: np.ndarray, Y: np.ndarray, layout: ModalLayout, hyper, separate: bool):
        X, Y = merge_duplicates(X, Y)
        n = layout.n_modal
        if separate:
            modes = mrgp_core.condition_reduced if reduced_outputs("auto", n) else mrgp_core.condition
            self.parts = [modes(X, Y[:, :n], hyper), mrgp_core.condition_reduced(X, Y[:, n:], hyper)]
        else:
            self.parts = [mrgp_core.condition(X, Y, hyper)]

    def mean(self, points: np.ndarray) -> np.ndarray:
        points = np.atleast_2d(points)
        return np.hstack([part.predict(points, return_var=False)[0] for part in self.parts])


def predict(X: np.ndarray, Y: np.ndarray, E: np.ndarray, layout: ModalLayout, hyper, C: np.ndarray, residual,
            low: np.ndarray, high: np.ndarray, separate: bool) -> tuple[np.ndarray, np.ndarray]:
    """(candidates, predicted overall errors): ``C`` (w, m) and the Gauss-Newton end points on the emulator's
    mean appended; errors of the receptance the emulated modes give (Eq. 6b).

    ``X`` (r, m), ``Y`` (r, n_outputs), ``E`` (r,): the FE runs, their emulated outputs and overall errors;
    ``hyper``: :class:`mrgp_core.Hyperparameters`; ``residual``: the run's residual of the receptance at the
    kept values (:class:`fe_core.inference.frf_data.FRFData`, called on the receptance); ``low``, ``high``: the box of the
    Gauss-Newton runs.
    """
    best = X[np.argsort(E, kind="stable")[:GN_STARTS]]
    emulator = Emulator(X, Y, layout, hyper, separate)
    block = max(1, int(BLOCK_BYTES // (40 * len(layout.omega) * layout.n_modes + 16 * layout.n_outputs)))

    def residuals(points):
        r = residual(layout.receptance(emulator.mean(points)))
        return np.where(np.isfinite(r), r, 1e3)

    def errors(points):
        points = np.atleast_2d(points)
        return np.concatenate([np.mean(np.abs(residuals(points[i:i + block])), axis=1)
                               for i in range(0, len(points), block)])

    predicted = errors(C)
    starts = np.vstack([best, C[np.argsort(predicted, kind="stable")[:GN_STARTS]]])
    refined = refine_on_emulator(residuals, starts, low, high, tolerance=1e-14)
    return np.vstack([C, refined]), np.concatenate([predicted, errors(refined)])
