"""The fitted multi-response GP: training (``fit``), conditioning and prediction (Eq. 14).

``fit(X, Y, trainer=...)`` standardises the responses, maximises the profile
likelihood of :mod:`mrgp_core.likelihood` over the log hyper-parameters with
the chosen trainer, and returns an :class:`MRGP` conditioned on the data.
``condition(X, Y, hyperparameters)`` does the last step alone, at fixed
hyper-parameters.

Search space of every trainer (log scale, ``theta = [log l..., log g]``):

* ``l`` in ``[l_lower, l_upper]``: Table 1's ``(0, l~]``. ``l_upper`` is the
  ``l~`` the caller passes (the previous iteration's optimum in the adaptive
  loop); by default ``100`` times the squared diameter of the training inputs
  (per input for ARD), where the correlation between the two farthest points is
  still 0.995. The open lower end 0 becomes ``l_lower``, by default 1/100 of
  the smallest non-zero squared distance between training inputs (per input
  for ARD): below it every off-diagonal correlation is under ``e^-50`` and the
  likelihood is flat.
* the second variable is the nugget ratio ``g = sigma_n^2 / sigma_f^2`` in
  ``nugget_bounds`` (when ``nugget="fit"``), replacing Table 1's ``sigma_f in
  [0, 10]``: ``sigma_f`` is not identifiable when ``Q`` is estimated, so the
  model fixes ``sigma_f = 1`` and the amplitude of every response lives in
  ``Q``. With a fixed nugget (``nugget=0.0`` is the paper's noise-free case) the
  trainers search ``l`` alone.
* start (``sao``; the first screened point of ``gradient``; particle 0 of ``pso``):
  ``l = 1`` as in Table 1 (clipped into the box) and ``g = 1e-4``.

Prediction (standardised units, ``L`` the Cholesky factor of Sigma,
``L^-1 H = Q_H R_H``)::

    mean  = H* beta + K*^T alpha                                   (Eq. 14)
    v     = L^-1 K*                          (r, w), triangular solve
    s     = 1 - colsum(v**2) + |R_H^-T (h* - H^T Sigma^-1 K*)|^2   (w,)
    var   = s (x) diag(Q_reg)                                       (w, k)

The last term of ``s`` is the universal-kriging correction for estimating
``beta`` (off with ``mean_uncertainty=False``, which gives Eq. 14 literally).
The w x w posterior covariance is never formed. Means and variances are
returned in the original response units.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_triangular
from scipy.special import ndtr

from .kernels import KERNELS, correlation
from .likelihood import (
    DEFAULT_JITTER,
    Hyperparameters,
    ProfileLikelihood,
    ProfileTerms,
    mean_basis,
    profile,
    standardise,
)
from .optimizers import Result, get_trainer

__all__ = [
    "MRGP",
    "TrainingRecord",
    "fit",
    "condition",
    "default_bounds",
    "predicted_overall_error",
    "CRITERIA",
    "START_LENGTH_SCALE",
    "START_NUGGET",
    "NUGGET_BOUNDS",
]

log = logging.getLogger(__name__)

#: Table 1 start of the annealing (and first gradient start).
START_LENGTH_SCALE = 1.0
START_NUGGET = 1e-4
#: Default search range of the nugget ratio g = sigma_n^2 / sigma_f^2.
NUGGET_BOUNDS = (1e-8, 1.0)
#: Ranking criteria of :func:`predicted_overall_error`.
CRITERIA = ("mean_abs", "expected_abs")
_PREDICT_CHUNK = 20_000


@dataclass(frozen=True)
class TrainingRecord:
    """How the hyper-parameters were obtained.

    Attributes
    ----------
    trainer : str
    result : Result
        The trainer's output (``x`` is ``theta``, ``fun`` the negative log-likelihood).
    bounds : ndarray, shape (n_params, 2)
        The log-scale box searched.
    seconds : float
        Wall time of the search.
    """

    trainer: str
    result: Result
    bounds: np.ndarray
    seconds: float


@dataclass
class MRGP:
    """A multi-response GP conditioned on training data.

    Build it with :func:`fit` or :func:`condition`. Attributes are in
    standardised response units unless stated.

    Attributes
    ----------
    X : ndarray, shape (r, d)
    centre, scale : ndarray, shape (k,)
        Response standardisation: ``Y = centre + scale * Ys``.
    hyperparameters : Hyperparameters
    mean : str
    jitter : float
    terms : ProfileTerms
    training : TrainingRecord or None
    """

    X: np.ndarray
    centre: np.ndarray
    scale: np.ndarray
    hyperparameters: Hyperparameters
    mean: str
    jitter: float
    terms: ProfileTerms
    training: TrainingRecord | None = field(default=None)

    @property
    def n_responses(self) -> int:
        return self.centre.size

    @property
    def log_likelihood(self) -> float:
        """Eq. (10) at the fitted hyper-parameters, standardised units."""
        return self.terms.log_likelihood

    @property
    def Q(self) -> np.ndarray:
        """Regularised response covariance in original units, shape (k, k)."""
        return self.terms.Q_reg * np.outer(self.scale, self.scale)

    @property
    def beta(self) -> np.ndarray:
        """GLS mean coefficients in original units, shape (q, k) (the intercept absorbs ``centre``)."""
        b = self.terms.beta * self.scale
        if self.mean != "zero":
            b[0] += self.centre
        return b

    def predict(
        self,
        Xstar: np.ndarray,
        *,
        return_var: bool = True,
        observation_noise: bool = False,
        mean_uncertainty: bool = True,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Posterior mean and per-response variance at new inputs.

        Parameters
        ----------
        Xstar : ndarray, shape (w, d)
        return_var : bool
            If False the variance is skipped (cheaper) and returned as None.
        observation_noise : bool
            Add the nugget variance (a new noisy observation rather than the
            latent function).
        mean_uncertainty : bool
            Include the variance due to estimating ``beta`` (universal
            kriging). False gives Eq. (14) literally.

        Returns
        -------
        mean : ndarray, shape (w, k), response units
        var : ndarray, shape (w, k), response units squared, or None
        """
        mean, s = self.predict_factors(Xstar, return_var=return_var, observation_noise=observation_noise,
                                       mean_uncertainty=mean_uncertainty)
        if not return_var:
            return mean, None
        return mean, np.outer(s, np.diag(self.terms.Q_reg) * self.scale**2)

    def predict_factors(
        self,
        Xstar: np.ndarray,
        *,
        return_var: bool = True,
        observation_noise: bool = False,
        mean_uncertainty: bool = True,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Posterior mean and the spatial factor ``s`` of the posterior covariance.

        The posterior covariance of the k responses at one input ``x*`` is
        ``s(x*) Q`` (Q in response units, :attr:`Q`), so :meth:`predict`'s
        variance is ``outer(s, diag(Q))``. Callers that need other
        combinations of the responses (:mod:`mrgp_core.reduced`) use ``s``
        and ``Q`` directly. Parameters as :meth:`predict`.

        Returns
        -------
        mean : ndarray, shape (w, k), response units
        s : ndarray, shape (w,), dimensionless, or None
        """
        Xstar = np.asarray(Xstar, dtype=float)
        if Xstar.ndim != 2 or Xstar.shape[1] != self.X.shape[1]:
            raise ValueError(f"Xstar must have shape (w, {self.X.shape[1]}), got {Xstar.shape}")
        w = Xstar.shape[0]
        mean = np.empty((w, self.n_responses))
        s = np.empty(w) if return_var else None
        for a in range(0, w, _PREDICT_CHUNK):
            sl = slice(a, min(a + _PREDICT_CHUNK, w))
            m_c, s_c = self._predict_standardised(Xstar[sl], return_var, observation_noise, mean_uncertainty)
            mean[sl] = m_c
            if return_var:
                s[sl] = s_c
        return self.centre + mean * self.scale, s

    def _predict_standardised(self, Xs, return_var, observation_noise, mean_uncertainty):
        t = self.terms
        hyper = self.hyperparameters
        Ks = correlation(self.X, Xs, hyper.length_scale)  # (r, w)
        Hs = mean_basis(Xs, self.mean)  # (w, q)
        mean = Hs @ t.beta + Ks.T @ t.alpha
        if not return_var:
            return mean, None
        V = solve_triangular(t.chol, Ks, lower=True, check_finite=False)
        s = 1.0 - np.einsum("ij,ij->j", V, V)
        np.maximum(s, 0.0, out=s)
        if mean_uncertainty and Hs.shape[1]:
            # h* - H^T Sigma^-1 k* = h* - (L^-1 H)^T (L^-1 k*) = h* - R_H^T Q_H^T V
            U = Hs.T - t.basis_r.T @ (t.basis_q.T @ V)
            Z = solve_triangular(t.basis_r, U, trans="T", lower=False, check_finite=False)
            s += np.einsum("ij,ij->j", Z, Z)
        if observation_noise:
            s += hyper.nugget
        return mean, s

    def predicted_overall_error(self, Xstar: np.ndarray, criterion: str = "mean_abs") -> np.ndarray:
        """Predicted Eq. (6b) error of each candidate, shape (w,); see :func:`predicted_overall_error`."""
        if criterion not in CRITERIA:
            raise ValueError(f"unknown criterion {criterion!r}; valid criteria are {', '.join(CRITERIA)}")
        mean, var = self.predict(Xstar, return_var=criterion == "expected_abs")
        return predicted_overall_error(mean, var, criterion)


def predicted_overall_error(mean: np.ndarray, var: np.ndarray | None = None, criterion: str = "mean_abs") -> np.ndarray:
    """Predicted overall error (Eq. 6b) of candidates from emulated relative residuals.

    The MRGP emulates signed relative residuals ``e_j = (u_model - u_meas) /
    u_meas``; Eq. (6b) is ``mean_j |e_j|``.

    Parameters
    ----------
    mean : ndarray, shape (w, k)
        Predicted residuals.
    var : ndarray, shape (w, k), optional
        Predictive variances; needed for ``"expected_abs"``.
    criterion : {"mean_abs", "expected_abs"}
        ``"mean_abs"``: ``mean_j |mu_j|`` (plug in the posterior mean).
        ``"expected_abs"``: ``mean_j E|e_j|`` under ``e_j ~ N(mu_j, s_j^2)``,
        ``E|e| = s sqrt(2/pi) exp(-mu^2 / (2 s^2)) + mu (1 - 2 Phi(-mu/s))``,
        which is ``|mu|`` when ``s = 0`` and never smaller than ``|mu|``. It
        is the posterior expectation of the error itself, so it does not
        reward a candidate for a mean that crosses zero by chance where the
        emulator is uncertain.

    Returns
    -------
    ndarray, shape (w,)
    """
    mean = np.asarray(mean, dtype=float)
    if criterion == "mean_abs":
        return np.mean(np.abs(mean), axis=-1)
    if criterion != "expected_abs":
        raise ValueError(f"unknown criterion {criterion!r}; valid criteria are {', '.join(CRITERIA)}")
    if var is None:
        raise ValueError("criterion 'expected_abs' needs the predictive variance")
    sd = np.sqrt(np.maximum(np.asarray(var, dtype=float), 0.0))
    pos = sd > 0
    safe = np.where(pos, sd, 1.0)
    z = mean / safe
    folded = safe * np.sqrt(2.0 / np.pi) * np.exp(-0.5 * z * z) + mean * (1.0 - 2.0 * ndtr(-z))
    return np.mean(np.where(pos, folded, np.abs(mean)), axis=-1)


def _check_data(X, Y) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, dtype=float)
    Y = np.asarray(Y, dtype=float)
    if Y.ndim == 1:
        Y = Y[:, None]
    if X.ndim != 2 or Y.ndim != 2 or X.shape[0] != Y.shape[0] or X.shape[0] < 2:
        raise ValueError(f"X must be (r, d) and Y (r, k) with the same r >= 2, got {X.shape} and {Y.shape}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(Y))):
        raise ValueError("X and Y must be finite")
    return X, Y


def default_bounds(X: np.ndarray, kernel: str = "iso", l_lower=None, l_upper=None) -> tuple[np.ndarray, np.ndarray]:
    """Search box of the squared length scales (Table 1's ``(0, l~]``).

    Parameters
    ----------
    X : ndarray, shape (r, d)
    kernel : {"iso", "ard"}
    l_lower, l_upper : float or array_like, optional
        Override either end (scalar, or one per input for ARD). ``l_upper`` is
        the ``l~`` of Table 1. Defaults: 1/100 of the smallest non-zero squared
        distance, and 100 times the squared diameter of the inputs (per input
        for ARD). A lower end that is not below the upper end is moved to
        ``upper / 1000``.

    Returns
    -------
    low, high : ndarray, shape (1,) or (d,), input units squared
    """
    X = np.asarray(X, dtype=float)
    if kernel not in KERNELS:
        raise ValueError(f"unknown kernel {kernel!r}; valid kernels are {', '.join(KERNELS)}")
    n = 1 if kernel == "iso" else X.shape[1]
    cols = [X] if kernel == "iso" else [X[:, [j]] for j in range(X.shape[1])]
    lo_def, hi_def = np.empty(n), np.empty(n)
    for j, Z in enumerate(cols):
        sq = np.sum((Z[:, None, :] - Z[None, :, :]) ** 2, axis=-1)
        nz = sq[sq > 0]
        span = np.sum(np.ptp(Z, axis=0) ** 2)
        lo_def[j] = nz.min() / 100.0 if nz.size else 1e-6
        hi_def[j] = 100.0 * span if span > 0 else 1.0
    hi = hi_def if l_upper is None else np.broadcast_to(np.asarray(l_upper, float), (n,)).copy()
    lo = lo_def if l_lower is None else np.broadcast_to(np.asarray(l_lower, float), (n,)).copy()
    if np.any(hi <= 0) or not np.all(np.isfinite(hi)) or np.any(lo <= 0) or not np.all(np.isfinite(lo)):
        raise ValueError(f"length-scale bounds must be finite and positive, got lower {lo}, upper {hi}")
    lo = np.where(lo < hi, lo, hi / 1000.0)
    return lo, hi


def condition(
    X: np.ndarray,
    Y: np.ndarray,
    hyperparameters: Hyperparameters,
    *,
    mean: str = "linear",
    shrinkage="auto",
    jitter: float = DEFAULT_JITTER,
    training: TrainingRecord | None = None,
) -> MRGP:
    """Condition the MRGP on data at fixed hyper-parameters (no training).

    Parameters
    ----------
    X : ndarray, shape (r, d)
    Y : ndarray, shape (r, k) or (r,)
        Responses in their own units; standardised internally.
    hyperparameters : Hyperparameters
    mean : {"zero", "constant", "linear"}
        ``"zero"`` is zero mean on the standardised responses, i.e. the column
        means (scikit-learn's ``normalize_y=True``); ``"constant"`` and
        ``"linear"`` are estimated by GLS.
    shrinkage : float in [0, 1] or "auto"
        Regularisation of ``Q^`` (:func:`mrgp_core.likelihood.regularise_q`).
    jitter : float
        Fixed perturbation of Sigma's diagonal.
    training : TrainingRecord, optional
        Stored on the model.

    Returns
    -------
    MRGP
    """
    X, Y = _check_data(X, Y)
    Ys, centre, scale = standardise(Y)
    kernel = hyperparameters.kernel
    nugget = float(hyperparameters.nugget)
    lik = ProfileLikelihood(X, Ys, kernel=kernel, mean=mean, nugget=nugget, shrinkage=shrinkage, jitter=jitter)
    theta = lik.theta(hyperparameters)
    Sigma, _ = lik.sigma(theta)
    terms = profile(Sigma, lik.H, Ys, lik.shrinkage)
    hyper = Hyperparameters(length_scale=np.atleast_1d(np.asarray(hyperparameters.length_scale, float)).copy(), nugget=nugget)
    return MRGP(X=X.copy(), centre=centre, scale=scale, hyperparameters=hyper, mean=mean, jitter=float(jitter),
                terms=terms, training=training)


def fit(
    X: np.ndarray,
    Y: np.ndarray,
    trainer: str = "gradient",
    *,
    rng: np.random.Generator,
    kernel: str = "iso",
    mean: str = "linear",
    nugget="fit",
    shrinkage="auto",
    l_lower=None,
    l_upper=None,
    nugget_bounds: tuple[float, float] = NUGGET_BOUNDS,
    start: Hyperparameters | None = None,
    options: dict | None = None,
    jitter: float = DEFAULT_JITTER,
) -> MRGP:
    """Train the hyper-parameters by maximum profile likelihood and condition on the data.

    Parameters
    ----------
    X : ndarray, shape (r, d)
        Inputs (model parameters), in their own units; not rescaled.
    Y : ndarray, shape (r, k) or (r,)
        Responses; standardised internally (they may span decades).
    trainer : {"gradient", "sao", "pso"}
        See :mod:`mrgp_core.optimizers`.
    rng : numpy.random.Generator
        Randomness of the trainer (required: runs are reproducible).
    kernel : {"iso", "ard"}
        Isotropic squared exponential of Eq. (8), or one length scale per input.
    mean : {"zero", "constant", "linear"}
        ``"linear"`` is the paper's ``H = [1, x]``.
    nugget : "fit" or float >= 0
        Fit the nugget ratio ``g = sigma_n^2 / sigma_f^2`` inside
        ``nugget_bounds``, or fix it (``0.0`` is the paper's noise-free case).
    shrinkage : float in [0, 1] or "auto"
        Regularisation of ``Q^``; see :mod:`mrgp_core.likelihood`.
    l_lower, l_upper : float or array_like, optional
        Bounds of the squared length scale(s); ``l_upper`` is Table 1's ``l~``
        (pass the previous iteration's optimum). See :func:`default_bounds`.
    nugget_bounds : (float, float)
        Range of the fitted nugget ratio.
    start : Hyperparameters, optional
        Start of the search; Table 1's ``l = 1`` and ``g = 1e-4`` by default.
    options : dict, optional
        Trainer options (see each trainer's ``DEFAULTS``).
    jitter : float
        Fixed perturbation of Sigma's diagonal.

    Returns
    -------
    MRGP
        With ``training`` recording the trainer's result and wall time.
    """
    minimize = get_trainer(trainer)
    X, Y = _check_data(X, Y)
    Ys, _, _ = standardise(Y)
    lik = ProfileLikelihood(X, Ys, kernel=kernel, mean=mean, nugget=nugget, shrinkage=shrinkage, jitter=jitter)
    lo, hi = default_bounds(X, kernel, l_lower, l_upper)
    bounds = np.column_stack([np.log(lo), np.log(hi)])
    if lik.fit_nugget:
        g_lo, g_hi = (float(v) for v in nugget_bounds)
        if not 0 < g_lo <= g_hi:
            raise ValueError(f"nugget_bounds must satisfy 0 < low <= high, got {nugget_bounds}")
        bounds = np.vstack([bounds, [np.log(g_lo), np.log(g_hi)]])
    if start is None:
        x0 = np.full(lik.n_length_scales, np.log(START_LENGTH_SCALE))
        if lik.fit_nugget:
            x0 = np.append(x0, np.log(START_NUGGET))
    else:
        x0 = lik.theta(start)
    x0 = np.clip(x0, bounds[:, 0], bounds[:, 1])

    t0 = time.perf_counter()
    result = minimize(lik.negative, bounds, rng, options, x0=x0, value_and_grad=lik.negative_and_grad)
    seconds = time.perf_counter() - t0
    hyper = lik.hyperparameters(result.x)
    at_edge = np.isclose(result.x, bounds[:, 0]) | np.isclose(result.x, bounds[:, 1])
    log.info(
        "MRGP fit (%s, %s kernel, %s mean): r=%d k=%d, l=%s, nugget=%.3g, -lnL=%.6g, %d evaluations, %.3f s%s",
        trainer, kernel, mean, X.shape[0], Y.shape[1], np.array2string(hyper.length_scale, precision=4),
        hyper.nugget, result.fun, result.nfev, seconds,
        " (optimum on a bound)" if np.any(at_edge) else "",
    )
    record = TrainingRecord(trainer=trainer, result=result, bounds=bounds, seconds=seconds)
    return condition(X, Y, hyper, mean=mean, shrinkage=shrinkage, jitter=jitter, training=record)
