"""Simulated annealing with the schedule of Table 1 (Zhou & Tang).

Table 1: initial temperature 100, target temperature 3, temperature descent
factor 0.8, 400 iterations per temperature, start ``l = 1, sigma_f = 1``. The
temperature levels are ``100 * 0.8**j`` while they are >= 3, i.e. 16 levels
(100 down to 3.52), 6,400 proposals plus the start.

The paper does not say how a neighbour is generated; here each proposal adds
a Gaussian step with standard deviation ``step * T / T0`` times the width of
each bound (so steps shrink with the temperature, as in "fast annealing"),
reflected back into the box. A proposal is accepted by the Metropolis
criterion ``exp(-(f_new - f) / T)`` on the raw objective values, and the best
point ever evaluated is returned. Non-finite objective values are rejected.
"""

from __future__ import annotations

import logging

import numpy as np

from .result import Result, check_bounds, check_options

__all__ = ["DEFAULTS", "minimize", "temperature_levels"]

log = logging.getLogger(__name__)

#: Table 1 schedule; ``step`` (fraction of each bound's width at T0) is ours.
DEFAULTS = {
    "initial_temperature": 100.0,
    "final_temperature": 3.0,
    "cooling": 0.8,
    "iterations_per_temperature": 400,
    "step": 0.25,
    "max_evaluations": None,
}


def temperature_levels(initial: float, final: float, cooling: float) -> np.ndarray:
    """Temperatures ``initial * cooling**j`` that are >= ``final``, shape (n_levels,)."""
    if not (initial >= final > 0 and 0 < cooling < 1):
        raise ValueError(f"need initial >= final > 0 and 0 < cooling < 1, got {initial}, {final}, {cooling}")
    levels = [initial]
    while levels[-1] * cooling >= final * (1 - 1e-12):
        levels.append(levels[-1] * cooling)
    return np.array(levels)


def _reflect(u: np.ndarray) -> np.ndarray:
    u = np.mod(u, 2.0)
    return np.where(u > 1.0, 2.0 - u, u)


def minimize(fun, bounds, rng: np.random.Generator, options: dict | None = None, *, x0=None, value_and_grad=None) -> Result:
    """Minimise ``fun`` over a box by simulated annealing.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> float`` for ``x`` of shape (n,).
    bounds : array_like, shape (n, 2)
    rng : numpy.random.Generator
        The only source of randomness: a fixed seed gives identical results.
    options : dict, optional
        Keys of :data:`DEFAULTS`. ``max_evaluations`` caps the objective
        evaluations (start included); None runs the whole schedule.
    x0 : array_like, shape (n,), optional
        Start (clipped into the box); the centre of the box by default.
    value_and_grad : callable, optional
        Ignored (derivative-free); accepted so all trainers share one signature.

    Returns
    -------
    Result
        ``nit`` is the number of temperature levels completed; ``history`` the
        best value after each level.
    """
    opts = check_options(options, DEFAULTS, "annealing")
    low, high = check_bounds(bounds)
    width = high - low
    temps = temperature_levels(opts["initial_temperature"], opts["final_temperature"], opts["cooling"])
    t0 = temps[0]
    cap = np.inf if opts["max_evaluations"] is None else int(opts["max_evaluations"])

    u = np.full(low.size, 0.5) if x0 is None else np.clip((np.asarray(x0, float) - low) / np.where(width > 0, width, 1), 0, 1)
    to_x = lambda v: low + v * width  # noqa: E731
    f = float(fun(to_x(u)))
    nfev = 1
    if not np.isfinite(f):
        f = np.inf
    best_u, best_f = u.copy(), f
    history = []
    accepted = 0
    message = f"completed {len(temps)} temperature levels"
    for level, T in enumerate(temps):
        sigma = opts["step"] * T / t0
        for _ in range(int(opts["iterations_per_temperature"])):
            if nfev >= cap:
                message = f"stopped at max_evaluations={int(cap)}"
                break
            cand = _reflect(u + sigma * rng.standard_normal(u.size))
            fc = float(fun(to_x(cand)))
            nfev += 1
            draw = rng.random()
            if not np.isfinite(fc):
                continue
            if fc <= f or draw < np.exp(-(fc - f) / T):
                u, f = cand, fc
                accepted += 1
                if f < best_f:
                    best_u, best_f = u.copy(), f
        history.append(best_f)
        if message.startswith("stopped"):
            break
    log.debug("annealing: %d evaluations, %d accepted, best %.6g", nfev, accepted, best_f)
    return Result(x=to_x(best_u), fun=float(best_f), nfev=nfev, nit=len(history), message=message, history=np.array(history))
