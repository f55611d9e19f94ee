"""Trust-region Gauss-Newton on exact FRF derivatives, with a composite local model.

One step needs the complex receptance ``Z`` (shape (k,), the k measured
(frequency, sensor) pairs) and its exact derivative ``dZ`` (shape (k, m)) at
the current point; the fitted quantity is the relative amplitude residual of
Eq. 5, ``r = |Z| / u - 1``. The local model is *composite* (Astudillo and
Frazier 2019): the model's response is linearised and the residual computed
from it exactly, instead of linearising the residual itself. Which response
is linearised (``model``):

* ``"inverse"`` (default): the inverse receptance ``1 / Z``, linear in a
  segment's stiffness when one mode dominates (``1 / Z ~ (k - w^2 m + j w c)
  / phi^2``), so the model follows the resonance's sharp amplitude change
  over a wider trust region than a linear model of ``r``;
* ``"receptance"``: ``Z`` itself;
* ``"linear"``: the residual ``r`` (classical Gauss-Newton).

Measured on the benchmark from the nominal model (exact Jacobians, one trial
point per step; docs/results/suite.md): the linear model jumped to a wrong basin on 2
of 10 truths, the inverse model on none.

The stepper is an ask-tell object (:class:`TrustRegionGN`): ``propose`` gives
the next trial point, ``tell`` takes its result, so a caller can run several
of them side by side and evaluate their trial points in one parallel round.
Deterministic: the same results give the same sequence of points.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

__all__ = ["MODELS", "composite_model", "residual_jacobian", "TrustRegionGN", "Step"]

MODELS = ("inverse", "receptance", "linear")

#: Trust-region radius bounds (max-norm, parameter units).
MIN_RADIUS = 1e-9
MAX_RADIUS = 1.0


def residual_jacobian(Z: np.ndarray, dZ: np.ndarray, residual) -> np.ndarray:
    """``d r / d theta`` of ``residual`` (:class:`fe_core.inference.frf_data.FRFData`) at ``Z`` (k,) from ``dZ``
    (k, m): shape (k, m), or (2 k, m) with complex residuals."""
    return residual.jacobian(Z, dZ)


def composite_model(Z: np.ndarray, dZ: np.ndarray, residual, model: str = "inverse") -> Callable:
    """The local model ``s -> r(x + s)`` for a step s of shape (m,).

    Parameters
    ----------
    Z : ndarray, shape (k,), complex, m/N
    dZ : ndarray, shape (k, m), complex, m/N per unit parameter
    residual : FRFData
        The measured data at the k values (:class:`fe_core.inference.frf_data.FRFData`): ``residual(Z)`` is the
        relative residual.
    model : {"inverse", "receptance", "linear"}
    """
    Z, dZ = np.asarray(Z), np.asarray(dZ)
    if model == "linear":
        r0, J = residual(Z), residual_jacobian(Z, dZ, residual)
        return lambda s: r0 + J @ s
    if model == "receptance":
        return lambda s: residual(Z + dZ @ s)
    if model == "inverse":
        g, dg = 1.0 / Z, -dZ / (Z**2)[:, None]
        return lambda s: residual(1.0 / (g + dg @ s))
    raise ValueError(f"unknown local model {model!r}; choose one of {', '.join(MODELS)}")


@dataclass
class Step:
    """One trial point: where, and the objective the local model predicted there."""

    x: np.ndarray
    predicted: float


@dataclass
class TrustRegionGN:
    """Ask-tell trust-region Gauss-Newton from a point with known Z and dZ.

    Parameters (attributes)
    ----------
    x : ndarray, shape (m,)
        Current centre.
    Z, dZ : its receptance (k,) and derivative (k, m).
    residual : FRFData
        The measured data at the k values; ``residual(Z)`` is the relative residual, the objective is its
        sum of squares.
    lower, upper : ndarray, shape (m,)
        Search box.
    radius : float
        Trust-region radius (max-norm).
    model : str
        Local model (:data:`MODELS`).

    The objective is ``f = sum r^2``. A trial with ``rho = (f - f_new) /
    (f - f_predicted) > 0.75`` that used most of the radius multiplies it by
    ``expand``; a trial that did not decrease ``f`` shrinks the radius to
    ``shrink`` times its step; ``rho < 0.25`` halves it.
    """

    x: np.ndarray
    Z: np.ndarray
    dZ: np.ndarray
    residual: object
    lower: np.ndarray
    upper: np.ndarray
    radius: float = 0.2
    model: str = "inverse"
    shrink: float = 0.25
    expand: float = 2.0
    steps: int = 0
    rejected: int = 0
    trace: list = field(default_factory=list)  # f after every tell

    def __post_init__(self) -> None:
        self.x = np.asarray(self.x, float).copy()
        self.lower, self.upper = np.asarray(self.lower, float), np.asarray(self.upper, float)
        self.f = self.objective(self.Z)
        self._pending: list[Step] = []

    @property
    def residuals(self) -> np.ndarray:
        return self.residual(self.Z)

    @property
    def error(self) -> float:
        """Overall error (Eq. 6b) at the centre."""
        return self.residual.error(self.Z)

    def objective(self, Z: np.ndarray) -> float:
        r = self.residual(Z)
        return float(r @ r) if np.all(np.isfinite(r)) else np.inf

    def propose(self, scale: float = 1.0) -> Step:
        """The minimiser of the local model inside the trust region (radius times ``scale``) and the box.

        Several calls before one :meth:`tell` give trial points at several radii
        (to evaluate in one round); :meth:`tell` then takes the one chosen.
        """
        rad = max(self.radius * scale, MIN_RADIUS)
        lo = np.maximum(self.lower, self.x - rad) - self.x
        hi = np.minimum(self.upper, self.x + rad) - self.x
        hi = np.where(hi - lo > 0, hi, lo + MIN_RADIUS)  # a centre on a bound keeps a sliver to move in
        fun = composite_model(self.Z, self.dZ, self.residual, self.model)
        sol = least_squares(fun, np.clip(np.zeros_like(self.x), lo, hi), bounds=(lo, hi), method="trf",
                            max_nfev=100, xtol=1e-12, ftol=1e-12, gtol=1e-12)
        step = Step(self.x + sol.x, float(2.0 * sol.cost))
        self._pending.append(step)
        return step

    def tell(self, x: np.ndarray, Z: np.ndarray, dZ: np.ndarray | None) -> bool:
        """The result at a proposed point; returns whether it became the centre.

        ``dZ`` may be None (no derivative computed there): the point can then
        only be accepted with a Broyden update of ``dZ``.
        """
        match = [p for p in self._pending if np.array_equal(np.asarray(x, float), p.x)]
        if not match:
            raise ValueError("tell() needs a point proposed since the last tell()")
        step = match[0]
        self._pending = []
        f_new = self.objective(Z)
        s = step.x - self.x
        size = float(np.max(np.abs(s)))
        predicted = self.f - step.predicted
        rho = (self.f - f_new) / predicted if predicted > 0 else -np.inf
        accepted = bool(f_new < self.f)
        if accepted:
            if dZ is None:  # Broyden: the secant condition dZ_new s = Z_new - Z
                dZ = self.dZ + np.outer(Z - self.Z - self.dZ @ s, s) / float(s @ s)
            self.x, self.Z, self.dZ, self.f = step.x.copy(), np.asarray(Z), np.asarray(dZ), f_new
            self.steps += 1
            if rho > 0.75 and size > 0.5 * self.radius:
                self.radius = min(self.expand * max(self.radius, size), MAX_RADIUS)
            elif rho < 0.25:
                self.radius = max(0.5 * size, MIN_RADIUS)
        else:
            self.rejected += 1
            self.radius = max(self.shrink * size, MIN_RADIUS)
        self.trace.append(self.f)
        return accepted

    def step_in_std(self) -> float:
        """The Gauss-Newton step from the centre (the linear model, kept in the box) measured in standard
        deviations along itself: ``||J s|| / sigma``, with ``sigma^2 = r^T r / (N - m)`` the residual's own
        variance, the Mahalanobis length of ``s`` under the covariance ``sigma^2 (J^T J)^-1`` (no less than the
        step of any one parameter in its own standard deviations). Infinite where that says nothing (a zero or
        non-finite residual, no more values than parameters)."""
        r = self.residuals
        J = residual_jacobian(self.Z, self.dZ, self.residual)
        n, m = J.shape
        rss = float(r @ r)
        if n <= m or not (np.isfinite(rss) and rss > 0) or not np.all(np.isfinite(J)):
            return float("inf")
        s = np.linalg.lstsq(J, -r, rcond=None)[0]
        s = np.clip(self.x + s, self.lower, self.upper) - self.x
        return float(np.linalg.norm(J @ s) / np.sqrt(rss / (n - m)))

    def stalled(self, window: int, rtol: float) -> bool:
        """The objective improved by less than ``rtol`` (relative) over the last ``window`` tells,
        or the radius has collapsed."""
        if self.radius <= 1e3 * MIN_RADIUS:
            return True
        if len(self.trace) <= window:
            return False
        before = self.trace[-window - 1]
        return before - self.trace[-1] <= rtol * before
