"""95 % intervals and the covariance of a finished closure's extended model (alpha and each effect's value).

Called by :func:`tasks.closure.steps.decide_task` on the final fit of the closure
(:func:`fe_core.closure.intervals.extended_intervals`: Gauss-Newton steps to the
least-squares optimum of the log residual and the Laplace covariance there,
every Jacobian column exact: alpha, each effect parameter, a sensor gain's
analytically). The fields join ``closure.json`` with the names of
``summary.json``'s: ``intervals``, ``covariance``, ``interval_method``,
``noise_sigma``, ``interval_details`` and ``interval_cost``; the parameters
are named as in ``parameters_after``.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from fe_core.closure.intervals import extended_intervals

__all__ = ["closure_interval_fields", "COLUMNS"]

log = logging.getLogger(__name__)

#: How the Jacobian's columns are made (written to closure.json).
COLUMNS = ("exact: d ln|Z| / d theta on one Krylov space for alpha and every structural effect parameter "
           "(fe_core.solvers.sensitivity.extended_log_jacobian), analytic for a sensor gain")


def closure_interval_fields(model, freqs, amplitude, final, names, noise: float | None, alpha_bounds) -> dict:
    """The interval fields of ``closure.json`` for the final fit (a :class:`fe_core.closure.Fit`).

    Parameters
    ----------
    model : ParametricModel
    freqs : ndarray, shape (p,), Hz
    amplitude : ndarray, shape (p, n), m/N
    final : fe_core.closure.Fit
        Alpha and the effects in the order added (``final.applied``).
    names : list of str
        Names of alpha and the effects' parameters, in that order (the keys of
        ``parameters_after``).
    noise : float or None
        The closure's ``--noise``; estimated from the final residual when None.
    alpha_bounds : (float, float)

    Returns
    -------
    dict
        Empty when the intervals cannot be computed (logged): the closure's
        result stands without them.
    """
    t0 = time.perf_counter()
    try:
        refined = extended_intervals(model, freqs, amplitude, final.alpha, final.applied,
                                     alpha_bounds=tuple(alpha_bounds), noise=noise, names=list(names))
    except (ValueError, np.linalg.LinAlgError) as exc:
        log.warning("closure: no parameter intervals: %s", exc)
        return {}
    iv = refined.intervals
    fields = iv.to_summary()
    fields["interval_cost"] = {"jacobians": refined.jacobians, "fe_runs": refined.fe_runs,
                               "seconds": round(time.perf_counter() - t0, 3), "at_optimum": refined.at_optimum,
                               "last_step_in_std": (refined.last_step_in_std if np.isfinite(refined.last_step_in_std)
                                                    else None),
                               "columns": COLUMNS}
    return fields
