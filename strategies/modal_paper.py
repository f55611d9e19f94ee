"""The paper's adaptive MRGP loop (Zhou & Tang, Table 2) on measured modes.

The loop is :class:`strategies.paper.PaperLoop` itself (ask/tell), with the MRGP emulating the
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
least squares with Nelson Jacobians (:func:`~fe_core.modal_update.fit.fit_modes`, one start), whose end
point gives the Laplace intervals, as the FRF paper loop ends with its polish.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from strategies.base import Outcome
from strategies.paper import PaperLoop, PaperOptions

__all__ = ["noise_threshold", "modal_paper_options", "run_modal_paper"]


def noise_threshold(n_residuals: int, k: float = 2.0) -> float:
    """``mean |r|`` of ``n`` standard normal residuals: its mean plus ``k`` standard deviations."""
    return float(np.sqrt(2 / np.pi) + k * np.sqrt(1 - 2 / np.pi) / np.sqrt(n_residuals))


def modal_paper_options(options: PaperOptions, n_residuals: int) -> PaperOptions:
    """The loop's settings for modal residuals: the MRGP over the residual outputs, stopping at the noise."""
    return replace(options, emulate="errors", conventional=False, threshold=noise_threshold(n_residuals))


def _as_receptance(r: np.ndarray) -> np.ndarray:
    """PaperLoop reads each FE run's output as a complex vector and maps it with ``residual``; a modal run's
    output is its (real) residual vector, and ``residual`` is then its real part."""
    return np.asarray(r, float).astype(complex)


def run_modal_paper(residual, lower, upper, options: PaperOptions, replay=None, on_round=None) -> PaperLoop:
    """Run the paper's loop on ``residual`` (:class:`ModalResidual` with its active modes set).

    ``replay(iteration, points) -> residual rows (b, n) or None``: stored FE runs of an iteration (a resumed
    run reads them back instead of solving); ``on_round(iteration, points, rows)``: called after the FE runs
    of each iteration that was computed. A failed eigen-solve gives a row of NaN (left out by the loop).
    Returns the loop (``best()``, ``history``, ``stop()``).
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    n_res = len(residual.active) * (1 + (0 if residual.sigma_u is None else residual.n_dofs))
    n_swaps = len(residual.swaps)
    loop = PaperLoop(modal_paper_options(options, n_res), lambda Z: np.real(Z), lower, upper, (lower, upper))
    while not loop.stop().stop:
        batch = loop.propose()
        k = loop.iteration + 1
        rows = None if replay is None else replay(k, batch.points)
        if rows is None:
            residual.label = f"paper-{k}"
            rows = np.array([_evaluate(residual, x, n_res) for x in batch.points])
            if on_round is not None:
                on_round(k, batch.points, rows)
        loop.update(batch, [Outcome(_as_receptance(r)) for r in rows])
    residual.label = "fit"
    del residual.swaps[n_swaps:]  # pairings of scattered samples differ by nature: no path to track a swap along
    return loop


def _evaluate(residual, x, n_res: int) -> np.ndarray:
    try:
        r = residual.evaluate(x, jacobian=False)["r"]
    except (np.linalg.LinAlgError, RuntimeError, ValueError):
        return np.full(n_res, np.nan)
    return r if r.size == n_res else np.full(n_res, np.nan)
