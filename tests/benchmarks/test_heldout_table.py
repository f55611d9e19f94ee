"""The held-out runner's tally counts the effects a case's truth lacks (benchmarks.heldout.table)."""

from benchmarks.heldout import table


def _row(case, expected, found, judged, **extra):
    return {"case": case, "structure": "plate", "expected": expected, "true effect": "t", "found": found,
            "verdict": "explained", "converged": False, "update FE runs (eq.)": "9 (9)", "closure FE solves": 10,
            "wall min": 5.0, "judged right": judged, "pass": "yes" if judged else "no: place", **extra}


def test_effects_beside_the_true_one_are_counted_in_the_tally():
    rows = [_row("a", "explained", "point_mass at node 1 = 0.2; point_mass at node 9 = 0.019", True),
            _row("b", "explained", "grounded_spring at node 4 = 3e5", True),
            _row("c", "explained", "patch at node 2 r1 = -0.5; point_mass at node 3 = 0.1", False),
            _row("d", "explained", "grounded_spring at node 5 = 1e5", True, **{"extra effects": 0})]
    text = table(rows)
    assert "placed within 5 %, sized within 15 %: 3 of 4 (1 of them with an effect the truth lacks beside it)" in text


def test_no_remark_when_nothing_was_added_beside():
    text = table([_row("b", "explained", "grounded_spring at node 4 = 3e5", True)])
    assert ": 1 of 1\n" in text and "lacks" not in text
