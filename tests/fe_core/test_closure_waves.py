"""Far off, the closure checks further candidates only when the best of each kind made no contender
(fe_core.closure.screening.pick_in_waves / second_wave): hand-built screens, the expected picks by hand."""

from __future__ import annotations

import numpy as np

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
