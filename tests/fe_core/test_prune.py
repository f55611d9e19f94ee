"""The backward check of a forward selection (fe_core.closure.prune): an effect that later refits left with no gain
of its own is dropped, and two effects the data carry are both kept. Data: the three-plate benchmark's FRF with
effects added by the direct solve (extended_frf), 0.5 % noise."""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ as F
from fe_core.closure.effects import Applied, GroundedSpring, PointMass, extended_frf
from fe_core.closure.fits import fit_update
from fe_core.closure.prune import prune

NOISE = 0.005


def _data(model, truth, seed):
    u = np.abs(extended_frf(model, ALPHA_ACTUAL, F, truth, method="direct"))
    return u * np.exp(NOISE * np.random.default_rng(seed).standard_normal(u.shape))


def test_an_effect_left_with_no_gain_is_dropped_and_the_true_one_kept(benchmark_model):
    pm = PointMass(benchmark_model)
    u = _data(benchmark_model, [Applied(pm, "node 337", np.array([0.12]))], 3)
    # what a move can leave: an earlier mass, shrunk to a few grams at another node, beside the true one
    both = fit_update(benchmark_model, F, u, ALPHA_ACTUAL, pm, "node 337", [0.12],
                      prior=[Applied(pm, "node 457", np.array([0.002]))])
    fit, dropped, notes = prune(benchmark_model, F, u, both, NOISE)
    assert dropped == [0] and len(notes) == 1 and "node 457" in notes[0]
    assert [a.location for a in fit.applied] == ["node 337"]
    assert fit.applied[0].values[0] == pytest.approx(0.12, rel=0.05)
    assert fit.rss <= 1.05 * both.rss  # what the dropped mass explained is within the noise


def test_two_effects_the_data_carry_are_both_kept(benchmark_model):
    pm, gs = PointMass(benchmark_model), GroundedSpring(benchmark_model)
    truth = [Applied(pm, "node 337", np.array([0.12])), Applied(gs, "node 919", np.array([4e5]))]
    u = _data(benchmark_model, truth, 4)
    both = fit_update(benchmark_model, F, u, ALPHA_ACTUAL, gs, "node 919", [4e5], prior=truth[:1])
    fit, dropped, notes = prune(benchmark_model, F, u, both, NOISE)
    assert dropped == [] and notes == [] and fit is both


def test_after_a_drop_the_effects_left_are_judged_again_without_it(benchmark_model, monkeypatch):
    """An effect that carries over only beside another one that does not: judged first (it is the newer), it is
    kept while the other is in; once the other is dropped it is judged again and dropped too. The cross-band
    check and the refits are stand-ins here (the check's arithmetic is tests/fe_core/test_crossband.py's): the
    point is the order of judgement."""
    from fe_core.closure import prune as pr
    from fe_core.closure.fits import Fit

    pm, gs = PointMass(benchmark_model), GroundedSpring(benchmark_model)
    spurious, leaning = Applied(pm, "node 457", np.array([0.002])), Applied(gs, "node 919", np.array([1e3]))

    def fit_with(applied):
        return Fit(alpha=np.zeros(6), effect=None, location=None, values=np.zeros(0), model_amplitude=None,
                   residual=np.zeros((1, 1)), evaluations=0, prior=list(applied))

    judged = []

    def carries(model, f, u, alpha, applied, j, noise):
        judged.append((applied[j].location, len(applied)))
        here = applied[j]
        return (here is leaning and any(a is spurious for a in applied)), "stand-in"

    monkeypatch.setattr(pr, "carries_over", carries)
    monkeypatch.setattr(pr, "stands_out", lambda refitted, candidate, noise: True)  # the first rule passes both
    monkeypatch.setattr(pr, "_refit", lambda model, f, u, alpha, applied, bounds, restart: fit_with(applied))
    fit, dropped, notes = prune(benchmark_model, F, np.ones((len(F), 1)), fit_with([spurious, leaning]), NOISE,
                                across=True)
    assert judged == [("node 919", 2), ("node 457", 2), ("node 919", 1)]
    assert dropped == [0, 1] and fit.applied == [] and len(notes) == 2


def test_a_refit_without_an_effect_also_starts_from_the_alpha_only_fit_and_keeps_the_better_end(benchmark_model,
                                                                                                 monkeypatch):
    """Alpha where a dropped effect had taken it can lie in a worse basin than the alpha-only fit's (held-out hb20).
    The refit starts from both; the fits are stand-ins whose sum of squares is the start's distance from
    ``good``."""
    from fe_core.closure import prune as pr
    from fe_core.closure.fits import Fit

    good = np.full(6, 0.1)
    starts = []

    def fake_fit(model, f, u, start, *args, **kwargs):
        starts.append(np.asarray(start, float).copy())
        return Fit(alpha=np.asarray(start, float), effect=None, location=None, values=np.zeros(0),
                   model_amplitude=None, residual=np.full((1, 1), np.linalg.norm(start - good)), evaluations=1)

    monkeypatch.setattr(pr, "fit_update", fake_fit)
    far = np.full(6, -0.3)
    f = pr._refit(benchmark_model, F, None, far, [], (-0.5, 0.5), restart=good + 0.01)
    assert len(starts) == 2 and np.allclose(f.alpha, good + 0.01)
    starts.clear()
    f = pr._refit(benchmark_model, F, None, good, [], (-0.5, 0.5), restart=far)  # the first start is better
    assert len(starts) == 2 and np.allclose(f.alpha, good)
    starts.clear()
    pr._refit(benchmark_model, F, None, far, [], (-0.5, 0.5), restart=far.copy())  # the same start: one fit
    pr._refit(benchmark_model, F, None, far, [], (-0.5, 0.5))
    assert len(starts) == 2
