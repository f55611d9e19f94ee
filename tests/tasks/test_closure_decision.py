"""The closure's headline (tasks.closure.summary.decision_text) says why no effect is left."""

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
