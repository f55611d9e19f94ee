"""Where the Laplace intervals' linearisation is poor: a check, and a sampled posterior on the FE model.

The Laplace intervals (:mod:`fe_core.inference.laplace`) treat the model as linear
within the intervals and ignore the search box. Two things break that:
an interval that crosses a bound of the box (the posterior is cut there),
and a curved or skewed valley (a wide, poorly determined parameter).

:func:`linearity_check`
    For the parameters in question, the cost ``||r||^2`` at both ends of
    the interval along the parameter's profile direction
    ``d_i = q C[:, i] / std_i`` (the point where the linear model's profile
    cost has risen by ``q^2 sigma^2``; ``q`` the interval's quantile). Its
    ratio to ``q^2 sigma^2`` is 1 for a linear model; an end outside the
    box, or a ratio off 1 by more than ``tolerance``, makes the
    linearisation poor. Two FE runs per parameter checked.

:func:`importance_posterior`
    The posterior ``p(theta | u) ~ exp(-||r(theta)||^2 / (2 sigma^2))`` on
    the box (uniform prior), sampled by importance sampling on the FE model:
    proposals from a multivariate Student t (``df`` degrees of freedom,
    heavier tails than the Laplace Gaussian) centred on the least-squares
    optimum with the Laplace covariance inflated by ``inflate``; proposals
    outside the box cost nothing (weight 0), each inside one FE run, until
    ``budget`` FE runs are spent, in two rounds: the second proposes from the
    first's weighted samples, weights against the mixture of both. The intervals are the weighted 2.5 % and
    97.5 % quantiles of each marginal, the covariance the weighted one; the
    effective sample size ``(sum w)^2 / sum w^2`` says how far the posterior
    is from the proposal (and how much to trust the quantiles). Chosen over
    MCMC because its FE runs are independent (parallel, no burn-in, no
    chain to tune) and its weights measure the Laplace approximation's error
    directly; with a proposal this close, a few hundred FE runs suffice.

Plain numpy/scipy.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import special

__all__ = ["LinearityCheck", "linearity_check", "Posterior", "importance_posterior", "sampled_summary",
           "laplace_reason", "LINEARITY_TOLERANCE", "POSTERIOR_BUDGET", "MIN_ESS"]

log = logging.getLogger(__name__)

#: A profile cost at an interval's end off the linear model's by more than this share is "poor".
LINEARITY_TOLERANCE = 0.25
#: Default FE runs of the sampled posterior.
POSTERIOR_BUDGET = 400
#: Below this effective sample size the sampled intervals are reported as uncertain.
MIN_ESS = 50


@dataclass(frozen=True)
class LinearityCheck:
    """The profile cost at the intervals' ends against the linear model's (:func:`linearity_check`).

    Attributes
    ----------
    names : list of str
    checked : ndarray of bool, shape (m,)
    ratio : ndarray, shape (m, 2)
        ``(cost(end) - cost(optimum)) / (q^2 sigma^2)`` at the lower and upper end;
        NaN where not checked or where the end lies outside the box.
    outside : ndarray of bool, shape (m, 2)
        The end lies outside the box (not evaluated).
    tolerance : float
    fe_runs : int
    """

    names: list
    checked: np.ndarray
    ratio: np.ndarray
    outside: np.ndarray
    tolerance: float
    fe_runs: int

    @property
    def poor(self) -> np.ndarray:
        """Per parameter: an end outside the box or a ratio off 1 by more than the tolerance."""
        off = np.abs(self.ratio - 1.0) > self.tolerance
        return self.checked & (self.outside.any(axis=1) | np.nan_to_num(off, nan=False).any(axis=1))

    def reasons(self) -> list[str]:
        """Why the linearisation is poor, one sentence per parameter (empty if it is not)."""
        lines = []
        for i in np.flatnonzero(self.poor):
            name = self.names[i]
            ends = [f"{r:.2f} times the linear model's at the {side} end" for r, side in
                    zip(self.ratio[i], ("lower", "upper")) if np.isfinite(r)]
            text = f"along {name}'s interval the cost rises " + " and ".join(ends) if ends else ""
            if self.outside[i].any():
                cut = f"{name}'s interval crosses a bound of the search box (the posterior is cut there)"
                text = cut + (f"; {text[0].lower()}{text[1:]}" if text else "")
            else:
                text += f" (tolerance {self.tolerance:g})"
            lines.append(text)
        return lines

    def to_dict(self) -> dict:
        def num(x):
            return float(x) if np.isfinite(x) else None

        return {"checked": [n for n, c in zip(self.names, self.checked) if c],
                "ratio": {n: [num(a), num(b)] for n, c, (a, b) in zip(self.names, self.checked, self.ratio) if c},
                "poor": [n for n, p in zip(self.names, self.poor) if p], "tolerance": self.tolerance,
                "fe_runs": self.fe_runs, "reasons": self.reasons()}


def linearity_check(residual, intervals, optimum_residual, lower, upper, which=None,
                    tolerance: float = LINEARITY_TOLERANCE) -> LinearityCheck:
    """Profile cost at both ends of the intervals of ``which`` against the linear model's.

    Parameters
    ----------
    residual : callable
        ``residual(theta) -> ndarray (N,)``, the log residual (one FE run).
    intervals : fe_core.inference.intervals.Intervals
        Laplace intervals at the optimum ``intervals.estimate``.
    optimum_residual : ndarray, shape (N,)
        The residual at the optimum.
    lower, upper : float or array_like (m,)
        The search box.
    which : array_like of bool, shape (m,), optional
        Parameters to check; by default the flagged ones (not pinned down or
        crossing the box), where a linearisation error could matter.
    tolerance : float

    Returns
    -------
    LinearityCheck
    """
    iv = intervals
    m = iv.estimate.size
    lo = np.broadcast_to(np.asarray(lower, float), (m,))
    hi = np.broadcast_to(np.asarray(upper, float), (m,))
    which = (iv.unpinned | iv.near_bound) if which is None else np.asarray(which, bool)
    which = which & np.isfinite(iv.std)
    r0 = np.asarray(optimum_residual, float).ravel()
    c0 = float(r0 @ r0)
    scale = iv.quantile**2 * iv.noise_sigma**2
    ratio = np.full((m, 2), np.nan)
    outside = np.zeros((m, 2), bool)
    runs = 0
    for i in np.flatnonzero(which):
        d = iv.quantile * iv.covariance[:, i] / iv.std[i]
        for k, sign in enumerate((-1.0, 1.0)):
            point = iv.estimate + sign * d
            if np.any(point < lo) or np.any(point > hi):
                outside[i, k] = True
                continue
            r = np.asarray(residual(point), float).ravel()
            runs += 1
            ratio[i, k] = (float(r @ r) - c0) / scale
    return LinearityCheck(names=list(iv.names), checked=which, ratio=ratio, outside=outside,
                          tolerance=float(tolerance), fe_runs=runs)


@dataclass(frozen=True)
class Posterior:
    """A sampled posterior (:func:`importance_posterior`).

    Attributes
    ----------
    names : list of str
    mean : ndarray, shape (m,)
    covariance : ndarray, shape (m, m)
    low, high : ndarray, shape (m,)
        Weighted quantiles ``(1 -/+ level) / 2`` of each marginal.
    level : float
    samples : ndarray, shape (n, m)
        The FE-evaluated proposals.
    weights : ndarray, shape (n,)
        Normalised importance weights.
    ess : float
        Effective sample size ``1 / sum w^2``.
    fe_runs : int
    outside_box : int
        Proposals outside the box (weight 0, no FE run).
    method : str
    """

    names: list
    mean: np.ndarray
    covariance: np.ndarray
    low: np.ndarray
    high: np.ndarray
    level: float
    samples: np.ndarray
    weights: np.ndarray
    ess: float
    fe_runs: int
    outside_box: int
    method: str = "importance sampling"

    @property
    def reliable(self) -> bool:
        return self.ess >= MIN_ESS


def _log_t_density(x, centre, chol, df):
    """Log density of the multivariate t with scale ``chol chol^T``, up to nothing: exact."""
    m = centre.size
    z = np.linalg.solve(chol, (x - centre).T)  # (m, n)
    maha = np.sum(z**2, axis=0)
    return (special.gammaln((df + m) / 2) - special.gammaln(df / 2) - 0.5 * m * np.log(df * np.pi)
            - np.sum(np.log(np.diag(chol))) - 0.5 * (df + m) * np.log1p(maha / df))


def _cholesky(cov):
    """Cholesky factor of a covariance, with a jitter of 1e-12 of its mean variance for round-off."""
    m = cov.shape[0]
    cov = 0.5 * (cov + cov.T)
    return np.linalg.cholesky(cov + 1e-12 * np.trace(cov) / m * np.eye(m))


def _weighted_quantile(x, w, q):
    order = np.argsort(x)
    cw = np.cumsum(w[order])
    cw /= cw[-1]
    return float(np.interp(q, cw - 0.5 * w[order] / w.sum(), x[order]))


def importance_posterior(residual, intervals, lower, upper, rng: np.random.Generator,
                         budget: int = POSTERIOR_BUDGET, df: float = 4.0, inflate: float = 1.5, rounds: int = 2,
                         max_draws: int | None = None) -> Posterior:
    """Importance sampling of ``exp(-||r||^2 / (2 sigma^2))`` on the box around a Laplace approximation.

    ``rounds`` rounds of ``budget / rounds`` FE runs each: the first proposes
    from the Laplace approximation (Student t, scale ``inflate`` times its
    standard deviations), each later one from a Student t fitted to the
    weighted samples so far (their mean and covariance, inflated by 1.2):
    the proposal moves toward the posterior where the linearisation was
    wrong. All samples are weighted against the mixture of the proposals
    (deterministic-mixture weights), which keeps the estimate unbiased.

    Parameters
    ----------
    residual : callable
        ``residual(theta) -> ndarray (N,)``, one FE run.
    intervals : fe_core.inference.intervals.Intervals
        The Laplace approximation (estimate, covariance, noise, level).
    lower, upper : float or array_like (m,)
    rng : numpy.random.Generator
    budget : int
        FE runs to spend (proposals inside the box).
    df : float
        Degrees of freedom of the Student-t proposals.
    inflate : float
        Scale of the first proposal relative to the Laplace standard deviations.
    rounds : int
    max_draws : int, optional
        Most proposals drawn per round (inside or outside the box); 50 x its budget by default.

    Returns
    -------
    Posterior
    """
    iv = intervals
    m = iv.estimate.size
    if not np.all(np.isfinite(iv.covariance)):
        raise ValueError("the Laplace covariance is not finite: a parameter the data do not see cannot be sampled")
    lo = np.broadcast_to(np.asarray(lower, float), (m,))
    hi = np.broadcast_to(np.asarray(upper, float), (m,))
    sigma2 = iv.noise_sigma**2
    proposals = []  # (centre, cholesky, number of FE-evaluated samples)
    X = np.empty((0, m))
    log_target = np.empty(0)
    outside = 0
    centre, cov = iv.estimate, 0.5 * (iv.covariance + iv.covariance.T) * inflate**2
    per_round = [budget // rounds + (1 if k < budget % rounds else 0) for k in range(rounds)]
    w = None
    chol = _cholesky(cov)
    for n_round in per_round:
        limit = 50 * n_round if max_draws is None else max_draws
        new, drawn = [], 0
        while len(new) < n_round and drawn < limit:
            batch = min(4 * (n_round - len(new)), limit - drawn)
            g = rng.standard_normal((batch, m))
            chi = rng.chisquare(df, batch)
            x = centre + (g @ chol.T) * np.sqrt(df / chi)[:, None]
            drawn += batch
            inside = np.all((x >= lo) & (x <= hi), axis=1)
            outside += int(np.sum(~inside))
            new.extend(x[inside][: n_round - len(new)])
        if not new:
            continue
        new = np.array(new)
        values = []
        for theta in new:
            r = np.asarray(residual(theta), float).ravel()
            values.append(-0.5 * float(r @ r) / sigma2)
        proposals.append((centre, chol, len(new)))
        X = np.vstack([X, new])
        log_target = np.concatenate([log_target, values])
        # Deterministic-mixture weights of every sample so far against every proposal so far.
        n_all = sum(n for _, _, n in proposals)
        log_q = np.logaddexp.reduce([np.log(n / n_all) + _log_t_density(X, c, L, df) for c, L, n in proposals],
                                    axis=0)
        log_w = log_target - log_q
        w = np.exp(log_w - log_w.max())
        w /= w.sum()
        # The next proposal: the weighted samples' mean and covariance, if they are worth it (enough
        # effective samples to estimate a covariance); else the same proposal again.
        if 1.0 / np.sum(w**2) >= 2 * m + 2:
            mean_w = w @ X
            D = X - mean_w
            try:
                chol_w = _cholesky(1.2**2 * ((D * w[:, None]).T @ D))
            except np.linalg.LinAlgError:
                pass
            else:
                centre, chol = mean_w, chol_w
    if w is None:
        raise ValueError("no proposal fell inside the box")
    mean = w @ X
    D = X - mean
    covariance = (D * w[:, None]).T @ D
    a = (1.0 - iv.level) / 2
    low = np.array([_weighted_quantile(X[:, i], w, a) for i in range(m)])
    high = np.array([_weighted_quantile(X[:, i], w, 1.0 - a) for i in range(m)])
    ess = float(1.0 / np.sum(w**2))
    log.info("posterior: %d FE runs in %d rounds (%d proposals outside the box), effective sample size %.0f",
             len(X), len(proposals), outside, ess)
    return Posterior(names=list(iv.names), mean=mean, covariance=covariance, low=low, high=high, level=iv.level,
                     samples=X, weights=w, ess=ess, fe_runs=len(X), outside_box=outside)


def _num(x):
    return float(x) if np.isfinite(x) else None  # JSON has no inf


def laplace_reason(laplace, check: LinearityCheck | None) -> str:
    """Why the Laplace intervals were kept, in words."""
    if check is None or not check.checked.any():
        return ("laplace: every interval is narrower than the threshold and inside the search box, where the "
                "coverage study found the linearisation right")
    return (f"laplace: the linearity check along {', '.join(n for n, c in zip(check.names, check.checked) if c)} "
            f"passed (profile cost within {check.tolerance:.0%} of the linear model's at both ends)")


def sampled_summary(laplace, check: LinearityCheck, post: Posterior, budget: int) -> dict:
    """The ``summary.json`` interval fields when the sampled posterior replaces the Laplace intervals.

    ``intervals`` and ``covariance`` are the posterior's (weighted quantiles and covariance),
    ``interval_method`` is ``"importance sampling"``; ``interval_details`` keeps the least-squares
    estimate, adds the posterior's standard deviations and correlation, the Laplace intervals
    (``laplace``), the check (``linearity``), why (``method_reason``) and the sampling's diagnostics
    (``posterior``).
    """
    base = laplace.to_summary()
    d = base["interval_details"]
    names = laplace.names
    std = np.sqrt(np.diag(post.covariance))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = post.covariance / np.outer(std, std)
    unpinned = post.high - post.low > laplace.width_threshold
    d["laplace"] = {"intervals": base["intervals"], "std": d["std"], "covariance": base["covariance"],
                    "unpinned": d["unpinned"], "near_bound": d["near_bound"]}
    d["std"] = {n: _num(s) for n, s in zip(names, std)}
    d["correlation"] = [[_num(c) for c in row] for row in corr]
    d["unpinned"] = [n for n, f in zip(names, unpinned) if f]
    d["near_bound"] = []  # the sampled posterior lives on the box
    d["linearity"] = check.to_dict()
    d["method_reason"] = "importance sampling: " + "; ".join(check.reasons())
    d["posterior"] = {"mean": dict(zip(names, map(float, post.mean))), "ess": round(post.ess, 1),
                      "fe_runs": post.fe_runs, "budget": int(budget), "outside_box": post.outside_box,
                      "reliable": post.reliable, "level": post.level}
    pct = f"{post.level:.0%}"
    flags = [f"The Laplace linearisation failed its check along {', '.join(n for n, p in zip(names, check.poor) if p)}"
             f": the {pct} intervals are quantiles of the posterior sampled on the FE model ({post.fe_runs} FE runs, "
             f"effective sample size {post.ess:.0f})."]
    if not post.reliable:
        flags.append(f"The effective sample size {post.ess:.0f} is below {MIN_ESS}: the sampled intervals are "
                     "rough; a larger posterior_fe would sharpen them.")
    for n, f, lo, hi in zip(names, unpinned, post.low, post.high):
        if f:
            flags.append(f"{n} is not pinned down by this measurement: its {pct} interval [{lo:.3g}, {hi:.3g}] is "
                         f"{hi - lo:.3g} wide (threshold {laplace.width_threshold:g}).")
    d["flags"] = flags
    return {"intervals": {n: [float(lo), float(hi)] for n, lo, hi in zip(names, post.low, post.high)},
            "covariance": [[float(c) for c in row] for row in post.covariance],
            "interval_method": post.method, "noise_sigma": base["noise_sigma"], "interval_details": d}
