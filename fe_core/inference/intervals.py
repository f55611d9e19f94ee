"""How sure: 95 % intervals and the covariance of updated parameters (Laplace / Gauss-Newton).

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

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy import optimize, stats

__all__ = [
    "Intervals",
    "laplace_intervals",
    "LogFit",
    "fit_log_amplitudes",
    "RefinedIntervals",
    "parameter_intervals",
    "extended_intervals",
    "WIDTH_THRESHOLD",
    "METHOD",
]

log = logging.getLogger(__name__)

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
    _, s, Vt = np.linalg.svd(J, full_matrices=True)
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


def _log_problem(model, freqs_hz, measured_amplitude, lower, upper, m: int | None = None):
    """Checked inputs: ``(freqs (p,), lower (m,), upper (m,), residual)``; ``residual(alpha)``: log residual (p n,).

    ``m``: the box's length, the model's parameters (alpha and updated mass factors) by default.
    """
    freqs = np.asarray(freqs_hz, float)
    u = np.asarray(measured_amplitude, float)
    if u.shape != (freqs.size, model.n_sensors):
        raise ValueError(f"measured amplitude has shape {u.shape}, expected (frequencies, sensors) = "
                         f"({freqs.size}, {model.n_sensors})")
    if not np.all(np.isfinite(u) & (u > 0)):
        raise ValueError("measured amplitudes must be finite and positive (the residual is logarithmic)")
    m = model.n_parameters if m is None else m
    lo = np.broadcast_to(np.asarray(lower, float), (m,)).copy()
    hi = np.broadcast_to(np.asarray(upper, float), (m,)).copy()
    if np.any(lo <= -1.0) or np.any(lo >= hi):
        raise ValueError(f"the box [{lower}, {upper}] must lie inside (-1, inf) with lower < upper")
    log_u = np.log(u).ravel()

    def residual(a):
        return np.log(np.abs(model.parameter_frf(a, freqs))).ravel() - log_u

    return freqs, lo, hi, residual


@dataclass(frozen=True)
class LogFit:
    """A least-squares fit of log-amplitudes on the FE model (:func:`fit_log_amplitudes`).

    Attributes
    ----------
    alpha : ndarray, shape (m,)
    residual : ndarray, shape (p * n,)
        ``ln|Z(alpha)| - ln u``, frequency-major, sensors fastest.
    jacobian : ndarray, shape (p * n, m)
        Exact (adjoint) ``d residual / d alpha`` at ``alpha``.
    fe_runs : int
        FRF evaluations (Krylov) of the fit, finite-difference ones included.
    jacobians : int
        Exact Jacobian evaluations (each about 2 Krylov FRFs of time on the
        benchmark), the final one at ``alpha`` included.
    status : str
        scipy's message.
    """

    alpha: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray
    fe_runs: int
    jacobians: int
    status: str


def fit_log_amplitudes(model, freqs_hz, measured_amplitude, alpha0, lower, upper, max_fe_runs: int = 20,
                       xtol: float = 1e-8, search_jacobian: str = "exact") -> LogFit:
    """Least squares of the log residual on the FE model, from ``alpha0``; exact Jacobian at the end.

    ``scipy.optimize.least_squares`` (trust region reflective, bounds
    ``[lower, upper]``). The search's Jacobian is the exact adjoint one
    (:func:`fe_core.solvers.sensitivity.log_amplitude_jacobian` on a Krylov space,
    about 2 Krylov FRFs of time on the benchmark) or, with ``search_jacobian =
    "2-point"``, forward differences of step 1e-6 (m Krylov FRFs; the same
    optimum to the accuracy of the differences).
    The returned Jacobian is always the exact one at the optimum.
    A local search: start it in the basin (the update's result).

    Parameters
    ----------
    model : ParametricModel
    freqs_hz : array_like, shape (p,), Hz
    measured_amplitude : array_like, shape (p, n), m/N, all > 0
    alpha0 : array_like, shape (m,)
        Start (clipped into the box).
    lower, upper : float or array_like (m,)
        Search box; ``lower`` must be > -1.
    max_fe_runs : int
        Budget of residual evaluations (scipy's ``max_nfev``; each
        iteration costs one, plus one Jacobian).
    xtol : float
        scipy's step tolerance (relative to ``x_scale = "jac"``).
    search_jacobian : {"exact", "2-point"}

    Returns
    -------
    LogFit
    """
    from ..solvers.sensitivity import log_amplitude_jacobian

    freqs, lo, hi, log_residual = _log_problem(model, freqs_hz, measured_amplitude, lower, upper)
    counts = {"fe": 0, "jac": 0}
    cache: dict[bytes, np.ndarray] = {}

    def fun(a):
        counts["fe"] += 1
        return log_residual(a)

    def jac(a):
        key = np.asarray(a, float).tobytes()
        if key not in cache:
            counts["jac"] += 1
            cache.clear()
            cache[key] = log_amplitude_jacobian(model, a, freqs)
        return cache[key]

    if search_jacobian not in ("exact", "2-point"):
        raise ValueError(f"search_jacobian must be 'exact' or '2-point', got {search_jacobian!r}")
    x0 = np.clip(np.asarray(alpha0, float), lo, hi)
    extra = {"jac": jac} if search_jacobian == "exact" else {"jac": "2-point", "diff_step": 1e-6}
    res = optimize.least_squares(fun, x0, bounds=(lo, hi), method="trf", x_scale="jac", xtol=xtol, ftol=1e-12,
                                 gtol=1e-12, max_nfev=max_fe_runs, **extra)
    J = jac(res.x)  # cached when scipy's last Jacobian was at the optimum
    log.info("log-amplitude least squares: %s after %d FE runs and %d Jacobians", res.message, counts["fe"],
             counts["jac"])
    return LogFit(alpha=res.x, residual=res.fun, jacobian=J, fe_runs=counts["fe"], jacobians=counts["jac"],
                  status=str(res.message))


@dataclass(frozen=True)
class RefinedIntervals:
    """Intervals after Gauss-Newton steps from an update's result (:func:`parameter_intervals`).

    Attributes
    ----------
    intervals : Intervals
        Centred on the refined least-squares estimate.
    start : ndarray, shape (m,)
        The update's result the steps started from.
    residual : ndarray, shape (p * n,)
        Log residual at ``intervals.estimate``.
    last_step_in_std : float
        Largest ``|step_i| / std_i`` of the last Gauss-Newton step computed
        (taken or not): below ``step_tolerance`` the estimate is at the
        optimum as far as the intervals can tell.
    at_optimum : bool
    fe_runs : int
        FRF evaluations besides the Jacobians (0: each Jacobian brings its FRF).
    jacobians : int
        Exact Jacobians (with their FRF) the intervals cost.
    jacobian : ndarray, shape (p * n, m)
        ``d residual / d alpha`` at the estimate.
    """

    intervals: Intervals
    start: np.ndarray
    residual: np.ndarray
    last_step_in_std: float
    at_optimum: bool
    fe_runs: int
    jacobians: int
    jacobian: np.ndarray | None = None


def parameter_intervals(model, freqs_hz, measured_amplitude, alpha0, lower, upper, noise: float | None = None,
                        level: float = 0.95, width_threshold: float = WIDTH_THRESHOLD, max_jacobians: int = 3,
                        step_tolerance: float = 0.1) -> RefinedIntervals:
    """Laplace intervals at the log-amplitude least-squares optimum near an update's result.

    The update's result (the polish's best FE run) is within a fraction of
    an interval of the optimum, but it minimised the relative residual and
    stopped when it stalled, so Gauss-Newton steps with the exact Jacobian
    (:func:`fe_core.solvers.sensitivity.log_amplitude_jacobian`) finish the job:
    ``step = -(J^T J)^-1 J^T r``, taken (clipped to the box) while it lowers
    ``||r||^2``, until the step is below ``step_tolerance`` standard
    deviations in every parameter or ``max_jacobians`` Jacobians are spent.
    The intervals (:func:`laplace_intervals`) then use the Jacobian and the
    residual at the final estimate. Each point costs one Jacobian, whose
    Krylov space gives the FRF (hence the residual) too: one Jacobian (about
    2 FE runs of time on the benchmark) when the start is already at the
    optimum, one more per step.

    Parameters
    ----------
    model, freqs_hz, measured_amplitude, alpha0, lower, upper
        As in :func:`fit_log_amplitudes`.
    noise : float, optional
        Relative amplitude noise (standard deviation); estimated when None.
    level, width_threshold : float
        As in :func:`laplace_intervals`.
    max_jacobians : int
        At least 1.
    step_tolerance : float
        In standard deviations.

    Returns
    -------
    RefinedIntervals
    """
    from ..solvers.sensitivity import log_amplitude_jacobian

    freqs, lo, hi, _ = _log_problem(model, freqs_hz, measured_amplitude, lower, upper)
    log_u = np.log(np.asarray(measured_amplitude, float)).ravel()

    def at(alpha):  # residual and Jacobian from one Krylov space
        J, Z = log_amplitude_jacobian(model, alpha, freqs, return_frf=True)
        return np.log(np.abs(Z)).ravel() - log_u, J

    return _gauss_newton_intervals(at, alpha0, lo, hi, model.parameter_names, noise, level, width_threshold,
                                   max_jacobians, step_tolerance)


#: A Gauss-Newton step (in the parameters) below which the point counts as the optimum: the FRF's own accuracy.
RESOLVABLE_STEP = 1e-8


def _gauss_newton_intervals(at, start, lo, hi, names, noise, level, width_threshold, max_jacobians, step_tolerance,
                            absent_at_zero=None) -> RefinedIntervals:
    """Gauss-Newton steps from ``start`` (``at(theta) -> (residual, jacobian)``), then Laplace intervals."""
    if max_jacobians < 1:
        raise ValueError(f"max_jacobians must be at least 1, got {max_jacobians}")
    start = np.clip(np.asarray(start, float), lo, hi)
    a = start
    r, J = at(a)
    jacobians = 1

    def intervals(r, J, a):
        iv = laplace_intervals(r, J, a, names=names, noise=noise, level=level, lower=lo, upper=hi,
                               width_threshold=width_threshold)
        if absent_at_zero is None:
            return iv
        absent = np.asarray(absent_at_zero, bool)
        unpinned = np.where(absent, (iv.low <= 0) & (0 <= iv.high), iv.unpinned)
        return replace(iv, unpinned=unpinned, absent_at_zero=absent)

    while True:
        iv = intervals(r, J, a)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            in_std = float(np.nanmax(np.abs(step) / iv.std)) if np.isfinite(iv.std).any() else float("inf")
        # A step beneath what the FRF resolves (the FE core's 1e-9 between methods) is the optimum as far as
        # the model can tell: on noise-free data the standard deviations are round-off and so is the step.
        settled = in_std <= step_tolerance or float(np.max(np.abs(step))) <= RESOLVABLE_STEP
        if settled or jacobians >= max_jacobians:
            break
        a_new = np.clip(a + step, lo, hi)
        r_new, J_new = at(a_new)
        jacobians += 1
        if not r_new @ r_new < r @ r:
            log.warning("intervals: a Gauss-Newton step of %.3g standard deviations did not lower the residual; "
                        "the linearisation is poor here", in_std)
            break
        a, r, J = a_new, r_new, J_new
    log.info("intervals: %d Jacobians (each with its FRF), last Gauss-Newton step %.3g standard deviations",
             jacobians, in_std)
    return RefinedIntervals(intervals=iv, start=start, residual=r, last_step_in_std=in_std,
                            at_optimum=bool(settled), fe_runs=0, jacobians=jacobians, jacobian=J)


def extended_intervals(model, freqs_hz, measured_amplitude, alpha0, applied, alpha_bounds=(-0.95, 1.0),
                       noise: float | None = None, level: float = 0.95, width_threshold: float = WIDTH_THRESHOLD,
                       max_jacobians: int = 3, step_tolerance: float = 0.1, names=None) -> RefinedIntervals:
    """Laplace intervals of alpha *and* the values of added effects (a closure's extended model).

    The same as :func:`parameter_intervals` on ``theta = [alpha, values of
    each applied effect in order]``, with the exact Jacobian of the extended
    model (:func:`fe_core.solvers.sensitivity.extended_log_jacobian`: every column,
    effects' included, a derivative on one Krylov space; a sensor gain's
    analytic). The box is ``alpha_bounds`` for alpha and each effect's
    plausible range (:meth:`fe_core.closure.effects.Effect.bounds_at`); an effect
    value whose interval contains zero is flagged (the data do not tell the
    effect from its absence), alpha as in :func:`laplace_intervals`.

    Parameters
    ----------
    model : ParametricModel
    freqs_hz : array_like, shape (p,), Hz
    measured_amplitude : array_like, shape (p, n), m/N
    alpha0 : array_like, shape (m,)
    applied : sequence of fe_core.closure.effects.Applied
        The effects with their fitted values (the start of the steps).
    alpha_bounds : (float, float)
    noise, level, width_threshold, max_jacobians, step_tolerance
        As in :func:`parameter_intervals`.
    names : list of str, optional
        Of the m + k parameters; ``alpha_i`` and ``<kind>.<parameter>`` by default.

    Returns
    -------
    RefinedIntervals
        ``intervals.estimate`` is the refined ``theta``.
    """
    from ..closure.effects import Applied
    from ..solvers.sensitivity import extended_log_jacobian

    applied = list(applied)
    m = model.n_segments  # the extended model's alpha; mass factors stay nominal there (extended_matrices)
    freqs, lo_a, hi_a, _ = _log_problem(model, freqs_hz, measured_amplitude, alpha_bounds[0], alpha_bounds[1], m)
    log_u = np.log(np.asarray(measured_amplitude, float)).ravel()
    sizes = np.cumsum([m] + [item.effect.n_parameters for item in applied])
    bounds = [item.effect.bounds_at(item.location) for item in applied]
    lo = np.concatenate([lo_a] + [b[0] for b in bounds])
    hi = np.concatenate([hi_a] + [b[1] for b in bounds])
    start = np.concatenate([np.asarray(alpha0, float)] + [np.atleast_1d(np.asarray(item.values, float))
                                                            for item in applied])
    if names is None:
        names = [f"alpha_{i + 1}" for i in range(m)] + [f"{item.effect.kind}.{p}" for item in applied
                                                        for p in item.effect.parameters]
    if len(names) != start.size:
        raise ValueError(f"{len(names)} names for {start.size} parameters")

    def at(theta):
        now = [Applied(item.effect, item.location, theta[a:b]) for item, a, b in zip(applied, sizes[:-1], sizes[1:])]
        J, Z = extended_log_jacobian(model, theta[:m], freqs, now)
        return np.log(np.abs(Z)).ravel() - log_u, J

    absent = np.arange(start.size) >= m
    return _gauss_newton_intervals(at, start, lo, hi, names, noise, level, width_threshold, max_jacobians,
                                   step_tolerance, absent_at_zero=absent)
