"""Profile log-likelihood of the MRGP (Eqs. 9-12) and its analytic gradient.

Model (in standardised response units, ``sigma_f = 1``)::

    vec(Y) ~ N(vec(H beta), Q (x) Sigma),   Sigma = R(l) + (g + jitter) I

with ``Y`` (r, k), ``H`` (r, q) the mean basis, ``R`` the squared-exponential
correlation of :mod:`mrgp_core.kernels`, ``g`` the nugget ratio
``sigma_n^2 / sigma_f^2`` and ``jitter`` a fixed perturbation of the diagonal.

Everything is computed from the Cholesky factor ``L`` of the r x r ``Sigma``
alone; the (r k) x (r k) Kronecker product is never formed:

* ``beta^ = (H^T Sigma^-1 H)^-1 H^T Sigma^-1 Y`` (Eq. 11 with the inverses the
  paper drops). It does not depend on ``Q``: with a Kronecker covariance the
  GLS estimate is column by column.
* ``Q^ = (Y - H beta^)^T Sigma^-1 (Y - H beta^) / r`` (Eq. 12). Its rank is at
  most ``r - q``, so with ``k`` responses and ``k > r - q`` it is singular and
  Eq. (10) is ``-inf``. The rule used here (:func:`regularise_q`) is shrinkage
  toward the diagonal plus a tiny relative floor::

      Q_reg = (1 - lam) Q^ + lam diag(Q^) + delta * tr(Q^)/k * I

  with ``lam`` from :func:`shrinkage_weight` (default ``"auto"``:
  ``lam = k / (k + r - q)``, the weight an inverse-Wishart prior centred on
  ``diag(Q^)`` with ``k`` degrees of freedom gets against the ``r - q`` degrees
  of freedom of the residuals) and ``delta = Q_FLOOR = 1e-10``, which only
  matters for responses with zero residual (constant columns). The shrinkage
  keeps ``diag(Q_reg) = diag(Q^)`` (up to the floor), so the predictive
  variance of each response does not depend on ``lam``.
* The objective is the exact Eq. (10) at ``(beta^, Q_reg)``::

      ln p = -(r k / 2) ln 2 pi - (r / 2) ln det Q_reg - (k / 2) ln det Sigma
             - 1/2 tr(Q_reg^-1 S),    S = (Y - H beta^)^T Sigma^-1 (Y - H beta^)

  The quadratic term is computed honestly; only when ``lam = 0`` and ``Q^`` is
  nonsingular does it reduce to ``r k / 2`` (trace identity).

The gradient is that of this same function, with ``beta^`` and ``Q_reg``
following their profiled dependence on the hyper-parameters. Because
``beta^`` minimises ``tr(W S)`` for every positive-definite ``W``,
``dS/dtheta = -A^T (dSigma/dtheta) A`` with ``A = Sigma^-1 (Y - H beta^)``; with
``G = d ln p / dS`` (chain rule through the linear map ``Q^ -> Q_reg``),
``d ln p / dtheta = -tr(dSigma/dtheta (A G A^T + (k/2) Sigma^-1))``.

``sigma_f``: ``Q (x) sigma_f^2 Sigma`` is invariant under ``sigma_f -> c
sigma_f, Q -> Q / c^2``, and ``Q_reg`` inherits the scaling, so the profile
likelihood does not depend on ``sigma_f``. It is fixed at 1; the amplitude of
each response lives in ``Q``, and the nugget is a ratio to ``sigma_f^2``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_solve, cholesky, lapack, solve_triangular

from .kernels import check_length_scale, correlation_from_squared, squared_differences, squared_distances

__all__ = [
    "MEANS",
    "DEFAULT_JITTER",
    "Q_FLOOR",
    "Hyperparameters",
    "mean_basis",
    "standardise",
    "shrinkage_weight",
    "regularise_q",
    "ProfileTerms",
    "profile",
    "ProfileLikelihood",
]

log = logging.getLogger(__name__)

#: Mean functions: zero (on standardised responses), constant, or the paper's [1, x].
MEANS = ("zero", "constant", "linear")
#: Fixed perturbation of Sigma's diagonal (relative to sigma_f^2 = 1). It bounds
#: cond(Sigma) by about r / jitter, so the Cholesky factorisation of a
#: correlation matrix of nearly coincident or very smooth inputs never fails. It
#: is part of the model: the likelihood and the prediction use the same Sigma.
DEFAULT_JITTER = 1e-8
#: Relative floor on Q_reg's diagonal (times the mean of diag(Q^)).
Q_FLOOR = 1e-10

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class Hyperparameters:
    """Hyper-parameters of the MRGP prior.

    Attributes
    ----------
    length_scale : ndarray, shape (1,) or (d,), input units squared
        The ``l`` of Eq. (8) (a squared length scale), one for the isotropic
        kernel, one per input for ARD.
    nugget : float
        Nugget ratio ``g = sigma_n^2 / sigma_f^2 >= 0``; 0 is the paper's
        noise-free case.
    sigma_f : float
        Always 1: not identifiable when ``Q`` is estimated (the amplitude is
        absorbed in ``Q``). Kept so the record states it.
    """

    length_scale: np.ndarray
    nugget: float = 0.0
    sigma_f: float = 1.0

    @property
    def kernel(self) -> str:
        """``"iso"`` for one length scale, ``"ard"`` for one per input."""
        return "iso" if np.size(self.length_scale) == 1 else "ard"

    def as_dict(self) -> dict:
        """Plain-Python view for logs and manifests."""
        return {
            "kernel": self.kernel,
            "length_scale": [float(v) for v in np.atleast_1d(self.length_scale)],
            "nugget": float(self.nugget),
            "sigma_f": float(self.sigma_f),
        }


def mean_basis(X: np.ndarray, mean: str) -> np.ndarray:
    """Mean-function basis ``H(X)``.

    Parameters
    ----------
    X : ndarray, shape (n, d)
    mean : {"zero", "constant", "linear"}
        ``"linear"`` is the paper's ``H = [1, x]``.

    Returns
    -------
    ndarray, shape (n, q)
        q = 0, 1 or d + 1.
    """
    X = np.asarray(X, dtype=float)
    if mean == "zero":
        return np.empty((X.shape[0], 0))
    if mean == "constant":
        return np.ones((X.shape[0], 1))
    if mean == "linear":
        return np.hstack([np.ones((X.shape[0], 1)), X])
    raise ValueError(f"unknown mean {mean!r}; valid means are {', '.join(MEANS)}")


def standardise(Y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Subtract each column's mean and divide by its standard deviation.

    Constant columns keep a scale of 1 (they become zeros, not NaN).

    Parameters
    ----------
    Y : ndarray, shape (r, k)

    Returns
    -------
    Ys : ndarray, shape (r, k)
    centre : ndarray, shape (k,)
    scale : ndarray, shape (k,)
        Positive.
    """
    Y = np.asarray(Y, dtype=float)
    centre = Y.mean(axis=0)
    scale = Y.std(axis=0)
    tiny = np.finfo(float).tiny
    scale = np.where(scale > np.maximum(1e-14 * np.abs(centre), tiny), scale, 1.0)
    return (Y - centre) / scale, centre, scale


def shrinkage_weight(shrinkage, r: int, q: int, k: int) -> float:
    """The ``lam`` of :func:`regularise_q`.

    Parameters
    ----------
    shrinkage : float in [0, 1] or "auto"
        ``"auto"`` gives ``k / (k + r - q)`` (``1`` if ``r <= q``): the weight of
        an inverse-Wishart prior on ``Q`` centred on ``diag(Q^)`` with ``k``
        degrees of freedom against the ``r - q`` degrees of freedom of the GLS
        residuals. It depends on the data sizes only, not on the
        hyper-parameters, so the likelihood stays a smooth function of them.
    r, q, k : int
        Runs, mean-basis columns, responses.
    """
    if isinstance(shrinkage, str):
        if shrinkage != "auto":
            raise ValueError(f"shrinkage must be a number in [0, 1] or 'auto', got {shrinkage!r}")
        dof = r - q
        return 1.0 if dof <= 0 else k / (k + dof)
    lam = float(shrinkage)
    if not 0.0 <= lam <= 1.0:
        raise ValueError(f"shrinkage must lie in [0, 1], got {lam}")
    return lam


def _shrink_map(M: np.ndarray, lam: float, floor: float) -> np.ndarray:
    """The linear, self-adjoint map ``M -> (1-lam) M + lam diag(M) + floor tr(M)/k I``."""
    k = M.shape[0]
    out = (1.0 - lam) * M
    out[np.diag_indices(k)] += lam * np.diag(M) + floor * np.trace(M) / k
    return out


def regularise_q(Q_hat: np.ndarray, lam: float, floor: float = Q_FLOOR) -> np.ndarray:
    """Shrink ``Q^`` toward its diagonal so it is positive definite.

    ``Q_reg = (1 - lam) Q^ + lam diag(Q^) + floor * tr(Q^)/k * I``.

    Parameters
    ----------
    Q_hat : ndarray, shape (k, k)
        Eq. (12), symmetric positive semi-definite.
    lam : float in [0, 1]
    floor : float
        Relative floor; keeps ``Q_reg`` nonsingular when a response has zero
        residual.

    Returns
    -------
    ndarray, shape (k, k)
    """
    return _shrink_map(np.array(Q_hat, dtype=float), lam, floor)


@dataclass(frozen=True)
class ProfileTerms:
    """The profiled quantities at one Sigma (standardised units).

    Attributes
    ----------
    chol : ndarray, shape (r, r)
        Lower Cholesky factor ``L`` of Sigma.
    basis_q, basis_r : ndarray, shape (r, q), (q, q)
        Reduced QR of the whitened basis ``L^-1 H``.
    beta : ndarray, shape (q, k)
        GLS estimate (Eq. 11, with inverses).
    alpha : ndarray, shape (r, k)
        ``Sigma^-1 (Y - H beta)``, the weights of the posterior mean (Eq. 14).
    whitened_residual : ndarray, shape (r, k)
        ``L^-1 (Y - H beta)``.
    Q_hat, Q_reg : ndarray, shape (k, k)
        Eq. (12) and its regularised version.
    chol_q : ndarray, shape (k, k)
        Lower Cholesky factor of ``Q_reg``.
    shrinkage : float
    log_likelihood : float
        Eq. (10) at ``(beta, Q_reg)``, standardised units.
    """

    chol: np.ndarray
    basis_q: np.ndarray
    basis_r: np.ndarray
    beta: np.ndarray
    alpha: np.ndarray
    whitened_residual: np.ndarray
    Q_hat: np.ndarray
    Q_reg: np.ndarray
    chol_q: np.ndarray
    shrinkage: float
    log_likelihood: float


def profile(Sigma: np.ndarray, H: np.ndarray, Y: np.ndarray, shrinkage="auto", floor: float = Q_FLOOR) -> ProfileTerms:
    """GLS ``beta``, ``Q^``, ``Q_reg`` and Eq. (10) for a given spatial covariance.

    Parameters
    ----------
    Sigma : ndarray, shape (r, r)
        Symmetric positive definite.
    H : ndarray, shape (r, q)
    Y : ndarray, shape (r, k)
    shrinkage : float in [0, 1] or "auto"
        See :func:`shrinkage_weight`.
    floor : float
        See :func:`regularise_q`.

    Returns
    -------
    ProfileTerms

    Raises
    ------
    numpy.linalg.LinAlgError
        If Sigma is not numerically positive definite, or ``H`` is rank deficient.
    """
    L = cholesky(Sigma, lower=True, check_finite=False)
    terms = _profile_from_chol(L, np.asarray(H, float), np.asarray(Y, float), shrinkage, floor)
    if terms is None:
        raise np.linalg.LinAlgError("Q_reg is not positive definite (all responses have zero residual?)")
    return terms


def _profile_from_chol(L, H, Y, shrinkage, floor) -> ProfileTerms | None:
    r, k = Y.shape
    q = H.shape[1]
    lam = shrinkage_weight(shrinkage, r, q, k)
    WY = solve_triangular(L, np.hstack([H, Y]), lower=True, check_finite=False)
    Ht, Yt = WY[:, :q], WY[:, q:]
    if q:
        Qh, Rh = np.linalg.qr(Ht)
        if np.min(np.abs(np.diag(Rh))) <= 1e-12 * np.max(np.abs(np.diag(Rh))):
            raise np.linalg.LinAlgError("the mean basis H is rank deficient on the training inputs")
        proj = Qh.T @ Yt
        beta = solve_triangular(Rh, proj, lower=False, check_finite=False)
        Et = Yt - Qh @ proj
    else:
        Qh, Rh, beta, Et = np.empty((r, 0)), np.empty((0, 0)), np.empty((0, k)), Yt
    S = Et.T @ Et
    Q_hat = S / r
    Q_reg = _shrink_map(Q_hat.copy(), lam, floor)
    Lq, info = lapack.dpotrf(Q_reg, lower=1, clean=1)
    if info != 0:
        return None
    logdet_sigma = 2.0 * np.sum(np.log(np.diag(L)))
    logdet_q = 2.0 * np.sum(np.log(np.diag(Lq)))
    Z = solve_triangular(Lq, Et.T, lower=True, check_finite=False)
    quad = float(np.sum(Z * Z))
    ll = -0.5 * (r * k * _LOG_2PI + r * logdet_q + k * logdet_sigma + quad)
    alpha = solve_triangular(L, Et, lower=True, trans="T", check_finite=False)
    return ProfileTerms(L, Qh, Rh, beta, alpha, Et, Q_hat, Q_reg, Lq, lam, float(ll))


class ProfileLikelihood:
    """Negative profile log-likelihood as a function of log hyper-parameters.

    Precomputes everything that does not depend on the hyper-parameters
    (pairwise squared distances or per-input squared differences, the mean
    basis, the responses). The search vector is

    ``theta = [log l_1, ..., log l_p, log g]``

    with ``p = 1`` (isotropic) or ``d`` (ARD) and ``log g`` present only when
    the nugget ratio is fitted (``nugget="fit"``).

    Parameters
    ----------
    X : ndarray, shape (r, d)
    Y : ndarray, shape (r, k)
        Responses as the likelihood should see them (the model passes
        standardised ones).
    kernel : {"iso", "ard"}
    mean : {"zero", "constant", "linear"}
    nugget : "fit" or float >= 0
        Fitted nugget ratio, or a fixed one (0 = the paper's noise-free case).
    shrinkage : float in [0, 1] or "auto"
        See :func:`shrinkage_weight`.
    jitter : float
        Fixed perturbation of Sigma's diagonal.
    """

    def __init__(self, X, Y, *, kernel="iso", mean="linear", nugget="fit", shrinkage="auto", jitter=DEFAULT_JITTER):
        self.X = np.asarray(X, dtype=float)
        self.Y = np.asarray(Y, dtype=float)
        if self.X.ndim != 2 or self.Y.ndim != 2 or self.X.shape[0] != self.Y.shape[0]:
            raise ValueError(f"X must be (r, d) and Y (r, k) with the same r, got {self.X.shape} and {self.Y.shape}")
        r, d = self.X.shape
        k = self.Y.shape[1]
        check_length_scale(np.ones(1 if kernel == "iso" else d), kernel, d)
        self.kernel = kernel
        self.mean = mean
        self.H = mean_basis(self.X, mean)
        if r < self.H.shape[1]:  # fewer runs than the GLS mean's columns: no fit (as many leave Q to the shrinkage)
            raise ValueError(f"the {mean} mean has {self.H.shape[1]} columns on {d} inputs: its fit needs at least "
                             f"{self.H.shape[1]} training runs, got {r}")
        self.fit_nugget = isinstance(nugget, str)
        if self.fit_nugget and nugget != "fit":
            raise ValueError(f"nugget must be 'fit' or a number >= 0, got {nugget!r}")
        self.fixed_nugget = 0.0 if self.fit_nugget else float(nugget)
        if self.fixed_nugget < 0:
            raise ValueError(f"the nugget ratio must be >= 0, got {nugget}")
        self.jitter = float(jitter)
        self.shrinkage = shrinkage_weight(shrinkage, r, self.H.shape[1], k)
        self.sq = squared_distances(self.X) if kernel == "iso" else squared_differences(self.X)
        self.n_length_scales = 1 if kernel == "iso" else d
        self.n_params = self.n_length_scales + int(self.fit_nugget)
        self.nfev = 0

    # -- parametrisation -------------------------------------------------
    def hyperparameters(self, theta) -> Hyperparameters:
        """Map a search vector to :class:`Hyperparameters`."""
        theta = np.asarray(theta, dtype=float)
        ls = np.exp(theta[: self.n_length_scales])
        g = float(np.exp(theta[-1])) if self.fit_nugget else self.fixed_nugget
        return Hyperparameters(length_scale=ls, nugget=g)

    def theta(self, hyper: Hyperparameters) -> np.ndarray:
        """Inverse of :meth:`hyperparameters`."""
        ls = check_length_scale(hyper.length_scale, self.kernel, self.X.shape[1])
        out = np.log(ls)
        if self.fit_nugget:
            if hyper.nugget <= 0:
                raise ValueError("a fitted nugget ratio must be positive")
            out = np.append(out, np.log(hyper.nugget))
        return out

    def sigma(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """``(Sigma, R)`` at ``theta``, each shape (r, r)."""
        hyper = self.hyperparameters(theta)
        R = correlation_from_squared(self.sq, hyper.length_scale)
        Sigma = R.copy()
        Sigma[np.diag_indices_from(Sigma)] += hyper.nugget + self.jitter
        return Sigma, R

    # -- objective -------------------------------------------------------
    def terms(self, theta) -> ProfileTerms:
        """All profiled quantities at ``theta`` (raises if Sigma is not positive definite)."""
        Sigma, _ = self.sigma(theta)
        return profile(Sigma, self.H, self.Y, self.shrinkage)

    def log_likelihood(self, theta) -> float:
        """Eq. (10) at ``(beta^, Q_reg)``; ``-inf`` if a factorisation fails."""
        return -self.negative(theta)

    def negative(self, theta) -> float:
        """Negative of :meth:`log_likelihood` (what the trainers minimise)."""
        self.nfev += 1
        Sigma, _ = self.sigma(theta)
        L, info = lapack.dpotrf(Sigma, lower=1, clean=1)
        if info != 0:
            log.debug("Sigma not positive definite at theta=%s", theta)
            return np.inf
        terms = _profile_from_chol(L, self.H, self.Y, self.shrinkage, Q_FLOOR)
        return np.inf if terms is None else -terms.log_likelihood

    def negative_and_grad(self, theta) -> tuple[float, np.ndarray]:
        """Negative log-likelihood and its gradient with respect to ``theta``.

        Returns
        -------
        value : float
        grad : ndarray, shape (n_params,)
        """
        self.nfev += 1
        theta = np.asarray(theta, dtype=float)
        hyper = self.hyperparameters(theta)
        Sigma, R = self.sigma(theta)
        L, info = lapack.dpotrf(Sigma, lower=1, clean=1)
        terms = None if info != 0 else _profile_from_chol(L, self.H, self.Y, self.shrinkage, Q_FLOOR)
        if terms is None:
            return np.inf, np.zeros(self.n_params)
        r, k = self.Y.shape
        lam = terms.shrinkage
        # Q_reg^-1 and Sigma^-1 from their Cholesky factors.
        Qinv = cho_solve((terms.chol_q, True), np.eye(k), check_finite=False)
        S = r * terms.Q_hat
        P = Qinv @ S @ Qinv
        G = -0.5 * _shrink_map(Qinv.copy(), lam, Q_FLOOR) - 0.5 * Qinv + (0.5 / r) * _shrink_map(P, lam, Q_FLOOR)
        Sinv, info = lapack.dpotri(L, lower=1)
        Sinv = np.tril(Sinv) + np.tril(Sinv, -1).T
        A = terms.alpha
        W = -((A @ G) @ A.T) - 0.5 * k * Sinv
        WR = W * R
        ls = hyper.length_scale
        if self.sq.ndim == 2:
            g_ls = np.array([np.sum(WR * self.sq) * 0.5 / ls[0]])
        else:
            g_ls = np.tensordot(self.sq, WR, axes=([1, 2], [0, 1])) * (0.5 / ls)
        grad = g_ls if not self.fit_nugget else np.append(g_ls, hyper.nugget * np.trace(W))
        return -terms.log_likelihood, -grad

    __call__ = negative
