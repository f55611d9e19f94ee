"""Local first, global when the data say so (issue 17's default candidate).

Every FE run goes out in *rounds*: one call of ``evaluate(points)`` is one
batch whose runs may execute in parallel and which must finish before the
next is chosen. The strategy counts FE runs and rounds.

1. **Local phase**: DFO-LS (derivative-free Gauss-Newton, Cartis, Fiala,
   Marteau and Roberts 2019) on the relative residuals of Eq. 5 from the
   nominal model: a linear interpolation model of the residual vector,
   about one FE run per iteration, so one FE run per round.
2. **Decision**: the local phase ends at ``target``, when the best error
   improved by less than ``stall_rtol`` (relative) over ``stall_window`` FE
   runs, when DFO-LS converges, or on the budget. It is at the noise floor when the
   residual's root mean square is at most ``noise_ratio`` times the noise
   level estimated from the residual's second differences along frequency
   (:func:`fe_core.inference.residual.estimate_noise`): a local minimum in the wrong
   basin leaves a misfit that is smooth in frequency, so its estimated noise
   is far below its rms.
3. **Global phase**: when stalled above the noise, one round of ``batch``
   space-filling points (scrambled Sobol, seeded) over the box; the local
   phase restarts from the best of them (of all points so far) that lies
   farther than ``basin_radius`` (max-norm) from every local minimum found.

Deterministic for a given seed and FE results (so resumable by replay).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import qmc

from fe_core.inference.residual import estimate_noise

__all__ = ["LocalFirstResult", "local_first", "at_noise_floor"]

FAILED = np.inf


@dataclass(frozen=True)
class LocalFirstResult:
    """Outcome of :func:`local_first`.

    x : ndarray (m,), best point; error : its overall error (Eq. 6b);
    evaluations : FE runs; rounds : batches; status : "target", "floor"
    (stalled at the estimated noise), "budget"; minima : list of (x, error) where
    local phases stalled; history : list of (round, x, error) in evaluation order.
    """

    x: np.ndarray
    residuals: np.ndarray
    error: float
    evaluations: int
    rounds: int
    status: str
    minima: list = field(default_factory=list, repr=False)
    history: list = field(default_factory=list, repr=False)


class _Budget(Exception):
    pass


def at_noise_floor(residuals: np.ndarray, freqs_hz: np.ndarray, target: float, noise_ratio: float) -> bool:
    """True when the residual (shape (p * n,), frequency-major) is at the target or looks like noise."""
    r = np.asarray(residuals, float)
    if np.mean(np.abs(r)) <= target:
        return True
    sigma = estimate_noise(r.reshape(len(freqs_hz), -1), freqs_hz)
    return bool(np.sqrt(np.mean(r**2)) <= noise_ratio * sigma)


def local_first(
    evaluate: Callable[[list[np.ndarray]], Sequence[np.ndarray]],
    x0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    freqs_hz: np.ndarray,
    *,
    target: float = 1e-4,
    max_evaluations: int = 400,
    batch: int = 20,
    rhobeg: float = 0.1,
    stall_window: int = 21,
    stall_rtol: float = 1e-2,
    noise_ratio: float = 1.5,
    basin_radius: float = 0.15,
    seed: int = 0,
) -> LocalFirstResult:
    """Run the strategy; ``evaluate(points) -> residual vectors`` is one round.

    ``x0`` is the start (the nominal model), ``lower``/``upper`` shape (m,)
    the box, ``freqs_hz`` shape (p,) the measured frequencies (residual
    vectors are (p * n,), frequency-major). A local phase is DFO-LS
    (``rhobeg`` start radius) stopped at ``target`` or when its best error
    improved by less than ``stall_rtol`` over ``stall_window`` FE runs.
    """
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    st = {"n": 0, "rounds": 0, "best": None}
    history: list = []
    minima: list = []
    sobol = qmc.Sobol(lower.size, scramble=True, seed=seed)
    warnings.filterwarnings("ignore", message="The balance properties", category=UserWarning)

    def run(points: list[np.ndarray]) -> list[np.ndarray]:
        if not points:
            return []
        if st["n"] + len(points) > max_evaluations:
            raise _Budget
        st["rounds"] += 1
        out = []
        for x, r in zip(points, evaluate([p.copy() for p in points])):
            r = np.asarray(r, float)
            st["n"] += 1
            e = float(np.mean(np.abs(r))) if np.all(np.isfinite(r)) else FAILED
            history.append((st["rounds"], x.copy(), e))
            if st["best"] is None or e < st["best"][0]:
                st["best"] = (e, x.copy(), r.copy())
            out.append(r)
        return out

    def err(r):
        return float(np.mean(np.abs(r))) if np.all(np.isfinite(r)) else FAILED

    class _Stall(Exception):
        pass

    def local(x):
        """DFO-LS from x, one FE run per round; returns (x, r) of the best point of this phase."""
        import dfols

        trace: list[float] = []
        phase = {"best": None}

        def fun(z):
            r = run([np.asarray(z, float)])[0]
            e = err(r)
            if phase["best"] is None or e < phase["best"][0]:
                phase["best"] = (e, np.asarray(z, float).copy(), r)
            trace.append(phase["best"][0])
            if phase["best"][0] <= target:
                raise _Stall
            if len(trace) > stall_window and trace[-stall_window - 1] - trace[-1] <= stall_rtol * trace[-stall_window - 1]:
                raise _Stall
            return np.where(np.isfinite(r), r, 1e3)

        logging.getLogger("dfols").setLevel(logging.WARNING)
        try:
            dfols.solve(fun, x, bounds=(lower, upper), maxfun=max_evaluations, do_logging=False,
                        rhobeg=rhobeg, rhoend=1e-8)
        except _Stall:
            pass
        return phase["best"][1], phase["best"][2]

    status = "budget"
    x = np.clip(np.asarray(x0, float), lower, upper)
    try:
        while True:
            x, r = local(x)
            minima.append((x.copy(), err(r)))
            if err(r) <= target:
                status = "target"
                break
            if at_noise_floor(r, freqs_hz, target, noise_ratio):
                status = "floor"
                break
            run(list(qmc.scale(sobol.random(batch), lower, upper)))
            far = [i for i, (_, hx, e) in enumerate(history)
                   if np.isfinite(e) and all(np.max(np.abs(hx - mx)) > basin_radius for mx, _ in minima)]
            if far:
                x = history[min(far, key=lambda j: history[j][2])][1].copy()
    except _Budget:
        pass
    e, xb, rb = st["best"]
    return LocalFirstResult(x=xb, residuals=rb, error=e, evaluations=st["n"], rounds=st["rounds"], status=status,
                            minima=minima, history=history)
