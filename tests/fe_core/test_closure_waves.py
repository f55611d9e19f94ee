"""Far off, the closure checks further candidates only when the best of each kind made no contender
(fe_core.closure.screening.pick_in_waves / second_wave): hand-built screens, the expected picks by hand. And the
screen's one-value fits (screening._linear_fits_1) against the explicit projection."""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.closure.screening import Candidate, pick_in_waves, second_wave


def _screen(rows):
    """Candidates from ``(effect, location, linear_explained)``, as the screen returns them (best first)."""
    out = [Candidate(effect=e, location=loc, n_locations=10, linear_values=np.array([1.0]), linear_rss=1.0 - x,
                     linear_explained=x) for e, loc, x in rows]
    return sorted(out, key=lambda c: -c.linear_explained)


SCREEN = _screen([("point_mass", f"node {n}", 0.9 - 0.01 * k) for k, n in enumerate((5, 6, 7, 8, 9, 10))]
                 + [("patch", f"node {n} r1", 0.5 - 0.01 * k) for k, n in enumerate((20, 21, 22))]
                 + [("sensor_mass", "all sensors", 0.1)])


def test_the_first_wave_is_the_best_of_each_kind_and_the_rest_the_far_off_further_ones():
    first, rest = pick_in_waves(SCREEN, per_type=1, far_per_type=5)
    assert [(c.effect, c.location) for c in first] == [
        ("point_mass", "node 5"), ("patch", "node 20 r1"), ("sensor_mass", "all sensors")]
    assert [(c.effect, c.location) for c in rest] == [
        ("point_mass", "node 6"), ("point_mass", "node 7"), ("point_mass", "node 8"), ("point_mass", "node 9"),
        ("patch", "node 21 r1"), ("patch", "node 22 r1")]
    assert pick_in_waves(SCREEN, per_type=1, far_per_type=1)[1] == []  # not far off: one wave


def test_a_contender_in_the_first_wave_makes_the_further_candidates_unneeded():
    _, rest = pick_in_waves(SCREEN, per_type=1, far_per_type=5)
    base_rss = 10.0
    # the point mass's full fit leaves 3.0 of 10 (explains 70 %): its moves re-screen at the fitted size
    assert second_wave(rest, [3.0, 6.0, 9.9], base_rss) == []
    # exactly half explained is a contender; just under half is not
    assert second_wave(rest, [5.0], base_rss) == []
    assert second_wave(rest, [5.001], base_rss) == rest


def test_where_no_kind_made_a_contender_every_further_candidate_is_checked():
    _, rest = pick_in_waves(SCREEN, per_type=1, far_per_type=5)
    assert second_wave(rest, [8.0, 7.0], 10.0) == rest


def test_the_screen_s_one_value_fits_equal_the_explicit_projection():
    """The screen's fits of one-value effects never form the projected columns (``screening._linear_fits_1``):
    against the explicit ``P j = j - q q^T j`` on general columns, one nearly in the refitted span (a difference
    of squares would keep 4 digits there) and one that explains the residual to 1e-9; a column in the span beside
    them."""
    from fe_core.closure.screening import _linear_fits_1

    rng = np.random.default_rng(7)
    n, m = 400, 6
    q, _ = np.linalg.qr(rng.normal(size=(n, m)))
    r = rng.normal(size=n)
    r_perp = r - q @ (q.T @ r)
    j = rng.normal(size=(5, n))
    j[1] = q @ rng.normal(size=m) + 1e-6 * rng.normal(size=n)  # nearly in the span
    j[2] = q @ rng.normal(size=m)  # in it: its value is rounding, as the explicit projection's is
    j[3] = -3.0 * r_perp + 1e-9 * (j[0] - q @ (q.T @ j[0])) + q @ rng.normal(size=m)  # explains nearly all
    d, rss = _linear_fits_1(j, r_perp, q)
    jp = j - (j @ q) @ q.T
    jj = np.einsum("ln,ln->l", jp, jp)
    for k in (0, 1, 3, 4):
        want = -(jp[k] @ r_perp) / jj[k]
        assert d[k] == pytest.approx(want, rel=1e-9)
        for v in (want, 0.5 * want, -2.0):
            res = r_perp + v * jp[k]
            assert rss(np.full(5, v))[k] == pytest.approx(res @ res, rel=1e-9, abs=1e-12 * (r_perp @ r_perp))
    assert rss(d)[3] < 1e-15 * (r_perp @ r_perp)


def test_the_screen_made_a_few_locations_at_a_time_is_the_screen_made_at_once(monkeypatch):
    """The screen forms its derivative columns :data:`~fe_core.closure.screening.SCREEN_BYTES` at a time (the 500k
    panel's every node is 4.8 GB at once): with room for 97 locations at a time, every candidate's values and sums of
    squares are those of one pass (each location's fit is its own; the products' rounding may differ)."""
    from pathlib import Path

    from fe_core.closure import screening
    from fe_core.closure.effects import extended_frf
    from fe_core.closure.fits import Fit
    from fe_core.inference.residual import log_residual
    from tasks.closure.library import cached_library
    from tasks.io.measured import read_measured
    from tasks.problem import read_model_ref

    model, _ = read_model_ref("three_plate")
    library = list(cached_library(model, ["point_mass", "grounded_spring", "patch"]).values())
    m = read_measured(Path(__file__).resolve().parents[2] / "data" / "cases" / "three_plate_closure_table"
                      / "two_effects.csv")
    alpha = np.array([0.05, -0.03, 0.02, 0.0, -0.04, 0.01])  # a point near the data's, not fitted (a screen's input)
    base = Fit(alpha=alpha, effect=None, location=None, values=np.zeros(0), model_amplitude=None,
               residual=log_residual(np.abs(extended_frf(model, alpha, m.frequencies_hz)), m.amplitude), evaluations=0)
    lin = screening.LinearisedResponse(model, alpha, m.frequencies_hz, [])
    once = {(c.effect, c.location): c for c in screening.screen(model, m.frequencies_hz, base, library, lin)}
    monkeypatch.setattr(screening, "SCREEN_BYTES", 97 * 8 * m.amplitude.size)
    chunked = screening.screen(model, m.frequencies_hz, base, library, lin)
    assert len(chunked) == len(once) > 3 * 97
    for c in chunked:
        c0 = once[(c.effect, c.location)]
        np.testing.assert_allclose(c.linear_values, c0.linear_values, rtol=1e-9,
                                   atol=1e-12 * np.abs(c0.linear_values).max())
        assert c.linear_rss == pytest.approx(c0.linear_rss, rel=1e-9)
