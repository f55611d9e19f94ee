"""The forward selection's full checks spread over worker processes (``check_many`` of
:func:`fe_core.closure.selection.forward_select`).

The closure's first round already checks its candidates in loky workers (:func:`tasks.closure.steps.check_task`);
the forward selection made its later rounds' checks and its swaps' one after another in the decision's process,
one of the two cores idle for much of it (held-out hd07: 496 s of checks in a 15-minute decision). Here each wave
of checks goes to the run's ``n_jobs`` workers (as many as the memory left holds,
:func:`tasks.machine.runs_that_fit`): a worker maps the model (:class:`tasks.problem.ModelRef`, once per
process), rebuilds the base fit's effects from its own library, makes :func:`fe_core.closure.screening.check` and
returns plain arrays; the fit is rebuilt here on this process's library, so no model or effect is pickled.

Only for models of at least :data:`MIN_DOFS` free DOFs: below that a check takes about a second, less than a
worker's share of the dispatch, and in one process the checks share one reduced basis
(:mod:`fe_core.closure.fast`). A worker's reduced basis holds the spaces of the checks it made, so a check's last
digits may differ from the same check made in the decision's process; the first round has always been so.
"""

from __future__ import annotations

import numpy as np
from joblib import Parallel, delayed

from fe_core.closure import fits, screening
from fe_core.closure.effects import Applied
from fe_core.threads import at_most
from tasks.closure.library import cached_library
from tasks.machine import runs_that_fit

__all__ = ["MIN_DOFS", "CHECK_WORKER_FACTOR", "check_workers", "process_checks"]

#: Free DOFs from which the forward selection's checks go to worker processes.
MIN_DOFS = 10_000
#: A closure check's worker holds more than an FE run (:attr:`tasks.problem.Problem.worker_bytes`): the effect's
#: fits, the reduced model of the fast fits (up to 480 full fields) and the Krylov spaces of its linearisation.
#: Measured on the 150k panel (``python -m benchmarks.scaling update ... -- --close-loop``): 4.93 and 4.51 GB per
#: worker, against an FE run's 1.36 GB estimate.
CHECK_WORKER_FACTOR = 3.6


def check_workers(problem, wanted: int) -> int:
    """Workers for ``wanted`` closure checks at once: as many as the memory left holds, each needing
    :data:`CHECK_WORKER_FACTOR` times an FE run's estimate (1: the checks run one after another here)."""
    per_run = getattr(problem, "worker_bytes", None)  # None: not a mesh model, or not estimated
    need = per_run and CHECK_WORKER_FACTOR * per_run
    return runs_that_fit(wanted, need)


def _applied(library: dict, items) -> list[Applied]:
    return [Applied(library[kind], location, np.asarray(values, float)) for kind, location, values in items]


def _items(applied) -> list[tuple]:
    return [(a.effect.kind, a.location, [float(v) for v in a.values]) for a in applied]


def _check_one(ref, effects, base: dict, kind: str, cand: dict, freqs, u, max_moves, alpha_bounds,
               max_evaluations) -> dict:
    """One check in a worker: the candidate's fit as plain values and arrays."""
    with at_most(1):
        model = ref.load()
        library = cached_library(model, effects)
        prior = _applied(library, base["prior"])
        b = fits.Fit(alpha=np.asarray(base["alpha"], float), effect=None, location=None, values=np.zeros(0),
                     model_amplitude=base["amplitude"], residual=base["residual"], evaluations=0, prior=prior)
        c = screening.Candidate(effect=kind, location=cand["location"], n_locations=cand["n_locations"],
                                linear_values=np.asarray(cand["linear_values"], float), linear_rss=0.0,
                                linear_explained=0.0, start_alpha=cand["start_alpha"])
        screening.check(model, freqs, u, b, library[kind], c, max_moves, tuple(alpha_bounds),
                        max_evaluations=max_evaluations)
        f = c.fit
        return {"location": c.location, "moved_from": list(c.moved_from), "alpha": f.alpha, "values": f.values,
                "prior": _items(f.prior), "amplitude": f.model_amplitude, "residual": f.residual,
                "evaluations": f.evaluations, "seconds": f.seconds, "message": f.message, "start": f.start}


def process_checks(problem, settings: dict, library: dict):
    """A ``check_many`` for :func:`~fe_core.closure.selection.forward_select` on ``settings["n_jobs"]`` loky
    workers, or None (the checks made in this process) for one job or a model under :data:`MIN_DOFS`."""
    n_jobs = int(settings.get("n_jobs", 1) or 1)
    if n_jobs == 1 or problem.model.n_dofs < MIN_DOFS:
        return None

    def check_many(model, freqs, u, base, pairs, max_moves, alpha_bounds, max_evaluations):
        pairs = list(pairs)
        if len(pairs) < 2:
            return screening.check_all(model, freqs, u, base, pairs, max_moves, alpha_bounds, max_evaluations)
        b = {"alpha": base.alpha, "prior": _items(base.applied), "amplitude": base.model_amplitude,
             "residual": base.residual}
        jobs = (delayed(_check_one)(problem.ref, settings.get("effects"), b, effect.kind,
                                    {"location": c.location, "n_locations": c.n_locations,
                                     "linear_values": c.linear_values, "start_alpha": c.start_alpha},
                                    freqs, u, max_moves, alpha_bounds, max_evaluations)
                for effect, c in pairs)
        records = Parallel(n_jobs=check_workers(problem, min(n_jobs, len(pairs))), backend="loky")(jobs)
        for (effect, c), r in zip(pairs, records):
            prior = _applied(library, r["prior"])
            added = Applied(library[effect.kind], r["location"], np.asarray(r["values"], float))
            c.fit = fits.Fit(alpha=np.asarray(r["alpha"], float), effect=effect.kind, location=r["location"],
                             values=np.asarray(r["values"], float), model_amplitude=r["amplitude"],
                             residual=r["residual"], evaluations=r["evaluations"], seconds=r["seconds"],
                             message=r["message"], prior=prior, added=added, start=r["start"])
            c.location, c.moved_from = r["location"], r["moved_from"]
        return [c for _, c in pairs]

    return check_many
