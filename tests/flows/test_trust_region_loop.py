"""The adaptive loop's trust-region variant (``loop = "trust-region"``) through the flow: its stages and records."""

from __future__ import annotations

import numpy as np

from tasks import stages, trust_region


def test_trust_region_loop_runs_its_stages_and_keeps_candidates_in_the_region(reduced_config, two_iterations):
    config = reduced_config.replace(loop="trust-region")
    store, cols = two_iterations(config)
    info = store.stage_info(1, "distribution")
    assert info["kind"] == "trust_region"
    tr = trust_region.region(store, 1)
    _, X, _, E = stages.training_data(store, 1)
    assert np.array_equal(tr.centre, X[np.argmin(E)]) and tr.best == E.min()  # centred on the best FE sample
    hyper = store.read_table(1, "train", "hyperparameters")
    assert sum(hyper["name"].str.startswith("length_scale_")) == 6  # one length scale per parameter
    low, high = tr.box(*stages.parameter_box(config, 6))
    cand = store.read_table(1, "predict", "candidates")
    C = cand[cols].to_numpy()
    assert len(C) >= config.w - 1 and np.all(C >= low - 1e-12) and np.all(C <= high + 1e-12)
    assert np.all(np.isfinite(cand["predicted_error"]))
    chosen = store.read_table(1, "select")[cols].to_numpy()
    assert all(np.any(np.all(np.isclose(C, x), axis=1)) for x in chosen)  # the s selected are candidates
