"""How sure: 95 % intervals and the covariance of updated parameters at a least-squares optimum
(:class:`Intervals`, :func:`laplace_intervals`); the Gauss-Newton steps that reach the optimum on
the FE model are in :mod:`fe_core.inference.intervals`.

Error model
-----------
The project's synthetic measurements (``benchmarks.compare.make_far_noisy``,
``benchmarks.coverage``) and the residual analysis (:mod:`fe_core.inference.residual`)
take the noise as multiplicative on each FRF amplitude::

    u_fs = |Z_fs(alpha_true)| (1 + sigma e_fs),   e_fs ~ N(0, 1) independent,

so on log-amplitudes it is additive:
``ln u = ln|Z(alpha_true)| + ln(1 + sigma e)``, and ``ln(1 + sigma e)`` is
``N(-sigma^2/2, sigma^2)`` up to terms of order ``sigma^3`` (a bias of 5e-5 and
a skewness of 3 sigma at 1 % noise: negligible beside the noise). The
likelihood used here is therefore the Gaussian one of the log residual::

    r(alpha) = ln|Z(alpha)| - ln u,   shape (p * n,),   r ~ N(0, sigma^2 I) at the truth,

whose maximum is the least-squares optimum ``alpha^`` of ``||r||^2``
(noise-weighted: ``||r / sigma||^2``; one sigma for every value, since the
noise is relative). Near ``alpha^`` the model is linearised with the exact
Jacobian ``J = d ln|Z| / d alpha`` (adjoint, on one Krylov space with the FRF:
:func:`fe_core.solvers.sensitivity.log_amplitude_jacobian`), which gives the
Gauss-Newton (Laplace) covariance::

    C = sigma^2 (J^T J)^-1.

Noise level: given (``noise``, the measurement's known relative accuracy),
or estimated from the residual at the optimum with the degrees-of-freedom
correction ``s^2 = ||r||^2 / (N - m)`` (N values, m parameters). The interval
is ``alpha^_i +/- q sqrt(C_ii)`` with ``q`` the normal quantile when sigma is
given and Student's t with ``N - m`` degrees of freedom when it is estimated
(the exact interval of a linear model with estimated variance: the estimate
is then independent of ``s^2``).

Flags: a parameter whose interval crosses a bound of the search box (the
linearisation ignores the bound; the estimate may sit on it) and a parameter
the data do not pin down (interval wider than ``width_threshold``, or a
Jacobian that cannot separate it from the others).

Plain numpy/scipy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Intervals", "laplace_intervals", "WIDTH_THRESHOLD", "METHOD"]


#: Widest 95 % interval (in units of alpha, a relative stiffness change) that still counts as pinned down.
WIDTH_THRESHOLD = 0.2

#: The ``interval_method`` written to summaries.
METHOD = "laplace"


@dataclass(frozen=True)
class Intervals:
    """Intervals of the parameters at the least-squares optimum (see the module's notes).

    Attributes
    ----------
    names : list of str, length m
    estimate : ndarray, shape (m,)
        The least-squares optimum the intervals are centred on.
    std : ndarray, shape (m,)
        ``sqrt(diag(covariance))``; inf for a direction the Jacobian cannot see.
    low, high : ndarray, shape (m,)
        ``estimate -/+ quantile * std`` (not clipped to the box).
    covariance : ndarray, shape (m, m)
        ``sigma^2 (J^T J)^-1`` (pseudo-inverse; inf rows for unseen parameters).
    correlation : ndarray, shape (m, m)
    noise_sigma : float
        Relative amplitude noise used (standard deviation).
    noise_source : {"given", "estimated"}
    dof : int
        ``N - m``.
    distribution : {"normal", "student-t"}
    quantile : float
    level : float
    near_bound, unpinned : ndarray of bool, shape (m,)
    width_threshold : float
    method : str
    absent_at_zero : ndarray of bool, shape (m,), or None
        Parameters whose zero means "absent" (an added effect's value): for
        them ``unpinned`` means the interval contains zero (the data do not
        tell the effect from its absence) instead of the width test.
    """

    names: list
    estimate: np.ndarray
    std: np.ndarray
    low: np.ndarray
    high: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    noise_sigma: float
    noise_source: str
    dof: int
    distribution: str
    quantile: float
    level: float
    near_bound: np.ndarray
    unpinned: np.ndarray
    width_threshold: float
    method: str = METHOD
    absent_at_zero: np.ndarray | None = None

    @property
    def half_width(self) -> np.ndarray:
        return self.quantile * self.std

    def contains(self, truth) -> np.ndarray:
        """Which intervals contain ``truth`` (shape (m,)): bool, shape (m,)."""
        t = np.asarray(truth, float)
        return (self.low <= t) & (t <= self.high)

    def flag_lines(self) -> list[str]:
        """One sentence per flagged parameter (empty when every parameter is pinned down, away from bounds)."""
        lines = []
        pct = f"{self.level:.0%}"
        for i, name in enumerate(self.names):
            if self.unpinned[i] and self.absent_at_zero is not None and self.absent_at_zero[i]:
                lines.append(f"{name}'s {pct} interval [{self.low[i]:.3g}, {self.high[i]:.3g}] contains zero: "
                             "the data do not tell this effect from its absence.")
            elif self.unpinned[i]:
                width = "unbounded" if not np.isfinite(self.std[i]) else f"{self.high[i] - self.low[i]:.3g} wide"
                lines.append(f"{name} is not pinned down by this measurement: its {pct} interval is {width} "
                             f"(threshold {self.width_threshold:g}).")
            if self.near_bound[i]:
                lines.append(f"{name}'s {pct} interval [{self.low[i]:.3g}, {self.high[i]:.3g}] crosses a bound of "
                             "the search box: the linearised interval ignores the bound there.")
        return lines

    def to_summary(self) -> dict:
        """The ``summary.json`` fields: intervals, covariance, interval_method, noise_sigma and details."""
        def num(x):
            return float(x) if np.isfinite(x) else None  # JSON has no inf

        return {
            "intervals": {n: [num(lo), num(hi)] for n, lo, hi in zip(self.names, self.low, self.high)},
            "covariance": [[num(c) for c in row] for row in self.covariance],
            "interval_method": self.method,
            "noise_sigma": float(self.noise_sigma),
            "interval_details": {
                "level": self.level, "noise_source": self.noise_source, "distribution": self.distribution,
                "quantile": self.quantile, "dof": self.dof,
                "estimate": dict(zip(self.names, map(float, self.estimate))),
                "std": {n: num(s) for n, s in zip(self.names, self.std)},
                "correlation": [[num(c) for c in row] for row in self.correlation],
                "unpinned": [n for n, f in zip(self.names, self.unpinned) if f],
                "near_bound": [n for n, f in zip(self.names, self.near_bound) if f],
                "width_threshold": self.width_threshold,
                "flags": self.flag_lines(),
            },
        }


def laplace_intervals(residual, jacobian, estimate, names=None, noise: float | None = None, level: float = 0.95,
                      lower=None, upper=None, width_threshold: float = WIDTH_THRESHOLD) -> Intervals:
    """Gauss-Newton (Laplace) intervals from the residual and Jacobian at a least-squares optimum.

    Parameters
    ----------
    residual : array_like, shape (N,) or (p, n)
        Log residual ``ln|Z(alpha^)| - ln u`` (dimensionless) at the optimum.
    jacobian : array_like, shape (N, m)
        ``d r / d alpha`` at the optimum, rows in the order of ``residual.ravel()``.
    estimate : array_like, shape (m,)
        The optimum ``alpha^``.
    names : list of str, optional
        ``alpha_1 ...`` by default.
    noise : float, optional
        Relative amplitude noise (standard deviation, 0.01 = 1 %); estimated as
        ``sqrt(||r||^2 / (N - m))`` when None.
    level : float
        Coverage of the intervals, in (0, 1).
    lower, upper : float or array_like (m,), optional
        The search box; intervals crossing it are flagged.
    width_threshold : float
        Intervals wider than this (alpha units) are flagged "not pinned down".

    Returns
    -------
    Intervals

    Raises
    ------
    ValueError
        Bad shapes, non-finite entries, a non-positive noise level, too few
        residuals to estimate it, or a level outside (0, 1).
    """
    from scipy import stats  # here, not at the top: 0.7 s of CPU to import, unused by most runs
    r = np.asarray(residual, float).ravel()
    J = np.asarray(jacobian, float)
    x = np.asarray(estimate, float).ravel()
    if J.ndim != 2 or J.shape[0] != r.size or J.shape[1] != x.size:
        raise ValueError(f"jacobian must be (residuals, parameters) = ({r.size}, {x.size}), got shape {J.shape}")
    for label, a in (("residual", r), ("jacobian", J), ("estimate", x)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{label} has non-finite entries")
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    if not width_threshold > 0:
        raise ValueError(f"width_threshold must be positive, got {width_threshold}")
    N, m = J.shape
    names = list(names) if names is not None else [f"alpha_{i + 1}" for i in range(m)]
    if len(names) != m:
        raise ValueError(f"{len(names)} names for {m} parameters")
    dof = N - m
    if noise is None:
        if dof < 1:
            raise ValueError(f"{N} residuals cannot estimate the noise of a fit of {m} parameters; give noise")
        sigma = float(np.sqrt(r @ r / dof))
        source, dist = "estimated", "student-t"
        q = float(stats.t.ppf(0.5 + level / 2, dof))
        if not sigma > 0:
            raise ValueError("the residual is exactly zero: the noise cannot be estimated; give noise")
    else:
        sigma = float(noise)
        if not (np.isfinite(sigma) and sigma > 0):
            raise ValueError(f"noise must be a positive relative amplitude noise (e.g. 0.01), got {noise}")
        source, dist = "given", "normal"
        q = float(stats.norm.ppf(0.5 + level / 2))

    # (J^T J)^-1 through the SVD; a parameter with weight on a (numerically) null direction is unbounded.
    # Thin SVD: only V is needed. The full one built U, N x N (N = lines x channels: 9,606 values of 1,601 lines
    # x 6 channels make 0.74 GB; complex residuals double N and quadruple it), the peak memory of a run.
    # Fewer values than parameters need the full V (its null directions).
    _, s, Vt = np.linalg.svd(J, full_matrices=N < m)
    s = np.concatenate([s, np.zeros(m - s.size)]) if s.size < m else s
    full = s > (s[0] * max(N, m) * np.finfo(float).eps if s[0] > 0 else 0.0)
    V = Vt.T
    cov = sigma**2 * (V[:, full] / s[full] ** 2) @ V[:, full].T
    unseen = (V[:, ~full] ** 2 > 1e-24).any(axis=1)
    cov[unseen, :] = np.inf
    cov[:, unseen] = np.inf
    std = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    corr[unseen, :] = np.nan
    corr[:, unseen] = np.nan
    np.fill_diagonal(corr, 1.0)
    low, high = x - q * std, x + q * std
    lo = np.broadcast_to(-np.inf if lower is None else np.asarray(lower, float), (m,))
    hi = np.broadcast_to(np.inf if upper is None else np.asarray(upper, float), (m,))
    return Intervals(
        names=names, estimate=x, std=std, low=low, high=high, covariance=cov, correlation=corr,
        noise_sigma=sigma, noise_source=source, dof=int(dof), distribution=dist, quantile=q, level=float(level),
        near_bound=(low < lo) | (high > hi), unpinned=~np.isfinite(std) | (high - low > width_threshold),
        width_threshold=float(width_threshold),
    )
