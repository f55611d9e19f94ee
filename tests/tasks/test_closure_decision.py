"""The closure's headline (tasks.closure.summary.decision_text) says why no effect is left, and which effects found
beside each other are one."""

from types import SimpleNamespace

from tasks.closure.summary import decision_text

STRUCTURE = SimpleNamespace(structured=True, p_chi2=1e-9, significance=0.01)


def test_no_effect_says_which_were_dropped_as_not_carrying_over():
    moves = ["point_mass at node 596 = [0.0005] dropped: it does not carry over across the band, the model's own "
             "error where it was fitted (...)", "swap: a -> b"]
    text = decision_text("not explained", [], STRUCTURE, STRUCTURE, moves)
    assert text.startswith("no effect: point_mass at node 596 = [0.0005] did not carry over")
    assert "no checked candidate" not in text


def test_no_effect_without_drops_says_nothing_lowers_the_extended_bic():
    assert decision_text("not explained", [], STRUCTURE, STRUCTURE) == (
        "no effect: no checked candidate lowers the extended BIC")


def test_effects_found_beside_each_other_are_named_as_one_between_their_nodes():
    effects = [{"status": "finding", "type": "point_mass", "location": f"node {n}"} for n in (6007, 5778)]
    group = {"type": "point_mass", "locations": ["node 6007", "node 5778"], "steps": [1, 2], "value": 0.2398,
             "unit": "kg", "position_m": [0.35094, 0.24711, 0.004], "span_mm": 14.7}
    text = decision_text("explained", effects, STRUCTURE, STRUCTURE, (), [group])
    assert ("added point_mass at node 6007; added point_mass at node 5778 (node 6007 and node 5778, 15 mm apart, are "
            "one point_mass of 0.2398 kg between them, at (0.351, 0.247, 0.004) m): the residual before") in text
    assert "between them" not in decision_text("explained", effects, STRUCTURE, STRUCTURE)
