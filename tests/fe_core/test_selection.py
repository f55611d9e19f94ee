"""Forward selection with swaps, joint relocation and the evidence of each effect (fe_core.closure.selection).

The full table on data/cases/three_plate_closure_table is ``python -m benchmarks.closure --table``; here the pieces, cheaply:
the evidence weights by hand, a relocation on noise-free data, and two closures with small libraries.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fe_core.closure.decisions import verdict
from fe_core.closure.fits import Fit, fit_update
from fe_core.closure.loop import close_loop
from fe_core.closure.screening import Candidate
from fe_core.closure.effects import Applied, GroundedSpring, PointMass, build_library, extended_frf
from fe_core.closure.identify import IDENTIFIED, evidence
from fe_core.closure.selection import refine
from tasks.io.measured import read_measured

DATA2 = Path(__file__).resolve().parents[2] / "data" / "cases" / "three_plate_closure_table"
TRUTH2 = json.loads((DATA2 / "truth.json").read_text())["data"]


def scored(kind: str, location: str, ebic: float, implausible: bool = False, negligible: bool = False) -> Candidate:
    c = Candidate(effect=kind, location=location, n_locations=1, linear_values=np.zeros(1), linear_rss=0.0,
                  linear_explained=0.0)
    c.fit = Fit(alpha=np.zeros(6), effect=kind, location=location, values=np.array([1.0]), model_amplitude=None,
                residual=np.zeros((1, 1)), evaluations=0)
    c.ebic, c.implausible, c.negligible = ebic, implausible, negligible
    return c


def test_the_evidence_weighs_each_plausible_kind_once_by_exp_of_minus_half_its_extended_bic():
    incumbent = scored("point_mass", "node 1", -100.0)
    rivals = [scored("patch", "node 2 r2", -98.0), scored("patch", "node 3 r1", -90.0),  # patch once: its best
              scored("grounded_spring", "node 4", -120.0, implausible=True),  # on a bound: not a rival
              scored("segment_mass", "segment1", -80.0)]  # exp(-10): under 1 %, not listed
    share, listed = evidence(incumbent, rivals)
    total = 1.0 + np.exp(-1.0) + np.exp(-10.0)
    assert share == pytest.approx(1.0 / total, rel=1e-12)
    assert [(r.effect, r.location) for r in listed] == [("patch", "node 2 r2")]
    assert listed[0].weight == pytest.approx(np.exp(-1.0) / total, rel=1e-12)
    assert listed[0].delta_ebic == pytest.approx(2.0)
    assert share < IDENTIFIED  # 2 ln B = 2 against one rival is not strong evidence
    alone, none = evidence(incumbent, [scored("patch", "node 2 r2", -93.0)])  # 2 ln B = 7: identified
    assert alone >= IDENTIFIED and [r.effect for r in none] == ["patch"]


def test_a_rival_too_small_to_be_an_effect_takes_no_evidence_from_it():
    """Held-out hd02: a patch that shifts no mode by the size rule's bar held all the evidence against a point mass of
    0.145 kg (2 ln B = 6317); it may not replace the mass in a swap, so it is no rival either: listed after the
    rivals with no weight."""
    incumbent = scored("point_mass", "node 1", -100.0)
    small = scored("patch", "node 2 r2", -6417.0, negligible=True)
    share, listed = evidence(incumbent, [small, scored("grounded_spring", "node 4", -98.0)])
    assert share == pytest.approx(1.0 / (1.0 + np.exp(-1.0)), rel=1e-12)
    assert [(r.effect, r.negligible, r.weight) for r in listed][1:] == [("patch", True, 0.0)]  # listed, not weighed
    assert listed[0].effect == "grounded_spring" and listed[1].delta_ebic == pytest.approx(-6317.0)
    far_worse = scored("patch", "node 5 r1", -80.0, negligible=True)  # would hold under 1 %: not listed
    assert [r.effect for r in evidence(incumbent, [far_worse])[1]] == []
    small.negligible = False  # the same rival plausible in size holds the evidence
    assert evidence(incumbent, [small])[0] < 1e-100
    incumbent.negligible = True  # the incumbent itself is weighed whatever its size
    assert evidence(incumbent, [])[0] == 1.0


def test_point_masses_found_beside_each_other_are_one_between_their_nodes(benchmark_model):
    """identify.combined: masses (and springs along one axis) within 5 % of the structure's size of one another are
    one, their sum at the value-weighted centre; farther apart, another kind, or not additive: apart."""
    from fe_core.closure.effects import Applied
    from fe_core.closure.effects.springs import GroundedSpring
    from fe_core.closure.identify import combined

    pm, spring = PointMass(benchmark_model), GroundedSpring(benchmark_model)
    nodes = benchmark_model.mesh.nodes
    a = [Applied(pm, "node 337", np.array([0.15])), Applied(pm, "node 307", np.array([0.05])),  # 14.4 mm apart
         Applied(spring, "node 337", np.array([1e5])),  # at the same node, another kind
         Applied(pm, "node 457", np.array([0.2]))]  # four elements away
    groups = combined(benchmark_model, a)
    assert len(groups) == 1
    g = groups[0]
    assert (g.effect, g.indices, g.locations) == ("point_mass", [0, 1], ["node 337", "node 307"])
    assert g.value == pytest.approx(0.2, rel=1e-14)
    centre = (0.15 * nodes[337] + 0.05 * nodes[307]) / 0.2
    assert np.allclose(g.position, centre, rtol=0, atol=1e-12)
    assert g.span_mm == pytest.approx(1e3 * np.linalg.norm(nodes[337] - nodes[307]), rel=1e-12)
    chain = a[:2] + [Applied(pm, "node 247", np.array([0.1]))]  # 43 mm from node 337, linked through node 307
    assert [len(g.indices) for g in combined(benchmark_model, chain)] == [3]
    assert combined(benchmark_model, [a[0], a[3]]) == []


def test_noise_after_with_a_rival_as_good_is_ambiguous_not_explained():
    class A:
        def __init__(self, structured):
            self.structured = structured

    assert verdict(A(True), A(False), 2, identified=False) == "ambiguous"
    assert verdict(A(True), A(False), 2, identified=True) == "explained"
    assert verdict(A(True), A(True), 2, identified=False) == "partly explained"


def test_an_earlier_effect_placed_wrong_is_moved_back_by_the_joint_relocation(benchmark_model):
    """Noise-free data with a point mass at node 337 and a spring at node 919; the mass starts at node 457
    (where it lands alone on data/cases/three_plate_closure_table/two_effects.csv): relocation moves it back."""
    from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ as F

    pm, gs = PointMass(benchmark_model), GroundedSpring(benchmark_model)
    truth = [Applied(pm, "node 337", np.array([0.12])), Applied(gs, "node 919", np.array([4e5]))]
    u = np.abs(extended_frf(benchmark_model, ALPHA_ACTUAL, F, truth, method="direct"))
    start = fit_update(benchmark_model, F, u, ALPHA_ACTUAL, gs, "node 919", [4e5],
                       prior=[Applied(pm, "node 457", np.array([0.06]))])
    late, late_moves = refine(benchmark_model, F, u, start, late=lambda: True)  # the closure's time is up
    assert late is start and late_moves == []
    moved, moves = refine(benchmark_model, F, u, start)
    assert moves and [a.location for a in moved.applied] == ["node 337", "node 919"]
    assert moved.rss < 1e-4 * start.rss  # noise-free: the truth fits to round-off of the fit's tolerance
    assert moved.applied[0].values[0] == pytest.approx(0.12, rel=1e-3)


@pytest.mark.slow
def test_the_transducers_mass_is_found_from_a_baseline_with_enough_starts(benchmark_model):
    """Two of nine alpha-only starts reach the right basin on these data (the nominal start does not)."""
    truth = TRUTH2["transducer_mass.csv"]["effects"][0]
    m = read_measured(DATA2 / "transducer_mass.csv")
    result = close_loop(benchmark_model, m.frequencies_hz, m.amplitude, np.zeros(6),
                        build_library(benchmark_model, ["sensor_mass", "point_mass", "sensor_gain"]),
                        noise=0.005, restarts=8, per_type=1)
    assert result.verdict == "explained" and [c.effect for c in result.steps] == ["sensor_mass"]
    assert result.final.values[0] == pytest.approx(truth["value"], rel=0.05)
    assert result.weights[0] >= IDENTIFIED


@pytest.mark.slow
def test_a_point_mass_or_a_stiffer_patch_the_data_cannot_tell_is_ambiguous(benchmark_model):
    """far_point_mass.csv (0.15 kg at node 201, alpha far from nominal): a stiffened patch next to it fits as
    well; the verdict names both and calls neither found."""
    m = read_measured(DATA2 / "far_point_mass.csv")
    result = close_loop(benchmark_model, m.frequencies_hz, m.amplitude, np.zeros(6),
                        build_library(benchmark_model, ["point_mass", "patch"]), noise=0.005, restarts=2,
                        per_type=1)
    assert result.verdict == "ambiguous" and not result.after.structured
    kinds = {c.effect for c in result.steps} | {r.effect for rs in result.rivals for r in rs}
    assert kinds == {"point_mass", "patch"}
    assert min(result.weights) < IDENTIFIED


def test_the_location_spread_says_how_far_the_evidence_reaches(benchmark_model):
    """A damaged patch is pinned to two overlapping patches; a point mass far from the sensors' strong
    points spreads over tens of nodes (data/cases/three_plate_closure_table, fitted at the true location from the true alpha)."""
    from fe_core.closure.identify import location_spread, spread_mm

    lib = {e.kind: e for e in build_library(benchmark_model, ["patch", "point_mass"])}
    spans = {}
    for name in ("damaged_patch.csv", "far_point_mass.csv"):
        truth = TRUTH2[name]
        t = truth["effects"][0]
        m = read_measured(DATA2 / name)
        fit = fit_update(benchmark_model, m.frequencies_hz, m.amplitude, truth["alpha"], lib[t["effect"]],
                         t["location"], [t["value"]])
        spread = location_spread(benchmark_model, m.frequencies_hz, fit, 0)
        assert t["location"] in [loc for loc, _ in spread]
        assert sum(w for _, w in spread) >= 0.95
        spans[name] = (len(spread), spread_mm(lib[t["effect"]], t["location"], spread))
    assert spans["damaged_patch.csv"][0] <= 3 and spans["damaged_patch.csv"][1] <= 25.0
    assert spans["far_point_mass.csv"][0] >= 10 and spans["far_point_mass.csv"][1] >= 40.0


def test_an_effect_is_located_when_the_evidence_stays_within_five_percent_of_the_structure(benchmark_model):
    from fe_core.closure.identify import located

    pm = PointMass(benchmark_model)
    size = 1e3 * np.linalg.norm(np.ptp(benchmark_model.mesh.nodes, axis=0))  # 641 mm: 32 mm allowed
    near = [("node 337", 0.6), ("node 307", 0.4)]  # one element (14.4 mm) apart
    far = [("node 337", 0.6), ("node 457", 0.4)]  # four elements apart
    assert 30.0 < 0.05 * size < 35.0
    assert located(benchmark_model, pm, "node 337", near) and not located(benchmark_model, pm, "node 337", far)
    assert located(benchmark_model, pm, "node 337", [("node 337", 1.0)])
    assert not located(benchmark_model, pm, "node 337", [("node 457", 1.0)])  # the evidence is elsewhere


@pytest.mark.slow
def test_two_effects_at_once_the_mass_at_its_node_and_the_spring_or_a_soft_patch_beside_it(benchmark_model):
    """two_effects.csv (0.12 kg at node 337, 4e5 N/m to ground at node 919): greedy selection had ended
    `explained` with the mass 4 elements off and two softened patches for the spring. With joint
    relocation and swaps the mass is at its node; the spring is one node station from its node (18 mm).
    A softened patch there fits as well (extended BIC +1.3) but shifts no mode by the size rule's bar: listed
    beside the spring, not weighed against it (it may not replace it in a swap either), so the spring is a
    finding; while it was weighed (until the fourth held-out set), the verdict was ``ambiguous``."""
    truth = TRUTH2["two_effects.csv"]["effects"]
    m = read_measured(DATA2 / "two_effects.csv")
    result = close_loop(benchmark_model, m.frequencies_hz, m.amplitude, np.zeros(6),
                        build_library(benchmark_model, ["point_mass", "grounded_spring", "patch", "joint_band"]),
                        noise=0.005, restarts=2, per_type=1)
    (mass, spring) = result.final.applied
    assert (mass.effect.kind, mass.location) == ("point_mass", truth[0]["location"])
    assert mass.values[0] == pytest.approx(truth[0]["value"], rel=0.05)
    assert result.weights[0] >= IDENTIFIED and result.located[0]
    nodes = benchmark_model.mesh.nodes
    assert spring.effect.kind == "grounded_spring"
    assert np.linalg.norm(nodes[int(spring.location.split()[1])] - nodes[truth[1]["node"]]) < 0.02
    assert [(r.effect, r.negligible, r.weight) for r in result.rivals[1]] == [("patch", True, 0.0)]
    assert abs(result.rivals[1][0].delta_ebic) < 6.0  # it fits about as well: 2 ln B < 6
    assert result.weights[1] >= IDENTIFIED
    assert result.verdict == "explained" and not result.after.structured


def test_the_time_limit_stops_the_selection_between_checks_and_leaves_the_round_undecided(benchmark_model,
                                                                                           monkeypatch):
    """far_point_mass.csv (0.15 kg at node 201) from the true alpha: out of time after two full checks, the
    round is not decided on part of its checks; its two fits are kept in its ranking and nothing is added."""
    from fe_core.closure import screening
    from fe_core.closure.fits import baseline
    from fe_core.closure.selection import forward_select

    truth = json.loads((DATA2 / "truth.json").read_text())["data"]["far_point_mass.csv"]
    m = read_measured(DATA2 / "far_point_mass.csv")
    library = build_library(benchmark_model, ["point_mass", "grounded_spring"])
    base, before = baseline(benchmark_model, m.frequencies_hz, m.amplitude, truth["alpha"], noise=0.005)
    assert before.structured
    made = []
    real = screening.check
    monkeypatch.setattr(screening, "check", lambda *a, **k: made.append(a[5]) or real(*a, **k))
    sel = forward_select(benchmark_model, m.frequencies_hz, m.amplitude, base, before, library, per_type=2,
                         out_of_time=lambda margin=0.0: len(made) >= 2, search=False)
    assert len(made) == 2 and sel.stopped == "time limit" and not sel.steps
    kept = {id(c) for c in sel.rounds[-1] if c.fit is not None}  # the two fits (one, if they met at one node)
    assert kept and kept <= {id(c) for c in made} and all(c.fit is not None for c in made)
    assert all(c.ebic is not None for c in sel.rounds[-1] if c.fit is not None)  # scored (ho23: unscored, unranked)
    assert sel.final is base and sel.after.structured
    # Without the limit the same round adds the mass (at its node or next to it: the check's moves).
    made.clear()
    free = forward_select(benchmark_model, m.frequencies_hz, m.amplitude, base, before, library, per_type=2,
                          max_effects=1, search=False)
    assert len(made) > 2 and free.stopped != "time limit" and free.steps[0].effect == "point_mass"


def test_a_closure_out_of_time_before_its_first_round_adds_nothing_and_says_why(benchmark_model):
    m = read_measured(DATA2 / "far_point_mass.csv")
    truth = json.loads((DATA2 / "truth.json").read_text())["data"]["far_point_mass.csv"]
    result = close_loop(benchmark_model, m.frequencies_hz, m.amplitude, truth["alpha"],
                        build_library(benchmark_model, ["point_mass"]), noise=0.005, max_minutes=0.0)
    assert result.stopped == "time limit" and not result.steps and result.verdict == "not explained"



def test_when_the_backward_check_drops_every_effect_the_alpha_only_fit_it_started_from_is_kept(benchmark_model,
                                                                                               monkeypatch):
    """Held-out hb20: both masses were dropped and alpha, refitted from where the masses had taken it, ended in a
    worse minimum (70 % rms) than the closure's own alpha-only fit (47 %), which the closure then reported as its
    model "after". Here the backward check is made to drop the one effect added and to return a worse alpha-only
    fit: the selection reports the fit it started from."""
    from fe_core.closure import selection
    from fe_core.closure.fits import baseline

    truth = TRUTH2["far_point_mass.csv"]
    m = read_measured(DATA2 / "far_point_mass.csv")
    library = build_library(benchmark_model, ["point_mass"])
    base, before = baseline(benchmark_model, m.frequencies_hz, m.amplitude, truth["alpha"], noise=0.005)
    worse = fit_update(benchmark_model, m.frequencies_hz, m.amplitude, np.asarray(truth["alpha"]) + 0.3,
                       max_evaluations=1)
    assert worse.rss > base.rss and not worse.applied
    seen = []

    def drop_all(model, freqs, u, fit, *args, **kwargs):
        seen.append(fit)
        return worse, list(range(len(fit.applied))), ["every effect dropped (by the test)"]

    monkeypatch.setattr(selection, "prune", drop_all)
    sel = selection.forward_select(benchmark_model, m.frequencies_hz, m.amplitude, base, before, library,
                                   per_type=1, max_effects=1, search=False, swaps=False, baseline=base)
    assert seen and seen[0].applied  # an effect was added, then dropped
    assert not sel.steps and sel.final is base
    assert sel.after.rms == pytest.approx(before.rms)


@pytest.mark.parametrize("drop_last", [True, False])
def test_a_selection_at_its_most_effects_whose_last_effect_is_dropped_stopped_because_nothing_stands_out(
        benchmark_model, monkeypatch, drop_last):
    """Held-out hd14: three effects added (the most), the third dropped by the backward check; the selection still
    said it stopped at its most effects, so the misfit left (23 % of the alpha-only fit's) was not judged the
    model's own. The best of the last round not standing out beside the others means no further one does. Here
    the backward check is made to drop the one effect of a selection of at most one (the mass of two_effects.csv,
    its spring left), or nothing."""
    from fe_core.closure import selection
    from fe_core.closure.fits import baseline

    truth = TRUTH2["two_effects.csv"]
    m = read_measured(DATA2 / "two_effects.csv")
    library = build_library(benchmark_model, ["point_mass"])  # the mass is added; the spring's structure remains
    base, before = baseline(benchmark_model, m.frequencies_hz, m.amplitude, truth["alpha"], noise=0.005)

    seen = []

    def backward(model, freqs, u, fit, *args, **kwargs):
        seen.append(fit)
        return (base, [0], ["dropped (by the test)"]) if drop_last else (fit, [], [])

    monkeypatch.setattr(selection, "prune", backward)
    sel = selection.forward_select(benchmark_model, m.frequencies_hz, m.amplitude, base, before, library,
                                   per_type=1, max_effects=1, search=False, swaps=False, baseline=base)
    assert seen and seen[0].applied[0].effect.kind == "point_mass"  # the mass was added, then judged
    if drop_last:
        assert not sel.steps and sel.stopped == "nothing stands out"
    else:
        assert len(sel.steps) == 1 and sel.stopped == "most effects"


def test_the_budget_counts_the_backward_checks_refits_at_the_fastest_rate_measured_on_the_fits():
    from fe_core.closure.budget import REFIT_EVALUATIONS, Budget, backward_refits

    # one effect: only the refit after a drop across the band; two or more: one (two with a restart) without each
    assert [backward_refits(n, restart=True) for n in range(4)] == [0, 1, 5, 7]
    assert [backward_refits(n, restart=False, across=False) for n in range(4)] == [0, 0, 2, 3]
    asked = []
    b = Budget(lambda margin: asked.append(margin) or margin > 100.0, restart=True)
    fit = lambda s, e: Fit(alpha=np.zeros(1), effect=None, location=None, values=np.zeros(0), model_amplitude=None,
                           residual=np.zeros((1, 1)), evaluations=e, seconds=s)
    b.see([fit(8.0, 4), None, fit(1.0, 0), fit(6.0, 3)])   # the fastest per evaluation: 2 s
    b.see([fit(25.0, 4)])  # a fit whose seconds include reduced evaluations its count does not see: not the rate
    assert b.per_evaluation == 2.0 and b.backward_seconds(2) == 5 * REFIT_EVALUATIONS * 2.0
    assert not b.late(0) and asked[-1] == 0.0
    b.step_seconds["round"] = 30.0
    assert b.late(1, "round") == (REFIT_EVALUATIONS * 2.0 + 30.0 > 100.0) and asked[-1] == REFIT_EVALUATIONS * 2.0 + 30
    assert not Budget(None, restart=True).late(3, "round")


def test_a_round_starts_only_if_the_backward_check_after_it_fits_in_the_time_left(benchmark_model, monkeypatch):
    """two_effects.csv from the true alpha: with time for the backward check of one effect but not of two, the
    selection adds the first effect, makes its second round (most rounds add nothing: held-out hf11's second round
    was cut 2.3 min into 12.7 while its backward check was to take 2 s) and does not add the second effect (held-out
    he07 began a second round and a swap it could not afford: the backward check of its two effects then took 329 s
    past the limit); with time for both, it adds two; with time for none, its first round adds nothing."""
    from fe_core.closure import budget as B
    from fe_core.closure.fits import baseline
    from fe_core.closure.selection import forward_select

    monkeypatch.setattr(B.Budget, "see", lambda self, fits: setattr(self, "per_evaluation", 1.0))  # 1 s each
    truth = TRUTH2["two_effects.csv"]
    m = read_measured(DATA2 / "two_effects.csv")
    library = build_library(benchmark_model, ["point_mass", "grounded_spring"])
    base, before = baseline(benchmark_model, m.frequencies_hz, m.amplitude, truth["alpha"], noise=0.005)
    one = B.backward_refits(1, restart=True) * B.REFIT_EVALUATIONS   # 25 s
    two = B.backward_refits(2, restart=True) * B.REFIT_EVALUATIONS   # 125 s

    def select(seconds_left):
        return forward_select(benchmark_model, m.frequencies_hz, m.amplitude, base, before, library, per_type=1,
                              max_effects=2, search=False, swaps=False, baseline=base,
                              out_of_time=lambda margin: margin > seconds_left)
    short = select(0.5 * (one + two))
    # two rounds: the first's effect added (the backward check may then drop it: alone, the mass does not carry
    # over across the band on these data), the second's found and not added
    assert short.stopped == "time limit" and len(short.rounds) == 2 and len(short.steps) <= 1
    assert all(any(c.fit is not None for c in r) for r in short.rounds)
    free = select(10.0 * two)
    assert free.stopped != "time limit" and len(free.rounds) == 2 and len(free.steps) == 2
    none = select(0.5 * one)
    assert len(none.rounds) == 1 and not none.steps and none.stopped == "time limit"
