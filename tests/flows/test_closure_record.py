"""One source of truth for a closure's result (issue 33): the printout is rendered from closure.json, field by
field, on a closure run with moves and a noise level estimated from a structured residual."""

from __future__ import annotations

import io
import json

import pytest

from flows import diagnose as dg
from flows import update
from flows.config import REPO, UpdateConfig
from fe_core.inference.residual import STRUCTURED_ESTIMATE
from tasks.closure.summary import STATUSES

#: data/cases/three_plate_closure_table's far point mass: the forward selection makes moves and swaps, with the noise
#: estimated (no --noise). The library is the five kinds its record involves (with all eleven registered kinds, on
#: 3649e6e, the record was the same: the same effects, swaps and verdict; the fixture was the suite's slowest, 107 s
#: in CI).
EFFECTS = ["segment_mass", "point_mass", "damping", "sensor_gain", "patch"]
DATA = REPO / "data" / "cases" / "three_plate_closure_table" / "far_point_mass.csv"


@pytest.fixture(scope="module")
def closure(tmp_path_factory, reduced_settings_frozen, prefect_harness):
    runs = tmp_path_factory.mktemp("closure-record")
    config = UpdateConfig(run_id="far", runs_dir=str(runs), measured=str(DATA), **dict(reduced_settings_frozen))
    summary = update.update_flow(config)
    # At the 1 % level the selection stops after its first effect: what that leaves, rms 0.513 %, is the data's
    # 0.5 % noise (p = 0.043 against the level estimated from it, 0.433 %; 0.17 against the true 0.5 %). At 5 % it
    # goes on to a second effect, with the moves this record is to show.
    record = dg.diagnose("far", runs, significance=0.05, effects=EFFECTS)
    out = io.StringIO()
    dg.print_closure(record, file=out)
    on_disk = json.loads((runs / "far" / "closure" / "closure.json").read_text())
    return summary, record, on_disk, out.getvalue().splitlines()


@pytest.mark.slow
def test_the_run_has_moves_and_every_swap_changes_something(closure):
    _, record, _, _ = closure
    assert record["moves"]
    for swap in record["swaps"]:  # a swap that changes nothing is not one
        old, new = swap.split(" (extended BIC")[0].split(" -> ")
        assert old != new


@pytest.mark.slow
def test_effects_found_beside_each_other_are_printed_as_recorded(closure):
    """This run's effects lie apart (``combined`` empty); a group is written in as the closure writes it."""
    _, record, on_disk, _ = closure
    assert on_disk["combined"] == [] and all("combined" not in e for e in on_disk["effects"])
    group = {"type": "point_mass", "locations": ["node 337", "node 307"], "steps": [1, 2], "value": 0.2,
             "unit": "kg", "position_m": [0.1, 0.2, 0.0], "span_mm": 14.4}
    out = io.StringIO()
    dg.print_closure({**record, "combined": [group]}, file=out)
    assert "  steps 1 and 2, 14 mm apart, are one point_mass of 0.2 kg between their nodes, at (0.100, 0.200, 0.000) m" \
        in out.getvalue().splitlines()


@pytest.mark.slow
def test_a_swap_is_printed_as_recorded(closure):
    """Since the selection checks the exact search's candidates first (issue 40), this run makes moves but no
    swap; the printout of swaps is checked on its own record with one written in as the selection writes them."""
    _, record, _, _ = closure
    swap = "sensor_gain at sensor 2 -> sensor_gain at sensor 1 (extended BIC -12.5)"
    out = io.StringIO()
    dg.print_closure({**record, "swaps": [swap]}, file=out)
    assert [x.split("swapped: ")[1] for x in out.getvalue().splitlines() if x.startswith("  swapped: ")] == [swap]


@pytest.mark.slow
def test_closure_json_has_no_contradicting_fields(closure):
    summary, record, on_disk, _ = closure
    assert record == on_disk  # what the command returns is what was written
    effects = on_disk["effects"]
    assert on_disk["effect"] == (effects[0] if effects else None)
    verdict = on_disk["verdict"]
    for e in effects:
        assert e["status"] == {"explained": "finding", "ambiguous": "ambiguous"}.get(verdict, "candidate")
        assert e["identified"] == (e["evidence"] >= 0.95 and e["located"])  # singled out in its place
    # One naming scheme for the parameters: <kind>@<location>.<parameter>, the effects in the order added.
    names = [f"alpha_{i}" for i in range(1, 7)] + [f"{e['type']}@{e['location']}.{p}" for e in effects
                                                   for p in ([e["parameter"]] if not isinstance(e["value"], dict)
                                                             else e["value"])]
    assert list(on_disk["parameters_after"]) == names
    # The errors: one measure, and the run's own figure beside it.
    assert on_disk["error_run"] == pytest.approx(summary["overall_error"], rel=1e-12)
    assert "amplitude residual" in on_disk["error_metric"] and "residual over" in on_disk["error_run_metric"]
    assert on_disk["error_after"] <= on_disk["error_before"]
    # The forward selection's time per stage: the stages it went through, each timed.
    seconds = on_disk["selection_seconds"]
    assert {"screen", "check", "refine", "swap", "backward"} <= set(seconds) <= {
        "screen", "search", "check", "refine", "swap", "backward"} and all(v >= 0 for v in seconds.values())


@pytest.mark.slow
def test_the_printout_says_what_closure_json_says(closure):
    _, _, c, lines = closure
    text = "\n".join(lines)
    assert f"closure: {c['decision']}" in lines
    headline = ", ".join(f"{e['type']} at {e['location']}" for e in c["effects"])
    assert all(f"{e['type']} at {e['location']}" in c["decision"] for e in c["effects"]), headline
    rb = c["residual_before"]
    assert rb["structured"] and rb["sigma_source"] == STRUCTURED_ESTIMATE  # labelled, not called the noise
    assert f"noise {rb['sigma']:.3%} ({STRUCTURED_ESTIMATE})" in text
    for e in c["effects"]:
        moved = f" (moved from {', '.join(e['moved_from'])})" if e["moved_from"] else ""
        line = [x for x in lines if x.startswith(f"  {e['step']}. ")]
        assert len(line) == 1
        assert line[0].startswith(f"  {e['step']}. {STATUSES[e['status']]}: {e['type']} at {e['location']}{moved}, ")
        assert f"evidence {e['evidence']:.0%} ({'singled out' if e['identified'] else 'not singled out'}" in line[0]
    assert [x.split("swapped: ")[1] for x in lines if x.startswith("  swapped: ")] == c["swaps"]
    assert (f"at the run's parameters {c['error_at_run_parameters']:.3%} -> refitted without effects "
            f"{c['error_before']:.3%} -> with them {c['error_after']:.3%}") in text
    assert f"(the run reported {c['error_run']:.3%}: {c['error_run_metric']})" in text
    for name, value in c["parameters_after"].items():
        assert any(x.startswith(name) and x.rstrip().endswith(f"{value:.4g}") for x in lines), name


@pytest.mark.slow
def test_a_closure_out_of_time_starts_no_second_round_and_says_the_limit_stopped_it(closure, tmp_path,
                                                                                    prefect_harness):
    """The same closure decided again with its time limit already spent (--closure-minutes 0): the first effect
    is decided from the stored checks, no round, swap or move follows (only the backward check may drop that first
    effect), and the record says the limit stopped it; without the limit the selection went on to a second round."""
    import shutil
    from pathlib import Path

    _, record, _, _ = closure
    assert len(record["effects"]) >= 2 and record["selection_stopped"] != "time limit"
    run = tmp_path / "far"
    shutil.copytree(Path(record["run_folder"]), run)
    shutil.rmtree(run / "closure" / "step=decide")
    (run / "closure" / "closure.json").unlink()
    late = dg.diagnose("far", tmp_path, significance=0.05, max_minutes=0.0, effects=EFFECTS)
    assert late["selection_stopped"] == "time limit" and late["max_minutes"] == 0.0
    assert all(e["step"] == 1 for e in late["effects"]) and len(late["effects"]) <= 1
    assert not late["swaps"] and all(" dropped: " in m for m in late["moves"])
    assert "time limit (0 min) stopped the forward selection" in late["decision"]
    assert late["verdict"] in ("partly explained", "not explained")


@pytest.mark.slow
def test_within_the_models_own_error_only_effects_that_take_the_residual_to_the_noise_are_claimed(closure, tmp_path):
    """The far point mass's baseline (fitted from the run's alpha) leaves 0.97 % rms beyond the noise, less than its
    one mode in the band 0.5 % off would: within the model's own error. Its effects take the residual to the noise,
    so they stand. Decided again with a spring to the ground as the only kind, no spring stands out: the verdict is
    noise (it was `not explained`), the alpha-only fit the model after, and the decision says why. (Effects fitted
    that leave structure are listed as not claimed: tests/fe_core/test_mode_shifts.py, on the closure's core.)"""
    import shutil
    from pathlib import Path

    _, record, _, _ = closure
    assert record["own_error"]["within"] and record["effects"] and not record["residual_after"]["structured"]
    assert record["verdict"] != "noise" and not record["not_claimed"]
    shutil.copytree(Path(record["run_folder"]), tmp_path / "far")
    gain = dg.diagnose("far", tmp_path, name="gain", significance=0.05, effects=["grounded_spring"])
    assert gain["verdict"] == "noise" and not gain["effects"] and gain["residual_after"]["structured"]
    assert gain["selection_stopped"] == "the model's own error" and gain["own_error"]["within"]
    assert gain["parameters_after"] == gain["parameters_before"]
    assert gain["not_claimed"] == []
    assert gain["decision"] == f"no effect claimed: {gain['own_error']['reason']}"
    out = io.StringIO()
    dg.print_closure(gain, file=out)
    assert "verdict: noise" in out.getvalue().splitlines() and "not claimed" not in out.getvalue()
