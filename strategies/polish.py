"""Local polish: trust-region least squares on the FE model, after the MRGP loop.

The adaptive MRGP loop finds the basin of the measured response with few FE
runs, but a Gaussian-process emulator of ~200 runs cannot resolve the last
per cent of error (the sampling distribution collapses around an emulator
artefact before the residual reaches the noise). Near the optimum the
problem is a smooth, well-posed nonlinear least-squares problem, so a
Gauss-Newton type method on the FE model itself converges quadratically
from there. This module runs :func:`scipy.optimize.least_squares` (``trf``,
forward-difference Jacobian) on the relative residuals of Eq. (5), started
from the best FE-evaluated sample, with three additions:

* every point is evaluated through a caller-supplied batch function, so the
  columns of a finite-difference Jacobian (absolute steps, so that a
  parameter at 0 gets a proper one; a failed column is retried on the other
  side) run in parallel and the caller can store (and on resume replay)
  each FE run;
* identical points are evaluated once (memoised), including the start,
  whose residual the caller already has;
* it stops as soon as a point's overall error (Eq. 6b) reaches ``target``,
  when the next batch would exceed ``max_evaluations`` FE runs, or when the
  best overall error has stagnated (improved by less than ``stall_rtol``
  relative over the last ``stall_window`` FE runs, three Jacobians by
  default), and returns the best point seen. On noisy data the error
  cannot reach ``target``: it levels off at the noise, and without the
  stagnation stop the polish would spend its whole budget there (on the
  far-from-nominal data set with 1 % noise of ``benchmarks.compare``, 40-85
  FE runs after the floor was reached).

The procedure is deterministic: the same start and the same FE results give
the same sequence of requested points, which is what makes a killed polish
resumable from stored FE runs.

:class:`Polish` is the same procedure as an ask-tell strategy (:mod:`.base`), by replay: each time it is
asked for its next batch it runs :func:`polish` again from the start against the results it has been told,
and the first batch of points it has no result for is that batch (the replay costs some least-squares
algebra, no FE run: exact, and as deterministic as the procedure). The ``adaptive`` strategy is the paper's
loop followed by it (:class:`.sequence.Sequence`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .base import Batch, Report, StopDecision
from .options import setting

__all__ = ["PolishResult", "polish", "FAILED_RESIDUAL", "PolishOptions", "Polish", "STAGE"]

log = logging.getLogger(__name__)

#: The stage of the run folder the polish's FE runs go to.
STAGE = "polish"


@dataclass(frozen=True)
class PolishOptions:
    """Settings of the polish after the paper's loop (the ``adaptive`` strategy)."""

    enabled: bool = setting(True, key="polish", help="after the MRGP loop (adaptive strategy only), least squares "
                            "on the FE model from the best sample; its FE runs count in fe_evaluations")
    max_evaluations: int = setting(200, key="polish_max_fe", metavar="N", help="FE runs reserved for the polish "
                                   "out of max_fe_evaluations: the MRGP loop stops at max_fe_evaluations - "
                                   "polish_max_fe (default 200 of 240: the loop hands over after 2 iterations, "
                                   "git show 0cbca1f:docs/handover.md)")
    target: float = setting(1e-4, key="polish_target", metavar="E", help="overall error at which the polish (and "
                            "the hybrid's Gauss-Newton) stops, e.g. 1e-4 = 0.01 % (the floor of noise-free data; "
                            "set it near the measurement's noise for real data)")
    stall_rtol: float = setting(0.01, key="polish_stall_rtol", metavar="R", help="the polish also stops when its "
                                "error improved by less than R (relative) over its last 3 Jacobians and steps, "
                                "e.g. at the noise of real data (0 = off)")
    diff_step: float = 1e-6
    tolerance: float = 1e-12

#: Residual given to the optimiser for a failed FE run: large, finite, so the
#: trust region shrinks away from the point instead of the solver stopping.
FAILED_RESIDUAL = 1e3


@dataclass(frozen=True)
class PolishResult:
    """Outcome of :func:`polish`.

    Attributes
    ----------
    x : ndarray, shape (m,)
        Best point seen (smallest overall error).
    residuals : ndarray, shape (p * n,)
        Its relative residuals.
    error : float
        Its overall error (mean absolute relative residual, Eq. 6b).
    error_start : float
        Overall error of the start point.
    evaluations : int
        New function (FE) evaluations made; the start point is not counted
        when its residuals were supplied.
    status : str
        ``"target"`` (error reached ``target``), ``"budget"`` (next batch would
        exceed ``max_evaluations``), ``"stagnated"`` (the best error improved
        by less than ``stall_rtol`` over the last ``stall_window`` runs, e.g.
        at the noise floor), ``"converged"`` (the optimiser's tolerances) or
        ``"stalled"`` (the optimiser stopped otherwise).
    message : str
    points : list of ndarray
        Every evaluated point in request order (the start first when supplied).
    """

    x: np.ndarray
    residuals: np.ndarray
    error: float
    error_start: float
    evaluations: int
    status: str
    message: str
    points: list = field(default_factory=list, repr=False)


class _Stop(Exception):
    def __init__(self, status: str, message: str):
        super().__init__(message)
        self.status, self.message = status, message


def polish(
    evaluate: Callable[[list[np.ndarray]], Sequence[np.ndarray]],
    x0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    residuals0: np.ndarray | None = None,
    target: float = 1e-4,
    max_evaluations: int = 40,
    diff_step: float = 1e-6,
    tolerance: float = 1e-12,
    stall_window: int | None = None,
    stall_rtol: float = 1e-2,
) -> PolishResult:
    """Trust-region least squares from ``x0`` on residuals computed by ``evaluate``.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(points) -> residual vectors``, one per point, each shape
        (p * n,). It is called with batches (the columns of a finite-difference
        Jacobian), so it may run them in parallel; a failed evaluation returns
        non-finite values.
    x0 : ndarray, shape (m,)
        Start, strictly inside the bounds (it is clipped into them otherwise).
    lower, upper : ndarray, shape (m,)
        Bounds of the search.
    residuals0 : ndarray, optional
        Known residuals at ``x0`` (saves one evaluation).
    target : float
        Stop once a point's overall error (mean |residual|) is at or below this.
    max_evaluations : int
        Budget of new evaluations; a batch that would exceed it is not started.
    diff_step : float
        Finite-difference step, ``diff_step * max(1, |x_i|)``; the FE
        responses are accurate to ~1e-9, so 1e-6 gives ~1e-3 relative
        derivative accuracy, plenty for Gauss-Newton.
    tolerance : float
        ``ftol``/``xtol``/``gtol`` of the optimiser; small, so that normally
        ``target``, stagnation or the budget ends the polish.
    stall_window : int, optional
        Number of FE runs over which the best error must improve by more than
        ``stall_rtol`` (relative); default three Jacobians and steps,
        ``3 * (m + 1)``. ``0`` turns the stagnation stop off.
    stall_rtol : float
        Relative improvement below which the polish counts as stagnated.
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    span = upper - lower
    given = np.asarray(x0, float)
    x0 = np.clip(given, lower + 1e-9 * span, upper - 1e-9 * span)
    if not np.array_equal(x0, given):
        residuals0 = None  # they belong to the unclipped point
    window = 3 * (x0.size + 1) if stall_window is None else int(stall_window)
    if window < 0 or not stall_rtol >= 0:
        raise ValueError(f"stall_window must be >= 0 and stall_rtol >= 0, got {stall_window!r}, {stall_rtol!r}")
    memo: dict[bytes, np.ndarray] = {}
    points: list[np.ndarray] = []
    state = {"n": 0, "best": None}
    trace: list[float] = []  # best overall error after each new evaluation

    def record(x: np.ndarray, r: np.ndarray) -> None:
        r = np.asarray(r, float)
        memo[x.tobytes()] = r
        points.append(x.copy())
        if np.all(np.isfinite(r)):
            e = float(np.mean(np.abs(r)))
            if state["best"] is None or e < state["best"][0]:
                state["best"] = (e, x.copy(), r.copy())

    def prefetch(xs: list[np.ndarray]) -> None:
        new, seen = [], set()
        for x in xs:
            key = x.tobytes()
            if key not in memo and key not in seen:
                seen.add(key)
                new.append(x)
        if not new:
            return
        if state["n"] + len(new) > max_evaluations:
            raise _Stop("budget", f"the next {len(new)} evaluation(s) would exceed the budget of "
                                  f"{max_evaluations} ({state['n']} used)")
        results = evaluate([x.copy() for x in new])
        state["n"] += len(new)
        for x, r in zip(new, results):
            record(x, r)
            trace.append(state["best"][0] if state["best"] is not None else float("inf"))
        if state["best"] is not None and state["best"][0] <= target:
            raise _Stop("target", f"overall error {state['best'][0]:.3e} <= target {target:.3e}")
        if window and len(trace) > window:
            before, now = trace[-window - 1], trace[-1]
            if np.isfinite(before) and before - now <= stall_rtol * before:
                raise _Stop("stagnated", f"overall error {now:.3e} improved by less than {stall_rtol:.0e} "
                                         f"(relative) over the last {window} FE runs")

    def fun(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, float)
        prefetch([x])
        r = memo[x.tobytes()]
        return np.where(np.isfinite(r), r, FAILED_RESIDUAL)

    def jac(x: np.ndarray) -> np.ndarray:
        """Forward differences with an absolute step, all columns in one batch.

        The step is ``diff_step * max(1, |x_i|)`` (scipy's own relative step
        vanishes at x_i = 0, the undamaged segment), backward where the forward
        point would leave the box. A column whose point fails is tried on the
        other side once, then set to zero (that parameter rests for a step).
        """
        x = np.asarray(x, float)
        prefetch([x])
        f0 = memo[x.tobytes()]
        h = diff_step * np.maximum(1.0, np.abs(x))
        h = np.where(x + h > upper, -h, h)
        J = np.zeros((f0.size, x.size))
        todo = list(range(x.size))
        for _ in range(2):
            pts = []
            for i in todo:
                xp = x.copy()
                xp[i] += h[i]
                pts.append(xp)
            prefetch(pts)
            failed = []
            for i, xp in zip(todo, pts):
                r = memo[xp.tobytes()]
                if np.all(np.isfinite(r)):
                    J[:, i] = (r - f0) / (xp[i] - x[i])
                else:
                    failed.append(i)
            todo = [i for i in failed if lower[i] <= x[i] - h[i] <= upper[i]]
            h[todo] = -h[todo]
            if not todo:
                break
        return J

    if residuals0 is not None:
        record(x0.copy(), residuals0)
    else:
        prefetch([x0])
    error_start = state["best"][0] if state["best"] is not None else float("inf")
    if error_start <= target:
        status, message = "target", f"start error {error_start:.3e} already <= target {target:.3e}"
    else:
        try:
            sol = least_squares(fun, x0, jac=jac, bounds=(lower, upper), method="trf", x_scale=1.0,
                                ftol=tolerance, xtol=tolerance, gtol=tolerance)
            status = "converged" if sol.status > 0 else "stalled"
            message = sol.message
        except _Stop as stop:
            status, message = stop.status, stop.message
    if state["best"] is None:
        raise RuntimeError("polish: every evaluation failed, including the start")
    error, x, r = state["best"]
    return PolishResult(x=x, residuals=r, error=error, error_start=error_start, evaluations=state["n"],
                        status=status, message=message, points=points)


class _Need(Exception):
    """The replayed procedure reached a batch of points without results."""

    def __init__(self, points):
        super().__init__("new points")
        self.points = points


class Polish:
    """The polish as a strategy (:mod:`.base`): :func:`polish` from ``x0`` (with its receptance ``Z0`` at the
    kept values, known already) inside ``lower``, ``upper``, on ``residual(Z) -> r``.

    Its batches go to ``iteration=<iteration>/stage=polish``; ``threshold``: the overall error the run counts as
    converged (the paper loop's). ``start_id``: the request index of the start (the run record's sample id).
    """

    def __init__(self, x0, Z0, residual, lower, upper, options: PolishOptions = PolishOptions(), iteration: int = 1,
                 threshold: float | None = None, start_id: int | None = None):
        self.x0 = np.asarray(x0, float)
        self.residual, self.options, self.iteration = residual, options, int(iteration)
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.r0 = np.asarray(residual(np.asarray(Z0)), float)
        self.threshold, self.start_id = threshold, start_id
        self.known: dict[bytes, np.ndarray] = {}
        self.result: PolishResult | None = None
        self._need = None
        if options.max_evaluations < self.x0.size + 1:
            log.warning("polish_max_fe = %d is less than one Jacobian and a step (%d FE runs): the polish can do "
                        "nothing", options.max_evaluations, self.x0.size + 1)

    def _replay(self) -> None:
        def evaluate(points):
            if any(x.tobytes() not in self.known for x in points):
                raise _Need([np.asarray(x, float).copy() for x in points])
            return [self.known[x.tobytes()] for x in points]

        o = self.options
        try:
            self.result = polish(evaluate, self.x0, self.lower, self.upper, residuals0=self.r0, target=o.target,
                                 max_evaluations=o.max_evaluations, diff_step=o.diff_step, tolerance=o.tolerance,
                                 stall_window=None if o.stall_rtol > 0 else 0, stall_rtol=o.stall_rtol)
            self._need = None
        except _Need as need:
            self._need = need.points

    def stop(self) -> StopDecision:
        if self.result is None and self._need is None:
            self._replay()
        if self.result is None:
            return StopDecision(False, False, "continue")
        return StopDecision(True, self.converged, self.result.status)

    def propose(self) -> Batch:
        if self._need is None:
            self._replay()
        return Batch(np.array(self._need), (False,) * len(self._need), STAGE, self.iteration, STAGE)

    def update(self, batch: Batch, outcomes: Sequence) -> None:
        for x, out in zip(self._need, outcomes):
            self.known[x.tobytes()] = np.asarray(self.residual(np.asarray(out[0])), float)
        self._need = None

    @property
    def converged(self) -> bool:
        return self.threshold is not None and self.result is not None and self.result.error <= self.threshold

    def stage_info(self, iteration: int, stage: str) -> dict:
        if (iteration, stage) != (self.iteration, STAGE) or self.result is None:
            return {}
        r = self.result
        return {"n": r.evaluations, "status": r.status, "message": r.message, "start_sample_id": self.start_id,
                "error_before": r.error_start, "error_after": float(r.error)}

    def report(self) -> Report:
        r = self.result
        summary = {"status": r.status, "n": r.evaluations, "error_before": r.error_start, "error_after": float(r.error)}
        return Report(f"{r.status} after {r.evaluations} FE runs ({r.message})", self.converged,
                      fields={"polish": summary}, iterations=self.iteration, intervals=True)
