"""The MRGP as the paper loop's emulator: fit, predict, and search on its mean.

* :func:`train_mrgp`: the hyper-parameters of the MRGP on the FE runs so far (Table 1's ``l~`` bound for
  the paper's trainers), full or in a reduced output basis (:func:`reduced_outputs`);
* :func:`predict_overall_error`: the predicted overall error (Eq. 6b) of candidates from stored
  hyper-parameters (the paper's emulation of the residuals);
* :func:`merge_duplicates`: one row per distinct input, so the likelihood stays well posed;
* :func:`refine_on_emulator`: Gauss-Newton end points on an emulator's mean.

The modal emulation (the modes of each FE run and the rest of its receptance) is :mod:`.modal_emulation`.
"""

from __future__ import annotations

import logging

import numpy as np

import mrgp_core

__all__ = ["train_mrgp", "predict_overall_error", "reduced_outputs", "AUTO_REDUCED_ABOVE", "merge_duplicates",
           "DUPLICATE_RTOL", "forward_difference_jacobian", "length_scales",
           "refine_on_emulator"]

log = logging.getLogger(__name__)


def train_mrgp(X: np.ndarray, Y: np.ndarray, trainer: str, rng: np.random.Generator,
               previous: dict | None, outputs: str = "full", kernel: str = "iso") -> tuple[dict, dict]:
    """Fit the MRGP's hyper-parameters; returns (hyper-parameters, diagnostics).

    For the paper's trainers (``sao``, ``pso``) the squared length scale is
    bounded above by the previous iteration's optimum, Table 1's ``l~``; the
    gradient trainer searches the default bounds every time.

    ``outputs`` (``full``, ``reduced`` or ``auto``, see :func:`reduced_outputs`)
    picks the full MRGP or the one in a reduced output basis
    (:mod:`mrgp_core.reduced`); the diagnostics then say which (``outputs``)
    and, for the reduced one, its rank ``components`` and ``captured`` variance.
    """
    X, Y = merge_duplicates(X, Y)
    l_upper = None
    if previous is not None and trainer in ("sao", "pso"):
        l_upper = length_scales(previous)
        l_upper = float(l_upper[0]) if l_upper.size == 1 else l_upper
    reduced = reduced_outputs(outputs, Y.shape[1])
    fit = mrgp_core.fit_reduced if reduced else mrgp_core.fit
    model = fit(X, Y, trainer, rng=rng, l_upper=l_upper, kernel=kernel)
    h = model.hyperparameters
    hyper = {f"length_scale_{i + 1}": float(v) for i, v in enumerate(np.atleast_1d(h.length_scale))}
    hyper["nugget"] = float(h.nugget)
    info = {"log_likelihood": float(model.log_likelihood), "evaluations": int(model.training.result.nfev),
            "l_upper": None if l_upper is None else np.atleast_1d(l_upper).tolist(),
            **_outputs_info(model, reduced)}
    return hyper, info


def predict_overall_error(X: np.ndarray, Y: np.ndarray, hyper: dict, C: np.ndarray,
                          outputs: str = "full") -> np.ndarray:
    """Predicted overall error (Eq. 6b) of each candidate, shape (w,), from stored hyper-parameters.

    With reduced outputs the basis is rebuilt from the same training data
    (deterministic), so a resumed or rerun stage predicts what the original did.
    """
    h = mrgp_core.Hyperparameters(length_scale=length_scales(hyper), nugget=float(hyper["nugget"]))
    X, Y = merge_duplicates(X, Y)
    condition = mrgp_core.condition_reduced if reduced_outputs(outputs, Y.shape[1]) else mrgp_core.condition
    return condition(X, Y, h).predicted_overall_error(C)


# -- output model: full MRGP or reduced output basis (config key ``outputs``) ----------------------
#: ``outputs = "auto"`` uses the reduced output basis above this many responses k. Up to it the full
#: MRGP (the paper's method) is affordable and stays: one likelihood evaluation scales as k^3, 4.5 s at
#: k = 1,998 (docs/results/many-responses.md), so about 5 ms at k = 200 against 0.07 s at k = 500 and 0.8 GB
#: for Q at k = 10,000. The benchmark (k = 72) keeps the full MRGP. "k > n" is not a criterion: the
#: benchmark's k = 72 exceeds n = 20 in every first iteration and the full MRGP handles it.
AUTO_REDUCED_ABOVE = 200


def reduced_outputs(outputs: str, k: int) -> bool:
    """Whether ``outputs`` (``full``, ``reduced`` or ``auto``) means the reduced basis for k responses."""
    if outputs not in ("full", "reduced", "auto"):
        raise ValueError(f"outputs must be 'full', 'reduced' or 'auto', got {outputs!r}")
    return outputs == "reduced" or (outputs == "auto" and k > AUTO_REDUCED_ABOVE)


def _outputs_info(model, reduced: bool) -> dict:
    """Stage-record entries naming the output model; rank and captured variance for the reduced one."""
    if not reduced:
        return {"outputs": "full"}
    return {"outputs": "reduced", "components": int(model.n_components),
            "captured": float(model.outputs.captured), "n_responses": int(model.n_responses)}


#: Samples closer than this (max-norm, relative to the largest spread of a parameter) are one input.
DUPLICATE_RTOL = 1e-6


def merge_duplicates(X: np.ndarray, Y: np.ndarray, rtol: float = DUPLICATE_RTOL) -> tuple[np.ndarray, np.ndarray]:
    """Merge (nearly) duplicated inputs into one row with the mean of their responses.

    Two FE runs at the same parameters make the MRGP's correlation matrix
    Sigma singular up to its jitter; the profile likelihood then rewards
    vanishing length scales (measured: the gradient trainer's length scale
    falls from 0.5 to 2e-8 with five duplicates 1e-12 apart) and the
    emulator degrades to its linear trend. One row per distinct input keeps
    the information and the likelihood well posed.
    """
    X, Y = np.asarray(X, float), np.asarray(Y, float)
    if len(X) < 2:
        return X, Y
    tol = rtol * max(float(np.ptp(X, axis=0).max()), 1e-300)
    group = np.full(len(X), -1)
    n = 0
    for i in range(len(X)):  # r is a few hundred at most: the quadratic scan is cheap
        if group[i] >= 0:
            continue
        close = (group < 0) & (np.max(np.abs(X - X[i]), axis=1) <= tol)
        group[close] = n
        n += 1
    if n == len(X):
        return X, Y
    log.warning("%d FE samples duplicate others (within %.1g); merged into %d distinct inputs for the MRGP",
                      len(X) - n, tol, n)
    counts = np.bincount(group, minlength=n)[:, None]
    Xm = np.zeros((n, X.shape[1]))
    Ym = np.zeros((n, Y.shape[1]))
    np.add.at(Xm, group, X)
    np.add.at(Ym, group, Y)
    return Xm / counts, Ym / counts


def length_scales(hyper: dict) -> np.ndarray:
    """``length_scale_1 .. length_scale_d`` of a stored hyper-parameter record, in input order."""
    keys = sorted((k for k in hyper if k.startswith("length_scale_")), key=lambda k: int(k.rsplit("_", 1)[1]))
    return np.array([hyper[k] for k in keys], dtype=float)


def refine_on_emulator(residuals_of, starts: np.ndarray, low: np.ndarray, high: np.ndarray,
                       max_evaluations: int = 50, tolerance: float = 1e-8) -> np.ndarray:
    """Gauss-Newton (trust-region least squares) on the emulator's mean from each start, inside [low, high].

    ``residuals_of(X)`` gives the residual vectors the emulator predicts at the points X (k, m), shape (k, p).
    Returns the end points, shape (len(starts), m): candidates where the emulator's mean is smallest.
    ``tolerance``: scipy's ``ftol``, ``xtol`` and ``gtol``; near machine precision the runs end on
    ``max_evaluations`` or at a stationary point, so an end point moves continuously with the data (a loose
    test that stops one step earlier for a change in the last digits moves it by a whole step).

    The Jacobian is scipy's forward difference (relative step 1e-6, turned back at the bounds) evaluated in
    one call of ``residuals_of`` on the point and its m steps, not m + 1 calls: the emulator's cost is in
    its per-call work, so a Jacobian costs about one evaluation.
    """
    from scipy.optimize import least_squares

    def residual(x):
        return residuals_of(x[None])[0]

    def jacobian(x):
        return forward_difference_jacobian(residuals_of, x, low, high)

    out = []
    for x0 in np.asarray(starts, float):
        sol = least_squares(residual, np.clip(x0, low, high), jac=jacobian, bounds=(low, high), method="trf",
                            max_nfev=max_evaluations, ftol=tolerance, xtol=tolerance, gtol=tolerance)
        out.append(sol.x)
    return np.array(out).reshape(-1, len(low))


def forward_difference_jacobian(residuals_of, x: np.ndarray, low: np.ndarray, high: np.ndarray,
                                relative_step: float = 1e-6) -> np.ndarray:
    """Forward-difference Jacobian (p, m) of the batched ``residuals_of`` at x, from one call on m + 1 points.

    The steps are scipy's for ``least_squares(..., diff_step=relative_step)``: relative to |x_i| (the square
    root of machine epsilon times max(1, |x_i|) where that step vanishes), reversed where it would leave
    [low, high], and shortened to the bound where neither direction fits.
    """
    x = np.asarray(x, float)
    sign = np.where(x >= 0, 1.0, -1.0)
    step = relative_step * sign * np.abs(x)
    step = np.where((x + step) - x == 0, np.sqrt(np.finfo(float).eps) * sign * np.maximum(1.0, np.abs(x)), step)
    below, above = x - low, high - x
    fits = np.abs(step) <= np.maximum(below, above)
    outside = ((x + step) < low) | ((x + step) > high)
    step = np.where(outside & fits, -step, step)
    step = np.where(~fits, np.where(above >= below, above, -below), step)
    points = np.vstack([x, x + np.diag(step)])
    dx = np.diag(points[1:]) - x
    values = residuals_of(points)
    return ((values[1:] - values[0]) / dx[:, None]).T
