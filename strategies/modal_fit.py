"""The modal update's Gauss-Newton fit as an ask-tell strategy, run by the one driver.

The fit is :func:`fe_core.modal_update.fit.fit_from_starts` (``scipy.optimize.least_squares``, ``trf`` within
the box, with the exact Nelson Jacobian of :class:`~fe_core.modal_update.residual.ModalResidual`, from the starts
of :func:`~fe_core.modal_update.fit.fit_starts`, then one evaluation with the Jacobian at the best end point for
the Laplace intervals). :class:`ModalFitStrategy` runs that procedure as it is in a worker thread
(:class:`.callback.CallbackStrategy`): each call scipy makes of ``fun(x)`` or ``jac(x)``, and the final
evaluation, is a :class:`~.base.Batch` of one point (``jacobian`` True for ``jac`` and the final one), in the
stage ``start-<k>`` of the start asking (the final evaluation with the last start). The caller answers with an
:class:`~.base.Outcome` whose ``Z`` is the weighted residual vector (n,) (real) and ``dZ`` its Jacobian (n, p)
when asked.

So the strategy gives exactly what :func:`~fe_core.modal_update.fit.fit_modes` gives on the same residual (the
same points asked in the same order, the same end point, the same FE runs and Jacobians: the residual's own
cache decides which evaluations cost an eigen-solve, as in the direct call). In memory it runs through
:func:`.base.run_loop` with :func:`residual_evaluations`; in the modal flow (``tasks/modal_fit.py``) under the
driver, each start's evaluations a stage of the run folder (``fit-start-<k>``), replayed on resume.

It is not in the registry: the registry's strategies work on an FRF problem (:class:`.base.Context`) and are
the FRF update's ``--strategy`` choices; the modal fit is the modal update's own (``flows/modal_update.py``),
as the modal paper loop is (:mod:`.modal_paper`).
"""

from __future__ import annotations

import numpy as np

from fe_core.modal_update.fit import ModalFit, fit_from_starts, fit_starts

from .base import Batch, Evaluate, Outcome, Report
from .callback import CallbackStrategy

__all__ = ["ModalFitStrategy", "residual_evaluations", "stage_of", "LEAST_SQUARES_STATUS"]

#: ``scipy.optimize.least_squares``'s ``status`` of the kept start, in words (``stop_reason``); > 0: converged.
LEAST_SQUARES_STATUS = {-1: "improper input", 0: "the FE-run budget of the start (max_nfev) spent",
                        1: "gradient tolerance met", 2: "cost tolerance met", 3: "step tolerance met",
                        4: "cost and step tolerances met"}


def stage_of(start: int) -> str:
    """The stage of a start's evaluations (1, 2, ...)."""
    return f"start-{start}"


class ModalFitStrategy(CallbackStrategy):
    """The modal Gauss-Newton fit, ask-tell (module docstring).

    Parameters
    ----------
    lower, upper : ndarray, shape (p,)
        The box.
    n_starts, seed, x0 : as :func:`~fe_core.modal_update.fit.fit_starts` (the nominal model, or ``x0``, first).
    stated : bool
        The residual's standard deviations are stated (intervals as they are), else scaled by chi^2/(n - p).
    max_nfev : int
        Evaluations of the residual per start at most (scipy's).
    iteration : int
        The iteration the batches name.

    Attributes
    ----------
    result : fe_core.modal_update.fit.ModalFit or None
        The fit once stopped (without the FE-run counts, which the evaluation knows).
    """

    def __init__(self, lower, upper, n_starts: int = 3, seed: int = 0, stated: bool = True, max_nfev: int = 50,
                 x0=None, iteration: int = 1):
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.starts = fit_starts(self.lower, self.upper, n_starts, seed, x0)
        self.stated, self.max_nfev, self.iteration = bool(stated), int(max_nfev), int(iteration)
        super().__init__(self._fit, name="modal fit")

    def _fit(self, ask) -> ModalFit:
        def evaluate(x, jacobian, start):
            batch = Batch(np.array([x], float), (bool(jacobian),), label=f"{stage_of(start)}"
                          f"{' (Jacobian)' if jacobian else ''}", iteration=self.iteration, stage=stage_of(start))
            told = ask(batch)[0]
            r, J = told[0], told[1]
            return np.asarray(r, float), (np.asarray(J, float) if jacobian else None)

        return fit_from_starts(evaluate, self.starts, self.lower, self.upper, self.stated, self.max_nfev)

    def best_start(self) -> dict:
        """The start the fit kept (least cost): its record (start, end, cost, nfev, status)."""
        return min(self.result.starts, key=lambda r: r["cost"])

    def converged(self) -> bool:
        return self.best_start()["status"] > 0

    def reason(self) -> str:
        status = self.best_start()["status"]
        return (f"local least squares from {len(self.starts)} start(s); the best start: "
                f"{LEAST_SQUARES_STATUS.get(status, 'scipy status ' + str(status))}")

    def report(self) -> Report:
        decision = self.stop()
        return Report(decision.reason, decision.converged, iterations=self.iteration, intervals=True)


def residual_evaluations(residual) -> Evaluate:
    """The in-memory evaluation of the strategy's batches on ``residual``
    (:class:`~fe_core.modal_update.residual.ModalResidual`, its active modes set): ``evaluate(batch)`` ->
    one :class:`~.base.Outcome` (r, J or None) per point."""
    def evaluate(batch: Batch) -> list:
        out = []
        for x, jacobian in zip(batch.points, batch.jacobian):
            e = residual.evaluate(x, jacobian=bool(jacobian))
            out.append(Outcome(e["r"], e["J"] if jacobian else None))
        return out

    return evaluate
