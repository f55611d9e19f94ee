"""A budget that follows the evidence (issue 28): past ``max_cost`` a phase goes on while its rounds improve,
up to ``cap``; it stops at ``max_cost`` when they do not.

On the analytic toy of ``test_hybrid.py`` (several basins in x_1; the nominal start is in a wrong one), whose
unlimited run reaches the target after 67 FE-run equivalents.
"""

from dataclasses import replace

import numpy as np
import pytest

from strategies.hybrid import HybridOptions, hybrid
from strategies.ledger import BudgetSpent, Ledger
from fe_core.inference.frf_data import FRFData

# The toy of test_hybrid.py: Z = u (1 + r(x)), r = 0.3 (sin(W x_1) - sin(W t_1)) + 0.1 (x_2 - t_2), exact dZ.
W = np.linspace(4.0, 9.0, 40)
TRUTH = np.array([-0.75, 0.3])
U = 1e-6 * (1.0 + 0.5 * np.cos(W))
DATA = FRFData.grid(W, U)
LOWER, UPPER = -np.ones(2), np.ones(2)
OPTIONS = HybridOptions(candidates=2000, starts=4, space_filling=12, max_cost=200.0)


def _evaluate():
    def evaluate(batch):
        out = []
        for x, j in zip(batch.points, batch.jacobian):
            r = 0.3 * (np.sin(W * x[0]) - np.sin(W * TRUTH[0])) + 0.1 * (x[1] - TRUTH[1])
            dr = np.column_stack([0.3 * W * np.cos(W * x[0]), np.full(W.size, 0.1)])
            out.append((U * (1.0 + r) + 0j, (U[:, None] * dr) + 0j if j else None))
        return out
    return evaluate


def _ledger(errors_per_round, max_cost=3.0, cap=10.0):
    """A ledger that has recorded one FE run per round with overall error ``e`` (``Z = u (1 + e)``: the relative
    amplitude error is e at every value, so Eq. 6b's mean is e)."""
    u = np.ones(4)
    ledger = Ledger(FRFData.grid(np.arange(4.0), u), max_cost, 2.5, cap=cap, improve_rounds=2, improve_rtol=0.05)
    for e in errors_per_round:
        ledger.record([np.zeros(1)], [False], [(u * (1.0 + e) + 0j, None)], "global")
    return ledger


def test_a_round_past_the_budget_is_admitted_only_while_the_phase_improves_and_never_past_the_cap():
    improving = _ledger([0.5, 0.4, 0.3])  # last two rounds' best 0.3 vs 0.5 before: 40 % better
    assert improving.improving()
    improving.admit([False])  # cost 3 + 1 > max_cost 3, <= cap 10, improving: admitted
    assert improving.extended == 1
    with pytest.raises(BudgetSpent):
        improving.admit([True] * 3)  # 3 + 7.5 > cap 10
    stalled = _ledger([0.5, 0.49, 0.48])  # 4 % better: below improve_rtol = 5 %
    assert not stalled.improving()
    with pytest.raises(BudgetSpent):
        stalled.admit([False])
    fresh = _ledger([0.5, 0.4, 0.3])
    fresh.phase_start = fresh.rounds  # a new phase has no rounds of its own yet: nothing shows it improves
    with pytest.raises(BudgetSpent):
        fresh.admit([False])
    assert _ledger([0.5, 0.4, 0.3], cap=None).improving() and not _ledger([], cap=None).improving()


def test_the_cap_lets_an_improving_global_cycle_finish_on_the_path_of_the_unlimited_run():
    unlimited = hybrid(_evaluate(), np.zeros(2), DATA, LOWER, UPPER, replace(OPTIONS, max_cost=1000.0))
    assert unlimited.status == "target" and unlimited.cost == pytest.approx(67.0)
    cut = hybrid(_evaluate(), np.zeros(2), DATA, LOWER, UPPER, replace(OPTIONS, max_cost=60.0))
    assert cut.status == "budget" and cut.error > 1e-4 and cut.cost <= 60.0
    followed = hybrid(_evaluate(), np.zeros(2), DATA, LOWER, UPPER, replace(OPTIONS, max_cost=60.0, cap=150.0))
    assert followed.status == "target" and followed.cost == pytest.approx(unlimited.cost)
    for a, b in zip(followed.history, unlimited.history):  # the same FE runs in the same rounds
        assert a[0] == b[0] and a[3] == b[3]
        np.testing.assert_array_equal(a[1], b[1])


def test_a_cap_gives_nothing_to_a_phase_that_has_not_started_improving():
    # Budget 40: the global cycle's space-filling round and Gauss-Newton starts use it up before any of its
    # rounds could show an improvement, so the run stops where it stopped without a cap.
    plain = hybrid(_evaluate(), np.zeros(2), DATA, LOWER, UPPER, replace(OPTIONS, max_cost=40.0))
    capped = hybrid(_evaluate(), np.zeros(2), DATA, LOWER, UPPER, replace(OPTIONS, max_cost=40.0, cap=100.0))
    assert plain.status == capped.status == "budget"
    assert capped.cost == plain.cost <= 40.0 and capped.evaluations == plain.evaluations


def test_default_options_have_no_cap():
    assert HybridOptions().cap is None
