"""Hyper-parameter trainers behind one interface, chosen by name.

Every trainer is ``minimize(fun, bounds, rng, options=None, *, x0=None,
value_and_grad=None) -> Result``:

* ``"sao"``: simulated annealing with the schedule of Table 1
  (:mod:`.annealing`);
* ``"pso"``: particle swarm with the swarm size and budget of Table 1
  (:mod:`.particle_swarm`);
* ``"gradient"``: multi-start L-BFGS-B on the analytic gradient
  (:mod:`.gradient`, beyond the paper).
"""

from __future__ import annotations

from . import annealing, gradient, particle_swarm
from .result import Result

__all__ = ["TRAINERS", "Result", "get_trainer"]

#: Name -> ``minimize`` function.
TRAINERS = {
    "gradient": gradient.minimize,
    "sao": annealing.minimize,
    "pso": particle_swarm.minimize,
}


def get_trainer(name: str):
    """The ``minimize`` function registered under ``name``.

    Raises
    ------
    ValueError
        For an unknown name, listing the valid ones.
    """
    try:
        return TRAINERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown trainer {name!r}; valid trainers are {', '.join(sorted(TRAINERS))}") from None
