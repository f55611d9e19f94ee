"""Local least squares on the modal residual from several starts, and Laplace intervals.

Each start runs a trust-region least squares (``scipy.optimize.least_squares``, ``trf`` within the box)
with the exact Jacobian of :class:`~fe_core.modal_update.residual.ModalResidual` (a Gauss-Newton step in
a trust region); the best end point is kept. Starts: the nominal model, then points of a Latin
hypercube in the inner half of the box (seeded; the far corners of a wide box give modes too unlike the
measured ones to pair).

Intervals (Laplace): the covariance ``s^2 (J^T J)^-1`` at the optimum, the residual being already
divided by the standard deviations; ``s^2 = 1`` when the uncertainties are stated, else
``s^2 = chi^2 / (n_res - n_par)`` estimated from the residual (as the FRF update does without ``--noise``);
95 % intervals ``theta +- 1.96 sd``. The measured modes used are those the residual paired at the nominal
model (:meth:`~fe_core.modal_update.residual.ModalResidual.set_active`), kept through the fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ModalFit", "fit_modes", "fit_starts", "fit_from_starts", "laplace_intervals"]

Z95 = 1.959963984540054


@dataclass
class ModalFit:
    theta: np.ndarray
    cost: float
    chi2: float
    n_residuals: int
    starts: list = field(default_factory=list)
    n_fe_runs: int = 0
    n_jacobians: int = 0
    covariance: np.ndarray | None = None
    sd: np.ndarray | None = None
    lower95: np.ndarray | None = None
    upper95: np.ndarray | None = None
    scale2: float = 1.0
    final: dict | None = None


def laplace_intervals(J: np.ndarray, r: np.ndarray, theta: np.ndarray, stated: bool) -> dict:
    """Covariance, standard deviations and 95 % intervals from the Jacobian of the weighted residual."""
    n, p = J.shape
    chi2 = float(r @ r)
    scale2 = 1.0 if stated else chi2 / max(n - p, 1)
    cov = scale2 * np.linalg.pinv(J.T @ J)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return {"covariance": cov, "sd": sd, "lower95": theta - Z95 * sd, "upper95": theta + Z95 * sd,
            "scale2": scale2, "chi2": chi2}


def fit_starts(lower, upper, n_starts: int = 3, seed: int = 0, x0=None) -> list[np.ndarray]:
    """The fit's starts (module docstring): ``x0`` (default the nominal model) inside the box, then
    ``n_starts - 1`` Latin points of the box's inner half (seeded)."""
    from scipy.stats import qmc

    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    p = lower.size
    first = np.zeros(p) if x0 is None else np.asarray(x0, float)  # the nominal model, or a given start
    starts = [np.clip(first, lower + 1e-9, upper - 1e-9)]
    if n_starts > 1:
        unit = qmc.LatinHypercube(d=p, seed=seed).random(n_starts - 1)
        # the inner half of the box: far corners of a wide box make modes too unlike the measured ones to pair
        mid, half = 0.5 * (lower + upper), 0.25 * (upper - lower)
        starts += [mid - half + 2 * half * u for u in unit]
    return starts


def fit_from_starts(evaluate, starts, lower, upper, stated: bool = True, max_nfev: int = 50) -> ModalFit:
    """The fit's procedure on any evaluation of the residual (module docstring).

    Parameters
    ----------
    evaluate : callable
        ``evaluate(x, jacobian, start) -> (r, J)``: the weighted residual (n,) at ``x`` (p,) and, when
        ``jacobian``, its Jacobian (n, p) (else None); ``start`` is the start asking (1, 2, ...; the final
        evaluation at the best end point is the last start's). Called in a deterministic order: the same
        results give the same calls.
    starts : list of ndarray, shape (p,)
        :func:`fit_starts`.
    lower, upper : ndarray, shape (p,)
    stated, max_nfev
        As in :func:`fit_modes`.

    Returns
    -------
    ModalFit
        Without the counts of FE runs and Jacobians (the caller's) and ``final`` (None).
    """
    from scipy.optimize import least_squares

    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    best, record = None, []
    for k, x0 in enumerate(starts, 1):
        def fun(x, k=k):
            return evaluate(x, False, k)[0]

        def jac(x, k=k):
            return evaluate(x, True, k)[1]

        sol = least_squares(fun, x0, jac=jac, bounds=(lower, upper), method="trf", x_scale="jac",
                            max_nfev=max_nfev, xtol=1e-8, ftol=1e-10, gtol=1e-8)
        record.append({"start": x0.tolist(), "end": sol.x.tolist(), "cost": float(2 * sol.cost),
                       "nfev": int(sol.nfev), "status": int(sol.status)})
        if best is None or sol.cost < best.cost:
            best = sol
    r, J = evaluate(best.x, True, len(starts))
    iv = laplace_intervals(J, r, best.x, stated)
    return ModalFit(theta=best.x, cost=float(2 * best.cost), chi2=iv["chi2"], n_residuals=r.size, starts=record,
                    covariance=iv["covariance"], sd=iv["sd"], lower95=iv["lower95"], upper95=iv["upper95"],
                    scale2=iv["scale2"])


def fit_modes(residual, lower, upper, n_starts: int = 3, seed: int = 0, stated: bool = True,
              max_nfev: int = 50, x0=None) -> ModalFit:
    """Fit the model's parameters to measured modes (see the module docstring) by calling ``residual``
    directly; ``x0``: the first start (default the nominal model).

    The modal update's own fit is the same procedure as an ask-tell strategy under the run's driver
    (:mod:`strategies.modal_fit`, its evaluations stored in the run folder); this direct call serves the
    closure's joint fits (:mod:`.closure`, inside one stage) and the tests and benchmarks of this package."""
    def evaluate(x, jacobian, start):
        out = residual.evaluate(x, jacobian=jacobian)
        return out["r"], out["J"]

    fit = fit_from_starts(evaluate, fit_starts(lower, upper, n_starts, seed, x0), lower, upper, stated, max_nfev)
    fit.final = residual.evaluate(fit.theta)  # the last evaluation, kept by the residual: no FE run
    fit.n_fe_runs, fit.n_jacobians = residual.n_evaluations, residual.n_jacobians
    return fit
