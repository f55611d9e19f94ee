"""A run's problem as a strategy sees it (:class:`strategies.base.Context`), and readers of its stored modes.

:func:`context` gives the strategy the run's search box, nominal model, residual and layout of the kept
values (the data object), the cost of a run with its Jacobian (a black-box deck's: its m + 1 forward-difference runs), the
emulated modes' layout and the effect screen's model (:func:`screen_model`, computed when first asked for).
"""

from __future__ import annotations

import numpy as np

from mrgp_core.modal_outputs import ModalLayout
from strategies.base import Context
from tasks import record
from tasks.fe_runs import JACOBIAN_COST, is_large
from tasks.problem import black_box
from tasks.runstore import RunStore

__all__ = ["context", "screen_model", "modal_layout", "modal_training_set"]


def screen_model(problem):
    """(the model seen through the data's channels, "") when the effect library can be screened on the run's data
    (:func:`fe_core.closure.evidence.screen_points` on ``problem.data``), else (None, why not)."""
    data = problem.data
    if black_box(problem.model):
        return None, "not screened: the effects are terms of K and M, which a black-box solver deck does not expose"
    if problem.m != problem.model.n_segments:
        return None, "the run updates mass factors; the effect screen refits stiffness factors only"
    try:
        model = data.single_reference_model(problem.model)
    except ValueError as exc:
        return None, f"not screened: {exc}"
    if data.complete_lines.sum() < 3:
        return None, "not screened: fewer than three lines with every channel kept"
    return model, ""


def modal_layout(problem) -> ModalLayout:
    """The emulated outputs' layout for the run's kept values and ``problem.modes`` modes."""
    data = problem.data
    line, channel = data.cells
    omega = 2.0 * np.pi * np.asarray(data.frequencies_hz, float)[line]
    damping = tuple(float(v) for v in problem.model.damping)
    return ModalLayout(omega, np.asarray(channel, int), int(data.amplitude.shape[1]), damping, problem.modes)


def context(problem, memo) -> Context:
    """The strategy's view of ``problem`` (a :class:`tasks.problem.Problem`), its steps going to ``memo``."""
    cost = problem.model.jacobian_cost if black_box(problem.model) else JACOBIAN_COST
    screened = {}

    def screens():
        if "model" not in screened:
            screened["model"] = screen_model(problem)
        return screened["model"]

    return Context(list(problem.names), problem.lower, problem.upper, problem.solver_box, problem.nominal,
                   problem.data, cost, (lambda: modal_layout(problem)) if problem.modes else None, screens, memo,
                   is_large(problem.model))


def modal_training_set(store: RunStore, problem, upto: int):
    """(X (r, m), Y (r, n_outputs), overall errors (r,), layout): the emulated modal outputs of every successful
    FE run with modes of iterations 1..``upto`` (the paper loop's training set, read from the run record)."""
    runs = record.fe_runs(store, upto)
    runs = runs[(runs["status"] == "ok") & (runs["stage"] == "fe")]
    ids = runs["sample_id"].to_numpy()
    data = problem.data
    p, n = data.amplitude.shape
    line, channel = data.cells
    resp = record.responses(store, upto, ids)
    by_id = {int(sid): part.sort_values(["frequency_hz", "sensor"], kind="stable")
             for sid, part in resp.groupby("sample_id", sort=False)}
    counts = {sum(c.startswith("omega2_") for c in by_id[int(sid)].columns) for sid in ids}
    if len(counts) != 1 or 0 in counts:
        raise RuntimeError(f"{store.root}: the FE results hold {sorted(counts)} modes; the modal emulator needs the "
                           "same modes in every FE run (was the run started with emulate = \"errors\"?)")
    modes = counts.pop()
    lay = modal_layout(problem.with_modes(modes))
    Y = np.empty((len(ids), lay.n_outputs))
    for i, sid in enumerate(ids):
        part = by_id[int(sid)]
        Z = (part["real"].to_numpy() + 1j * part["imag"].to_numpy()).reshape(p, n)[line, channel]
        omega2 = np.array([part[f"omega2_{r + 1}"].iloc[0] for r in range(modes)])
        P = np.array([part[f"participation_{r + 1}"].to_numpy()[:n] for r in range(modes)])
        Y[i] = lay.outputs(omega2, P, Z)
    return runs[problem.names].to_numpy(), Y, runs["overall_error"].to_numpy(), lay
