"""What the update hands its closure (``tasks.closure.handover``): the effects its evidence evaluated exactly, and no
baseline restarts for a large model whose evidence already weighed the basins (issue 41: at 500k DOFs the eight
restarts took 14.4 minutes for 25.2 -> 24.3 % rms).

The run's ``summary.json`` is written here as ``flows.update`` writes its ``evidence``; the model stands in by its
size alone (what :func:`tasks.fe_runs.is_large` reads).
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from tasks.closure.handover import evidence_found, restarts
from tasks.closure.store import ClosureStore
from tasks.fe_runs import LARGE_DOFS

EXACT = {"at": "local fit", "effect": "point_mass", "location": "node 12", "values": [0.88], "rss_effect": 28.8,
         "exact": True, "effect_alpha": [-0.15, 0.02]}
LINEAR = {"at": "nominal", "effect": "damping", "location": "b", "values": [5e-6], "rss_effect": 1904.0,
          "exact": False, "effect_alpha": []}


def _store(tmp_path, evidence) -> ClosureStore:
    """A closure store in a fresh run folder under ``tmp_path``, the run's ``summary.json`` with ``evidence`` (none
    written for None)."""
    run = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
    run.mkdir()
    if evidence is not None:
        (run / "summary.json").write_text(json.dumps({"evidence": evidence}))
    return ClosureStore(run / "closure")


@pytest.mark.parametrize("dofs, evidence, expected", [
    (LARGE_DOFS, {"choice": "closure", "screens": [LINEAR, EXACT]}, 0),       # large, handed over on an exact screen
    (LARGE_DOFS - 1, {"choice": "closure", "screens": [LINEAR, EXACT]}, 8),   # small: restarts as before
    (LARGE_DOFS, {"choice": "basins", "screens": [LINEAR, EXACT]}, 8),        # the evidence said basins
    (LARGE_DOFS, {"choice": "closure", "screens": [LINEAR]}, 8),              # only a linearised screen
    (LARGE_DOFS, None, 8),                                                     # no summary (a run without evidence)
])
def test_a_large_models_baseline_restarts_only_where_the_evidence_did_not_weigh_the_basins(tmp_path, dofs, evidence,
                                                                                          expected):
    model = SimpleNamespace(n_dofs=dofs)
    assert restarts(_store(tmp_path, evidence), model, {"restarts": 8}) == expected
    assert restarts(_store(tmp_path, evidence), model, {"restarts": 0}) == 0   # none asked: none made


def test_the_evidences_exact_effects_are_handed_over_with_their_alpha(tmp_path):
    library = {"point_mass": SimpleNamespace(locations=lambda: ["node 1", "node 12"])}
    found = evidence_found(_store(tmp_path, {"choice": "closure", "screens": [LINEAR, EXACT]}), library)
    assert [(f.effect, f.location, f.n_locations) for f in found] == [("point_mass", "node 12", 2)]
    np.testing.assert_array_equal(found[0].alpha, EXACT["effect_alpha"])
    assert found[0].values.tolist() == [0.88] and found[0].rss == 28.8
    assert evidence_found(_store(tmp_path, None), library) == []


@pytest.mark.parametrize("dofs, best, checked", [
    (LARGE_DOFS, 1.26, ["node 66094", "node 66065"]),               # large, the evidence 23 times the search's best
    (LARGE_DOFS, 2.9, ["node 66094", "node 66065", "node 12"]),     # large, within ten times: checked
    (LARGE_DOFS - 1, 1.26, ["node 66094", "node 66065", "node 12"]),  # small: every evidence find checked
])
def test_a_large_models_evidence_find_far_worse_than_the_search_is_not_checked(tmp_path, dofs, best, checked):
    """The 500k panel's case (session 30): the evidence's point mass at 28.8 against the exact search's 1.26; its
    check took 17 minutes to walk to the search's own node. A find at the place of a pick is never checked twice."""
    from fe_core.closure.far.search import Found
    from tasks.closure.handover import evidence_picks

    library = {"point_mass": SimpleNamespace(locations=lambda: ["node 12", "node 66065", "node 66094"])}
    found = [Found("point_mass", "node 66094", np.array([0.82]), np.zeros(2), 7.8, best, 3),
             Found("point_mass", "node 66065", np.array([0.88]), np.zeros(2), 1.7, best + 0.03, 3)]
    store = _store(tmp_path, {"choice": "closure", "screens": [LINEAR, EXACT]})
    picks = evidence_picks(store, SimpleNamespace(n_dofs=dofs), library, found, found)
    assert [f.location for f in picks] == checked
    again = {**EXACT, "location": "node 66065"}   # the evidence at a place the search picked: checked once
    store = _store(tmp_path, {"choice": "closure", "screens": [again]})
    picks = evidence_picks(store, SimpleNamespace(n_dofs=LARGE_DOFS - 1), library, found, found)
    assert [f.location for f in picks] == ["node 66094", "node 66065"]
