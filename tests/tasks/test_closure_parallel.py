"""The forward selection's checks in worker processes (tasks.closure.parallel) give the checks made in this process:
the same places, the fits equal within the optimiser's tolerance, the earlier effect carried and refitted."""

from __future__ import annotations

import copy
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fe_core.closure import fast, screening
from fe_core.closure.fits import baseline
from tasks.closure import parallel
from tasks.closure.library import cached_library
from tasks.io.measured import read_measured
from tasks.problem import read_model_ref

DATA = Path(__file__).resolve().parents[2] / "data" / "cases" / "three_plate_closure_table" / "two_effects.csv"
EFFECTS = ["point_mass", "grounded_spring", "patch"]


def test_a_wave_checked_in_workers_is_the_wave_checked_here(monkeypatch):
    model, ref = read_model_ref("three_plate")
    library = cached_library(model, EFFECTS)
    m = read_measured(DATA)
    freqs, u = m.frequencies_hz, m.amplitude
    start, _ = baseline(model, freqs, u, np.zeros(6), noise=0.005, restarts=2)
    # The base of a second round: the mass (0.12 kg at node 337 in the data) already in the model.
    base = fast.fit_update(model, freqs, u, start.alpha, library["point_mass"], "node 337", np.array([0.1]),
                           max_evaluations=100, tol=1e-6)
    screened = screening.screen(model, freqs, base, list(library.values()))
    picked = screening.pick_for_check(screened, 1)
    pairs = [(library[c.effect], c) for c in picked]
    assert len(pairs) == 3

    assert parallel.process_checks(SimpleNamespace(model=model, ref=ref), {"n_jobs": 2}, library) is None  # 3,000 DOFs
    monkeypatch.setattr(parallel, "MIN_DOFS", 0)
    assert parallel.process_checks(SimpleNamespace(model=model, ref=ref), {"n_jobs": 1}, library) is None
    check_many = parallel.process_checks(SimpleNamespace(model=model, ref=ref), {"n_jobs": 2, "effects": EFFECTS},
                                         library)
    here = screening.check_all(model, freqs, u, base, copy.deepcopy(pairs), 6, (-0.95, 1.0), 100)
    there = check_many(model, freqs, u, base, pairs, 6, (-0.95, 1.0), 100)

    assert [c is p for c, (_, p) in zip(there, pairs)] == [True] * 3  # the callers' candidates, filled
    for a, b in zip(here, there):
        assert (b.effect, b.location, b.moved_from) == (a.effect, a.location, a.moved_from)
        # Both fits stop at the optimiser's tolerance (1e-6) from their own reduced bases.
        assert b.fit.rss == pytest.approx(a.fit.rss, rel=1e-4)
        assert [(x.effect.kind, x.location) for x in b.fit.applied] == [("point_mass", "node 337"),
                                                                         (a.effect, a.location)]
        assert all(x.effect is library[x.effect.kind] for x in b.fit.applied)  # this process's effects
        assert np.allclose(b.fit.alpha, a.fit.alpha, rtol=0, atol=1e-3)
        assert b.fit.prior[0].values[0] == pytest.approx(a.fit.prior[0].values[0], rel=1e-3)
        assert np.allclose(b.fit.residual, a.fit.residual, rtol=0, atol=1e-3)
