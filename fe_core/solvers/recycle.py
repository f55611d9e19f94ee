"""One FE run's Krylov space seeds the next run's of the same large model (issue 41).

An FE run of a large model is mostly solves with the factor of K: a Jacobian's space is 70-84 vectors on the
bracket, grown a block of 7 at a time. Consecutive runs of an update (Gauss-Newton steps, the intervals' steps
at the optimum) are at nearby parameters, and the converged space of one nearly holds the responses of the
next. :func:`take` hands the last converged space to the next FE run of the model as the first columns of its
space (:class:`fe_core.solvers.frf.BlockKrylov` ``seed``); the space then grows by Krylov blocks of the new
operator as before, and converges by the same test (the responses and derivatives stop changing as it grows:
1e-10 and 1e-8, the first block against the seed alone). The Galerkin projection takes the exact matrices on
whatever space it is given, so the seed changes how many blocks the run needs, not the test its results pass.

Kept on the model object (one space per model, in the process that ran it), only for models of at least
:data:`MIN_DOFS` DOFs: small models keep their arithmetic exactly. A seeded space holds its seed whole, so it
grows run after run; beyond :data:`KEEP_FACTOR` times the dimension an unseeded run needed it is dropped and the
next run starts afresh. An FE
worker that runs other points next forgets it (:func:`forget`).

A seed pays only for a small step: the seeded space still grows the new operator's Krylov blocks until the
responses settle, now orthogonalised against the seed too and checked after every block. Measured in the 150k
panel's default update (docs/results/scaling.md; fresh runs 57-77 s): seeded runs after Gauss-Newton steps of
0.2, 0.087 and 0.0024 (max-norm) took 121, 137 and 99 s; one at the same point again took 22 s. So
the space is kept with the parameters it was built at, and :func:`take` hands it out only when the next run's
parameters are within :data:`MAX_STEP` of them (max-norm); a caller that gives no parameters gets it as before.
"""

from __future__ import annotations

__all__ = ["MIN_DOFS", "KEEP_FACTOR", "MAX_STEP", "ENABLED", "take", "store", "forget", "active"]

import os

import numpy as np

#: Models with at least this many free DOFs recycle their spaces.
MIN_DOFS = 50_000
#: A space is kept while at most this many times an unseeded run's dimension; a larger one is dropped and the
#: next run starts afresh (a seeded space holds its seed whole: trimming it loses the Krylov spaces it holds).
KEEP_FACTOR = 1.5
#: ``MRGP_KRYLOV_RECYCLE=0`` turns recycling off.
ENABLED = os.environ.get("MRGP_KRYLOV_RECYCLE", "1") != "0"

#: A kept space seeds only a run whose parameters are within this max-norm distance of its own (module docstring).
MAX_STEP = 1e-4

_SEED = "_krylov_seed"
_FRESH = "_krylov_fresh_dimension"
_POINT = "_krylov_point"


def active(model) -> bool:
    """Whether FE runs of ``model`` keep and reuse their spaces."""
    return ENABLED and getattr(model, "n_dofs", 0) >= MIN_DOFS


def take(model, point=None):
    """The space kept from the model's last FE run (removed from the model: the run's own space holds it
    now), or None; with ``point`` (the run's parameters), None unless the space was built within
    :data:`MAX_STEP` of it."""
    if not active(model):
        return None
    seed = model.__dict__.pop(_SEED, None)
    kept_at = model.__dict__.pop(_POINT, None)
    if seed is None or point is None or kept_at is None:
        return seed
    point = np.asarray(point, dtype=float)
    if kept_at.shape != point.shape or np.max(np.abs(point - kept_at), initial=0.0) > MAX_STEP:
        return None
    return seed


def store(model, keep: dict, point=None) -> None:
    """Keep the converged space a run left in ``keep`` (``basis``, ``seeded``) for the next run, with the
    parameters it was built at (``point``, if given)."""
    basis = keep.get("basis")
    if basis is None or not active(model):
        return
    if not keep.get("seeded"):
        model.__dict__[_FRESH] = basis.shape[1]
    if basis.shape[1] <= KEEP_FACTOR * model.__dict__.get(_FRESH, basis.shape[1]):
        model.__dict__[_SEED] = basis
        if point is None:
            model.__dict__.pop(_POINT, None)
        else:
            model.__dict__[_POINT] = np.array(point, dtype=float)
    else:  # grown too large: the next run starts afresh (and its space seeds the ones after it)
        forget(model)


def forget(model) -> None:
    """Drop the kept space (an FE worker's next run is at an unrelated point)."""
    model.__dict__.pop(_SEED, None)
    model.__dict__.pop(_POINT, None)
