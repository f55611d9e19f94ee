"""The MRGP in a reduced output basis: thousands of responses at the cost of dozens.

The full MRGP carries a k x k response covariance ``Q``: its likelihood costs
``O(k^3)`` per evaluation and ``Q`` alone is 800 MB at k = 10,000. Responses
that are FRF errors over many frequency lines are strongly correlated, so,
as in Higdon, Gattiker, Williams & Rightley (2008, JASA 103, "Computer model
calibration using high-dimensional output"), the responses are emulated
through their leading principal directions::

    Ys = (Y - centre) / scale                           (n, k), standardised
    Ys = U S V^T,      W = Ys V_r                       (n, r) coefficients
    W  ~ MRGP(H beta, Q_W (x) Sigma)                    Q_W is r x r
    y* = centre + scale * (V_r w* + delta)              delta: discarded directions

Rank rule: ``r`` is the smallest number of leading directions whose squared
singular values reach ``variance`` (default 99.9 %) of the total variance of
the *standardised* responses (each response weighs the same), capped by
``n - 1`` (the rank of centred data), by ``max_components`` and by the
numerical rank (squared singular values above 1e-10 of the largest, so the
basis is accurate to about 1e-6).

The basis comes from the n x n Gram matrix ``Ys Ys^T`` (``O(n^2 k)``, one
BLAS call) and its eigen-decomposition, never from a k x k matrix;
``V_r = Ys^T U_r / s_r``.

Predictive variance. At one input the coefficients' posterior covariance is
``s(x) Q_W`` (:meth:`mrgp_core.model.MRGP.predict_factors`), so response j
gets ``scale_j^2 (s(x) (V_r Q_W V_r^T)_jj + tau_j)``. ``tau_j`` is Higdon et
al.'s discrepancy for the discarded directions, estimated honestly by
``n_folds``-fold cross-validation: each fold's rows are projected on the basis
built (same ``r``) from the other rows, and ``tau_j`` is the mean squared
residual of response j over all rows. The in-sample residual would
underestimate it (the basis was fitted to those rows; at ``r = n - 1`` it is
zero). The folds reuse the Gram matrix, so they cost ``O(n r k)``.

Selection criterion. :meth:`ReducedMRGP.predicted_overall_error` predicts the
coefficients of all candidates (``w x r``) and maps them back in chunks of
about 524,000 numbers (4 MB; 1 MB per array for the expected absolute
error, whose formula makes several temporaries), taking each chunk's
``mean_j |mu_j|`` (or the expected absolute error) before the next: the
``w x k`` mean (800 MB for 10,000 x 10,000) is never held. ``mean |.|`` is
not linear, so it cannot be taken in the reduced space itself. The product
``w k (r + 1)`` is the bulk of an iteration at large k, so for
``mean_j |mu_j|`` it runs in single precision by default (sums in double;
error bound in the method).

Nothing here forms a k x k array; the largest arrays are ``n x k`` (the data)
and ``chunk x k``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from .likelihood import Hyperparameters, standardise
from .model import CRITERIA, MRGP, _check_data, condition, fit, predicted_overall_error

__all__ = [
    "VARIANCE_CAPTURED",
    "N_FOLDS",
    "OutputBasis",
    "output_basis",
    "ReducedMRGP",
    "fit_reduced",
    "condition_reduced",
]

log = logging.getLogger(__name__)

#: Default share of the standardised responses' variance the basis keeps.
VARIANCE_CAPTURED = 0.999
#: Default number of cross-validation folds for the truncation variance.
N_FOLDS = 5
#: Squared singular values below this fraction of the largest are not used.
_RANK_RTOL = 1e-10
#: Numbers per chunk when mapping candidates back to the k responses for the expected-absolute
#: criterion (1 MB per array; its formula makes about eight such temporaries); the mean-absolute
#: criterion holds one array and takes chunks four times larger.
_CHUNK_ELEMENTS = 1 << 17


def _eig_desc(G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (clipped at 0, descending) and eigenvectors of a symmetric PSD ``G``."""
    evals, U = np.linalg.eigh(G)
    return np.maximum(evals[::-1], 0.0), U[:, ::-1]


def _weights(evals: np.ndarray, U: np.ndarray, r: int) -> np.ndarray:
    """``A = U_r / s_r``, shape (n, r'), so that ``V_r = Yc^T A`` for the data ``Yc`` whose Gram matrix
    has the eigen-pairs ``(evals, U)``; ``r' <= r`` keeps only directions above the numerical rank."""
    r = min(r, np.count_nonzero(evals > _RANK_RTOL * evals[0])) if evals.size and evals[0] > 0 else 0
    return U[:, :r] / np.sqrt(evals[:r])


def _centred_gram(G: np.ndarray) -> np.ndarray:
    """``C G C`` with ``C = I - 1 1^T / n``: the Gram matrix of the row-centred data."""
    return G - G.mean(axis=0) - G.mean(axis=1)[:, None] + G.mean()


def _rank(evals: np.ndarray, variance: float, cap: int) -> int:
    total = float(np.sum(evals))
    frac = np.cumsum(evals) / total
    r = int(np.searchsorted(frac, variance * (1.0 - 1e-12))) + 1
    return max(1, min(r, cap))


@dataclass(frozen=True)
class OutputBasis:
    """Standardisation and leading principal directions of the training responses.

    Attributes
    ----------
    centre, scale : ndarray, shape (k,)
        ``Y = centre + scale * Ys``, response units.
    basis : ndarray, shape (k, r)
        Orthonormal columns ``V_r`` (dimensionless).
    singular_values : ndarray, shape (min(n, k),)
        Of the standardised training responses, descending (all of them, for the record).
    coefficients : ndarray, shape (n, r)
        ``W = Ys V_r`` of the training rows.
    truncation_variance : ndarray, shape (k,)
        Cross-validated mean squared residual of the discarded directions,
        standardised units (multiply by ``scale**2`` for response units).
    captured : float
        Share of the standardised variance the ``r`` directions keep (in-sample).
    n_folds : int
        Folds used for ``truncation_variance``.
    """

    centre: np.ndarray
    scale: np.ndarray
    basis: np.ndarray
    singular_values: np.ndarray
    coefficients: np.ndarray
    truncation_variance: np.ndarray
    captured: float
    n_folds: int

    @property
    def n_responses(self) -> int:
        return self.centre.size

    @property
    def n_components(self) -> int:
        return self.basis.shape[1]

    def project(self, Y: np.ndarray) -> np.ndarray:
        """Coefficients of responses, shape (w, r), from ``Y`` of shape (w, k) in response units."""
        Y = np.asarray(Y, dtype=float)
        if Y.ndim != 2 or Y.shape[1] != self.n_responses:
            raise ValueError(f"Y must have shape (w, {self.n_responses}), got {Y.shape}")
        return ((Y - self.centre) / self.scale) @ self.basis

    def reconstruct(self, C: np.ndarray) -> np.ndarray:
        """Responses, shape (w, k), response units, from coefficients ``C`` of shape (w, r)."""
        C = np.asarray(C, dtype=float)
        if C.ndim != 2 or C.shape[1] != self.n_components:
            raise ValueError(f"coefficients must have shape (w, {self.n_components}), got {C.shape}")
        return self.centre + (C @ self.basis.T) * self.scale


def output_basis(
    Y: np.ndarray,
    variance: float = VARIANCE_CAPTURED,
    max_components: int | None = None,
    n_folds: int = N_FOLDS,
) -> OutputBasis:
    """Reduced output basis of training responses (see the module docstring for the rule).

    Parameters
    ----------
    Y : ndarray, shape (n, k)
        Training responses, response units; ``n >= 2``.
    variance : float in (0, 1]
        Share of the standardised variance to keep.
    max_components : int, optional
        Upper bound on ``r`` (besides ``n - 1``).
    n_folds : int >= 2
        Cross-validation folds for the truncation variance (at most ``n``);
        row ``i`` is in fold ``i mod n_folds``.

    Returns
    -------
    OutputBasis

    Raises
    ------
    ValueError
        Bad ``variance``, ``max_components`` or ``n_folds``; fewer than two
        rows; non-finite values; or every response constant.
    """
    Y = np.asarray(Y, dtype=float)
    if Y.ndim != 2 or Y.shape[0] < 2:
        raise ValueError(f"Y must have shape (n, k) with n >= 2, got {Y.shape}")
    if not np.all(np.isfinite(Y)):
        raise ValueError("Y must be finite")
    if not 0.0 < variance <= 1.0:
        raise ValueError(f"variance must lie in (0, 1], got {variance}")
    if max_components is not None and int(max_components) < 1:
        raise ValueError(f"max_components must be >= 1, got {max_components}")
    if int(n_folds) < 2:
        raise ValueError(f"n_folds must be >= 2, got {n_folds}")
    n, k = Y.shape
    Ys, centre, scale = standardise(Y)
    G = Ys @ Ys.T  # (n, n); the rows of Ys are already centred
    cap = min(n - 1, k, int(max_components) if max_components is not None else n)
    evals, U = _eig_desc(G)
    if not evals[0] > 0:
        raise ValueError("every response is constant over the training rows: nothing to emulate")
    A = _weights(evals, U, _rank(evals, variance, cap))
    r = A.shape[1]
    captured = float(np.sum(evals[:r]) / np.sum(evals))

    # Cross-validation without copying rows of Ys: fold f's centred training rows are C_T Y_T,
    # their Gram matrix is C_T G_TT C_T, and its directions are V_f = Y_T^T C_T A_f = Ys^T Z_f with
    # Z_f zero off the training rows. The held-out rows' coefficients on V_f come from G too.
    n_folds = min(int(n_folds), n)
    fold = np.arange(n) % n_folds
    Z = np.zeros((n, r + n_folds * (r + 1)))
    Z[:, :r] = A
    held = []
    for f in range(n_folds):
        test, train = fold == f, fold != f
        G_tt = G[np.ix_(train, train)]
        A_f = _weights(*_eig_desc(_centred_gram(G_tt)), min(r, int(train.sum()) - 1))
        A_f -= A_f.mean(axis=0)  # C_T A_f
        a = r + f * (r + 1)
        Z[train, a] = 1.0 / train.sum()  # the fold's mean row: Ys^T Z[:, a]
        Z[train, a + 1: a + 1 + A_f.shape[1]] = A_f
        held.append((test, (G[np.ix_(test, train)] - G_tt.mean(axis=0)) @ A_f, a))
    P = Ys.T @ Z  # (k, r + n_folds (r + 1)): the basis, and each fold's mean and directions
    V = np.ascontiguousarray(P[:, :r])
    W = Ys @ V
    sq = np.zeros(k)
    for test, coef, a in held:
        E = Ys[test] - P[:, a]
        E -= coef @ P[:, a + 1: a + 1 + coef.shape[1]].T
        sq += np.einsum("ij,ij->j", E, E)
    tau = sq / n
    return OutputBasis(centre=centre, scale=scale, basis=V, singular_values=np.sqrt(evals), coefficients=W,
                       truncation_variance=tau, captured=captured, n_folds=n_folds)


@dataclass
class ReducedMRGP:
    """An MRGP on the coefficients of an :class:`OutputBasis`, predicting all k responses.

    Build it with :func:`fit_reduced` or :func:`condition_reduced`.

    Attributes
    ----------
    outputs : OutputBasis
    coefficients : MRGP
        Conditioned on ``outputs.coefficients`` (its ``Q`` is r x r).
    seconds_basis : float
        Wall time of the basis and its cross-validation.
    """

    outputs: OutputBasis
    coefficients: MRGP
    seconds_basis: float = 0.0
    _coef_var: np.ndarray | None = field(default=None, repr=False)
    _back: np.ndarray | None = field(default=None, repr=False)

    @property
    def n_responses(self) -> int:
        return self.outputs.n_responses

    @property
    def n_components(self) -> int:
        return self.outputs.n_components

    @property
    def hyperparameters(self) -> Hyperparameters:
        return self.coefficients.hyperparameters

    @property
    def training(self):
        """The coefficient model's :class:`~mrgp_core.model.TrainingRecord` (None if only conditioned)."""
        return self.coefficients.training

    @property
    def log_likelihood(self) -> float:
        """Eq. (10) of the coefficient model (standardised coefficients; not comparable with a full MRGP's)."""
        return self.coefficients.log_likelihood

    def coefficient_variance(self) -> np.ndarray:
        """``diag(V_r Q_W V_r^T)``, shape (k,), standardised response units: the part scaled by ``s(x)``."""
        if self._coef_var is None:
            V = self.outputs.basis
            self._coef_var = np.einsum("jr,rs,js->j", V, self.coefficients.Q, V)
        return self._coef_var

    def _factors(self, Xstar, return_var, observation_noise, mean_uncertainty):
        return self.coefficients.predict_factors(Xstar, return_var=return_var, observation_noise=observation_noise,
                                                 mean_uncertainty=mean_uncertainty)

    def _variance(self, s: np.ndarray, truncation: bool) -> np.ndarray:
        var = np.outer(s, self.coefficient_variance())
        if truncation:
            var += self.outputs.truncation_variance
        var *= self.outputs.scale**2
        return var

    def predict(
        self,
        Xstar: np.ndarray,
        *,
        return_var: bool = True,
        observation_noise: bool = False,
        mean_uncertainty: bool = True,
        truncation: bool = True,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Posterior mean and per-response variance of all k responses.

        This returns two (w, k) arrays: for many candidates and responses use
        :meth:`predicted_overall_error`, which never holds them.

        Parameters
        ----------
        Xstar : ndarray, shape (w, d)
        return_var, observation_noise, mean_uncertainty : bool
            As :meth:`mrgp_core.model.MRGP.predict`.
        truncation : bool
            Add the variance of the discarded directions (default; False
            gives the variance of the retained directions alone).

        Returns
        -------
        mean : ndarray, shape (w, k), response units
        var : ndarray, shape (w, k), response units squared, or None
        """
        C, s = self._factors(Xstar, return_var, observation_noise, mean_uncertainty)
        mean = self.outputs.reconstruct(C)
        return mean, (self._variance(s, truncation) if return_var else None)

    def predicted_overall_error(self, Xstar: np.ndarray, criterion: str = "mean_abs",
                                precision: str = "single") -> np.ndarray:
        """Predicted Eq. (6b) error of each candidate, shape (w,), in chunks of candidates.

        The values of :func:`mrgp_core.model.predicted_overall_error` applied to
        :meth:`predict`'s output; at most about 524,000 predicted responses
        (4 MB in double precision) are held at a time.

        Parameters
        ----------
        Xstar : ndarray, shape (w, d)
        criterion : {"mean_abs", "expected_abs"}
        precision : {"single", "double"}
            Arithmetic of the ``w x k`` back-mapping product for ``"mean_abs"``
            (``"expected_abs"`` is always double). It is the bulk of the work
            (``w k (r + 1)`` multiply-adds); single precision halves its time
            and changes each score by at most ``(r + 3) eps_32`` times the mean
            over responses of ``|centre_j| + sum_i |c_i B_ij|`` (about 1e-6
            relative), which reorders only candidates that tie to that level.

        Returns
        -------
        ndarray, shape (w,), float64
        """
        if criterion not in CRITERIA:
            raise ValueError(f"unknown criterion {criterion!r}; valid criteria are {', '.join(CRITERIA)}")
        if precision not in ("single", "double"):
            raise ValueError(f"precision must be 'single' or 'double', got {precision!r}")
        need_var = criterion == "expected_abs"
        dtype = np.float32 if precision == "single" and not need_var else np.float64
        C, s = self._factors(Xstar, need_var, False, True)
        if self._back is None:
            # one product per chunk gives centre + scale * (C V_r^T): [C, 1] @ [[V_r^T * scale], [centre]]
            self._back = np.ascontiguousarray(np.vstack([self.outputs.basis.T * self.outputs.scale,
                                                         self.outputs.centre]))
        back = self._back.astype(dtype, copy=False)
        C = np.hstack([C, np.ones((C.shape[0], 1))]).astype(dtype, copy=False)
        out = np.empty(C.shape[0])
        step = max(1, (_CHUNK_ELEMENTS if need_var else 4 * _CHUNK_ELEMENTS) // self.n_responses)
        for a in range(0, C.shape[0], step):
            sl = slice(a, min(a + step, C.shape[0]))
            M = C[sl] @ back
            if need_var:
                out[sl] = predicted_overall_error(M, self._variance(s[sl], True), criterion)
            else:
                out[sl] = np.abs(M, out=M).sum(axis=1, dtype=np.float64) / self.n_responses
        return out


def _reduced(X, Y, variance, max_components, n_folds, build) -> ReducedMRGP:
    X, Y = _check_data(X, Y)
    t0 = time.perf_counter()
    outputs = output_basis(Y, variance, max_components, n_folds)
    seconds = time.perf_counter() - t0
    log.info("output basis: k=%d responses -> r=%d directions (%.4g %% of the standardised variance), "
             "cross-validated truncation variance %.3g (mean, standardised), %.3f s",
             outputs.n_responses, outputs.n_components, 100 * outputs.captured,
             float(np.mean(outputs.truncation_variance)), seconds)
    return ReducedMRGP(outputs=outputs, coefficients=build(X, outputs.coefficients), seconds_basis=seconds)


def fit_reduced(
    X: np.ndarray,
    Y: np.ndarray,
    trainer: str = "gradient",
    *,
    rng: np.random.Generator,
    variance: float = VARIANCE_CAPTURED,
    max_components: int | None = None,
    n_folds: int = N_FOLDS,
    **fit_options,
) -> ReducedMRGP:
    """Train an MRGP on the reduced outputs of ``Y``.

    Parameters
    ----------
    X : ndarray, shape (n, d)
    Y : ndarray, shape (n, k)
        Responses, response units.
    trainer, rng, **fit_options
        Passed to :func:`mrgp_core.model.fit` (``kernel``, ``mean``,
        ``nugget``, ``shrinkage``, ``l_lower``, ``l_upper``, ...).
    variance, max_components, n_folds
        See :func:`output_basis`.

    Returns
    -------
    ReducedMRGP
    """
    return _reduced(X, Y, variance, max_components, n_folds,
                    lambda X_, W: fit(X_, W, trainer, rng=rng, **fit_options))


def condition_reduced(
    X: np.ndarray,
    Y: np.ndarray,
    hyperparameters: Hyperparameters,
    *,
    variance: float = VARIANCE_CAPTURED,
    max_components: int | None = None,
    n_folds: int = N_FOLDS,
    **condition_options,
) -> ReducedMRGP:
    """:func:`fit_reduced` at fixed hyper-parameters (no training); options go to :func:`~mrgp_core.model.condition`."""
    return _reduced(X, Y, variance, max_components, n_folds,
                    lambda X_, W: condition(X_, W, hyperparameters, **condition_options))
