"""The paper's adaptive MRGP loop (Zhou & Tang, Table 2) on measured modes.

The loop is :class:`strategies.paper.PaperLoop` itself (ask/tell, run by the one driver, ``tasks/driver.py``,
from ``tasks/modal_stages.py``), with the MRGP emulating the
*residual* outputs (``emulate = "errors"``, the paper's choice): each FE run is an eigen-solve whose output
vector is the modal residual of :class:`~fe_core.modal_update.residual.ModalResidual` (paired frequencies
``(f_s - f_r)/(sigma_f f_r)`` and the scale-free shape terms ``(u_r - P_s u_r)/sigma_u``, |.|^2 = 1 - MAC),
so the MRGP (separable ``Q x Sigma``; a reduced output basis above
:data:`strategies.emulation.AUTO_REDUCED_ABOVE` outputs) predicts every residual entry of the
candidates and their overall error ``mean |r|`` (Eq. 6b), and the loop samples, predicts, selects and
narrows as on FRFs.

Stopping "at the noise": the residual is divided by the measurement's standard deviations, so at the
truth its entries are standard normal and ``mean |r|`` has mean ``sqrt(2/pi)`` and standard deviation
``sqrt(1 - 2/pi)/sqrt(n)``; the loop stops when an FE run's ``mean |r|`` is within two of those standard
deviations of ``sqrt(2/pi)`` (:func:`noise_threshold`). The best FE run is then polished by the local
least squares with Nelson Jacobians (:class:`strategies.modal_fit.ModalFitStrategy`, one start, under the
same driver), whose end point gives the Laplace intervals, as the FRF paper loop ends with its polish.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from strategies.base import Outcome
from strategies.paper import PaperLoop, PaperOptions

__all__ = ["noise_threshold", "modal_paper_options", "n_residuals", "paper_loop", "evaluate_row"]


def noise_threshold(n_residuals: int, k: float = 2.0) -> float:
    """``mean |r|`` of ``n`` standard normal residuals: its mean plus ``k`` standard deviations."""
    return float(np.sqrt(2 / np.pi) + k * np.sqrt(1 - 2 / np.pi) / np.sqrt(n_residuals))


def modal_paper_options(options: PaperOptions, n_residuals: int) -> PaperOptions:
    """The loop's settings for modal residuals: the MRGP over the residual outputs, stopping at the noise."""
    return replace(options, emulate="errors", conventional=False, threshold=noise_threshold(n_residuals))


def n_residuals(residual) -> int:
    """Entries of the modal residual of ``residual``'s active modes (frequencies, and shapes when stated)."""
    return len(residual.active) * (1 + (0 if residual.sigma_u is None else residual.n_dofs))


def paper_loop(residual, lower, upper, options: PaperOptions, memo=None) -> PaperLoop:
    """The paper's loop on ``residual`` (:class:`ModalResidual` with its active modes set): each FE run's outcome
    is its residual row (as a complex vector, ``residual`` of the loop its real part, :func:`evaluate_row`); the
    steps go to ``memo``. The driver runs it (``tasks/modal_stages.py``)."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    return PaperLoop(modal_paper_options(options, n_residuals(residual)), np.real, lower, upper, (lower, upper),
                     memo=memo)


def evaluate_row(residual, x, n_res: int) -> Outcome:
    """One FE run (an eigen-solve) of the loop: its residual row as the outcome's ``Z``; a failed eigen-solve
    gives a row of NaN (left out by the loop)."""
    try:
        r = residual.evaluate(x, jacobian=False)["r"]
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        r = np.full(n_res, np.nan)
    r = r if r.size == n_res else np.full(n_res, np.nan)
    return Outcome(np.asarray(r, float).astype(complex))
