"""Particle swarm optimisation with the settings of Table 1 (Zhou & Tang).

Table 1: swarm size 100, at most 10,000 objective evaluations, search inside
the hyper-parameter bounds. The paper gives no coefficients; this is the
global-best swarm with Clerc's constriction coefficients (inertia 0.7298,
cognitive and social weights 1.49618), velocities limited to half the box
width, positions clipped to the box with the velocity component that hit a
wall set to zero. Particles start uniformly in the box (particle 0 at ``x0``
when one is given). Each generation evaluates the whole swarm, so the budget
of 10,000 evaluations is 100 generations including the initial one.

Velocity and position updates are vectorised over the swarm; only the
objective is called per particle.
"""

from __future__ import annotations

import logging

import numpy as np

from .result import Result, check_bounds, check_options

__all__ = ["DEFAULTS", "minimize"]

log = logging.getLogger(__name__)

#: Table 1 swarm size and budget; coefficients from Clerc & Kennedy (2002).
DEFAULTS = {
    "swarm_size": 100,
    "max_evaluations": 10_000,
    "inertia": 0.7298,
    "cognitive": 1.49618,
    "social": 1.49618,
    "max_velocity": 0.5,
    "stall_generations": None,
    "function_tolerance": 1e-6,
}


def _evaluate(fun, X: np.ndarray) -> np.ndarray:
    vals = np.array([float(fun(x)) for x in X])
    return np.where(np.isfinite(vals), vals, np.inf)


def minimize(fun, bounds, rng: np.random.Generator, options: dict | None = None, *, x0=None, value_and_grad=None) -> Result:
    """Minimise ``fun`` over a box with a particle swarm.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> float`` for ``x`` of shape (n,). Non-finite values count as
        ``+inf``.
    bounds : array_like, shape (n, 2)
    rng : numpy.random.Generator
        The only source of randomness: a fixed seed gives identical results.
    options : dict, optional
        Keys of :data:`DEFAULTS`. With ``stall_generations`` set, the swarm
        also stops when the best value has improved by less than
        ``function_tolerance * (1 + |best|)`` over that many generations (off by
        default, so the full Table 1 budget is spent).
    x0 : array_like, shape (n,), optional
        Seeds particle 0.
    value_and_grad : callable, optional
        Ignored (derivative-free); accepted so all trainers share one signature.

    Returns
    -------
    Result
        ``nit`` is the number of generations (including the initial one);
        ``history`` the global best after each generation.
    """
    opts = check_options(options, DEFAULTS, "particle swarm")
    low, high = check_bounds(bounds)
    width = high - low
    n_part = int(opts["swarm_size"])
    budget = int(opts["max_evaluations"])
    if n_part < 1 or budget < n_part:
        raise ValueError(f"need swarm_size >= 1 and max_evaluations >= swarm_size, got {n_part}, {budget}")
    dim = low.size
    vmax = float(opts["max_velocity"])

    # Positions and velocities live in the unit box; the objective sees low + u * width.
    U = rng.random((n_part, dim))
    if x0 is not None:
        U[0] = np.clip((np.asarray(x0, float) - low) / np.where(width > 0, width, 1), 0, 1)
    V = rng.uniform(-0.1, 0.1, (n_part, dim))
    to_x = lambda u: low + u * width  # noqa: E731
    F = _evaluate(fun, to_x(U))
    nfev = n_part
    P, PF = U.copy(), F.copy()
    g = int(np.argmin(PF))
    history = [PF[g]]
    message = f"spent the evaluation budget ({budget})"
    stall = opts["stall_generations"]
    while nfev + n_part <= budget:
        r1 = rng.random((n_part, dim))
        r2 = rng.random((n_part, dim))
        V = opts["inertia"] * V + opts["cognitive"] * r1 * (P - U) + opts["social"] * r2 * (P[g] - U)
        np.clip(V, -vmax, vmax, out=V)
        U = U + V
        hit = (U < 0.0) | (U > 1.0)
        U = np.clip(U, 0.0, 1.0)
        V[hit] = 0.0
        F = _evaluate(fun, to_x(U))
        nfev += n_part
        better = F < PF
        P[better], PF[better] = U[better], F[better]
        g = int(np.argmin(PF))
        history.append(PF[g])
        if stall is not None and len(history) > stall:
            old = history[-1 - int(stall)]
            if old - history[-1] <= opts["function_tolerance"] * (1 + abs(history[-1])):
                message = f"best value stalled for {int(stall)} generations"
                break
    log.debug("particle swarm: %d evaluations, best %.6g", nfev, PF[g])
    return Result(x=to_x(P[g]), fun=float(PF[g]), nfev=nfev, nit=len(history), message=message, history=np.array(history))
