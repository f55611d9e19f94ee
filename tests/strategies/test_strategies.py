"""The strategy interface (propose, evaluate, update, stop) on analytic responses, for both strategies."""

from __future__ import annotations

import numpy as np
import pytest

from strategies.base import Batch, Outcome, StopDecision, run_loop
from fe_core.inference.frf_data import FRFData
from strategies.hybrid import Hybrid, HybridOptions
from strategies.paper import PaperLoop, PaperOptions

W = np.linspace(4.0, 9.0, 40)
TRUTH = np.array([-0.55, 0.3])
U = 1e-6 * (1.0 + 0.5 * np.cos(W))  # measured amplitudes, m/N
DATA = FRFData.grid(W, U)
LOWER, UPPER = -np.ones(2), np.ones(2)


def _toy(x):
    """A "receptance" with several basins in x_1 and its exact derivative (tests/strategies/test_hybrid.py)."""
    r = 0.3 * (np.sin(W * x[0]) - np.sin(W * TRUTH[0])) + 0.1 * (x[1] - TRUTH[1])
    dr = np.column_stack([0.3 * W * np.cos(W * x[0]), np.full(W.size, 0.1)])
    return U * (1.0 + r) + 0j, (U[:, None] * dr) + 0j


class Counting:
    """``evaluate(batch)`` on the toy, keeping every batch."""

    def __init__(self):
        self.batches: list[Batch] = []

    def __call__(self, batch: Batch):
        self.batches.append(batch)
        out = []
        for x, jac in zip(batch.points, batch.jacobian):
            Z, dZ = _toy(x)
            out.append(Outcome(Z, dZ if jac else None))
        return out


def test_run_loop_asks_only_while_the_strategy_goes_on():
    class Three:
        def __init__(self):
            self.updates = 0

        def propose(self):
            return Batch(np.zeros((2, 1)), (False, False), "round")

        def update(self, batch, outcomes):
            assert len(outcomes) == len(batch) == 2
            self.updates += 1

        def stop(self):
            return StopDecision(self.updates == 3, True, "three rounds")

    s = Three()
    assert run_loop(s, lambda b: [Outcome(np.ones(1))] * len(b)) == StopDecision(True, True, "three rounds")
    assert s.updates == 3


def test_the_paper_loop_in_memory_keeps_table_2s_batches_and_narrows_on_the_truth():
    options = PaperOptions(q=12, s=6, z=8, w=3000, threshold=1e-3, max_iterations=8, max_fe=60, emulate="errors",
                           seed=3)
    evaluate = Counting()
    loop = PaperLoop(options, DATA, LOWER, UPPER, (LOWER + 1e-3, UPPER))
    decision = run_loop(loop, evaluate)
    sizes = [len(b) for b in evaluate.batches]
    assert sizes[0] == 12 and all(n == 6 for n in sizes[1:]) and sum(sizes) <= 60
    assert [b.label for b in evaluate.batches] == [f"iteration-{k}" for k in range(1, len(sizes) + 1)]
    assert all(not any(b.jacobian) for b in evaluate.batches)  # the paper's loop never asks for derivatives
    first = np.mean([np.mean(np.abs(DATA(_toy(x)[0]))) for x in evaluate.batches[0].points])
    x, error = loop.best()
    assert error < 0.1 * first  # the loop narrows on the measurement ...
    assert decision.stop and (decision.converged == (error <= options.threshold))
    assert np.all(np.vstack([b.points for b in evaluate.batches]) > LOWER)  # ... and never leaves the domain


def test_the_modal_loop_refuses_to_start_without_its_layout():
    with pytest.raises(ValueError, match="modal layout"):
        PaperLoop(PaperOptions(emulate="modes"), DATA, LOWER, UPPER, (LOWER, UPPER))


def test_the_hybrid_asks_local_rounds_then_global_ones_and_stops_within_its_budget():
    options = HybridOptions(candidates=2000, starts=4, space_filling=12, max_cost=200.0)
    evaluate = Counting()
    strategy = Hybrid(np.zeros(2), DATA, LOWER, UPPER, options)
    assert strategy.stop() == StopDecision(False, False, "continue")
    decision = run_loop(strategy, evaluate)
    labels = [b.label for b in evaluate.batches]
    n_local = labels.index("global-1")
    assert set(labels[:n_local]) == {"local"} and all(len(b) == 1 and all(b.jacobian)
                                                      for b in evaluate.batches[:n_local])
    glob = evaluate.batches[n_local]
    assert len(glob) == 12 and not any(glob.jacobian)  # the space-filling round
    result = strategy.result()
    assert decision.stop and decision.converged and result.status in ("target", "floor")
    assert np.max(np.abs(result.x - TRUTH)) < 1e-3
    assert result.cost <= options.max_cost
    assert result.rounds == len(evaluate.batches) and result.evaluations == sum(map(len, evaluate.batches))
