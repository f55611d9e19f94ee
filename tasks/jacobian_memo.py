"""The flow's process keeps a large model's last full-order FE runs with their Jacobians, for the intervals.

A large model's single FE runs (the hybrid's local phase) run in the flow's process
(:meth:`tasks.fe_runs.FEStage._results`); the intervals then start at the run's best FE run, a full-order one
(:func:`tasks.record.best_run`). :func:`last_jacobian` hands them that run's receptance and derivative, so the
intervals need not compute the Jacobian again (a minute and a half at 500k DOFs). Kept on the model object, a few
MB each (p x n x m complex).
"""

from __future__ import annotations

import numpy as np

__all__ = ["KEPT_JACOBIANS", "keep", "last_jacobian"]

_KEY = "_last_jacobians"
#: Full-order FE runs with their Jacobians kept per model.
KEPT_JACOBIANS = 4


def _channels(channels):
    return None if channels is None else (tuple(np.ravel(channels[0])), tuple(np.ravel(channels[1])))


def keep(model, theta, freqs_hz, channels, Z, dZ) -> None:
    """Keep a full-order FE run's receptance ``Z`` (p, n) and derivative ``dZ`` (p, n, m) at ``theta`` on the lines
    ``freqs_hz`` for ``channels`` (the oldest of :data:`KEPT_JACOBIANS` dropped)."""
    kept = model.__dict__.setdefault(_KEY, [])
    kept[:] = [*kept[1 - KEPT_JACOBIANS:], (np.array(theta, float), _channels(channels),
                                            np.array(freqs_hz, float), Z, dZ)]


def last_jacobian(model, theta, freqs_hz, channels=None):
    """``(Z, dZ)`` on the lines ``freqs_hz`` from a kept run made exactly at ``theta`` for ``channels`` on lines that
    include these; else None."""
    theta = np.asarray(theta, float)
    for x, key, freqs, Z, dZ in reversed(model.__dict__.get(_KEY, [])):
        if key != _channels(channels) or x.shape != theta.shape or not np.array_equal(x, theta):
            continue
        index = {float(f): i for i, f in enumerate(freqs)}
        rows = [index.get(float(f)) for f in np.asarray(freqs_hz, float)]
        if all(r is not None for r in rows):
            return Z[rows], dZ[rows]
    return None
