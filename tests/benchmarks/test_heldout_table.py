"""The held-out runner's tally counts the effects a case's truth lacks (benchmarks.heldout.table) and scores effects
found beside each other as the one closure.json says they are (benchmarks.heldout.score); a set not made is
refused by its command line."""

import pytest

from benchmarks.heldout import score, table


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


def test_masses_found_beside_each_other_are_scored_as_the_one_between_their_nodes():
    """Held-out hd02 as it ended: 0.1446 and 0.0952 kg 16 mm apart for one of 0.2431 kg; closure.json's ``combined``
    puts 0.2398 kg at their value-weighted centre, 4.9 mm from the truth (0.8 % of the 0.59 m plate)."""
    truth = {"case": "hd02", "structure": "holed_plate", "expected": "explained", "structure_size_m": 0.5937,
             "effect": {"kind": "point_mass", "location": "node 749", "value": 0.24313686780976818, "unit": "kg",
                        "xyz_m": [0.3537209787683955, 0.24684189741649035, 0.008]}}
    effects = [{"type": "point_mass", "location": "node 6007", "value": 0.1446, "combined": 0},
               {"type": "point_mass", "location": "node 5778", "value": 0.0952, "combined": 0}]
    centre = [(0.1446 * a + 0.0952 * b) / 0.2398 for a, b in zip([0.34523144, 0.24592455, 0.004],
                                                                  [0.35963317, 0.2489475, 0.004])]
    closure = {"verdict": "explained", "effects": effects, "fe_solves": 12,
               "combined": [{"type": "point_mass", "locations": ["node 6007", "node 5778"], "steps": [1, 2],
                             "value": 0.2398, "unit": "kg", "position_m": centre, "span_mm": 14.7}]}
    run = {"exit": 0, "wall_s": 600.0, "load": [1.0, 1.0]}
    row = score(truth, {"converged": True}, closure, run, {})
    assert row["pass"] == "yes" and row["extra effects"] == 0
    assert row["size error %"] == pytest.approx(100 * (0.24313686780976818 - 0.2398) / 0.24313686780976818, abs=0.05)
    off = sum((a - b) ** 2 for a, b in zip(centre, truth["effect"]["xyz_m"])) ** 0.5  # 4.9 mm (4 mm of it in z)
    assert row["place error %"] == pytest.approx(100 * off / 0.5937, abs=0.005)
    apart = {**closure, "combined": []}  # the same two effects not taken as one: the first alone is scored
    apart["effects"] = [{k: v for k, v in e.items() if k != "combined"} for e in effects]
    with pytest.raises(FileNotFoundError):  # its place is read from the structure's mesh, absent here
        score({**truth, "model": "no/such/model.toml"}, {"converged": True}, apart, run, {})


def test_a_set_not_made_is_refused_with_the_command_that_makes_it(tmp_path, capsys):
    from benchmarks.heldout import main

    with pytest.raises(SystemExit) as stop:
        main(["--set", "heldout9", "--root", str(tmp_path / "cases"), "--keep", str(tmp_path / "kept"), "--table",
              "--no-lock"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "no cases of heldout9 under" in err and f"--set heldout9 --out {tmp_path / 'cases'}" in err
