"""The closure's joint fit of segment factors and effect parameters from several starts (issue 28,
:func:`fe_core.closure.fits.joint_fit`), on effects of realistic size.

Measured data are scikit-fem's (``benchmarks/make/large_effects.py``): the cantilever of
``data/examples/cantilever_matrices`` with a 6.0 kg point mass (19 % of its 31.4 kg) or a nearly rigid 5e7 N/m
spring to ground (about 40 times the beam's own bending stiffness at the tip), added to scikit-fem's own
matrices; a small plate assembled by scikit-fem with a patch of four cells at 10 % of their stiffness. The
models fitted are the exported matrices and this project's own assembly of the plate. Each fit starts from the
alpha-only fit from the nominal model (the closure's baseline) and the linear screen's size there.
"""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.make.large_effects import cantilever_case, plate_case, plate_model
from fe_core.closure.decisions import at_bound, bound_hit
from fe_core.closure.effects import build_library
from fe_core.closure.fits import (FAR_PER_TYPE, alpha_starts, checks_per_type, far_off, fit_update, joint_fit,
                                  size_starts)
from fe_core.closure.screening import Candidate, _start_value, screen

#: Size error allowed: the issue's 10 %. With 0.5 % noise on 135 (cantilever) or 216 (plate) amplitudes the
#: sizes are determined to about a per cent; 10 % is what the linear screen misses by (38 % for the mass).
SIZE_RTOL = 0.10


def _start(case: dict, effect: str):
    """The closure's situation: the alpha-only fit from the nominal model, the screen at it, the true location."""
    model, f, u = case["model"], case["freqs"], case["amplitude"]
    library = build_library(model, [effect])
    base = fit_update(model, f, u, np.zeros(model.n_segments))
    loc = case["truth"]["location"]
    screened = next(c for c in screen(model, f, base, library) if c.location == loc)
    return model, library[0], base, loc, screened.linear_values


def _fit(case, effect, base, loc, linear, starts):
    return joint_fit(case["model"], case["freqs"], case["amplitude"], starts, effect, loc, linear,
                     primary=_start_value(effect, loc, linear), max_evaluations=100)


@pytest.fixture(scope="module")
def mass_case():
    return cantilever_case("point_mass", 6.0)


def test_a_point_mass_of_19_percent_is_sized_although_the_screen_underestimates_it(mass_case):
    model, effect, base, loc, linear = _start(mass_case, "point_mass")
    truth = mass_case["truth"]
    assert truth["share_of_mass"] == pytest.approx(0.19, abs=0.005)
    assert linear[0] < 0.8 * truth["value"]  # linearised at zero mass: far too small
    fit = _fit(mass_case, effect, base, loc, linear, alpha_starts(model, base.alpha))
    assert fit.values[0] == pytest.approx(truth["value"], rel=SIZE_RTOL)
    # The baseline's factors were far off (one on its bound); refitted with the mass they are the truth's.
    assert np.max(np.abs(base.alpha - truth["alpha"])) > 0.5
    np.testing.assert_allclose(fit.alpha, truth["alpha"], atol=0.02)
    assert fit.start and not at_bound(effect, loc, fit.values)
    # The closure tries several starts only where the residual is far off: the baseline's is (rms of the log
    # residual 46 %), the fit with the mass is at the noise.
    assert far_off(base) and not far_off(fit)
    assert checks_per_type(base, 1) == FAR_PER_TYPE and checks_per_type(fit, 1) == 1


def test_a_nearly_rigid_spring_needs_the_nominal_start_and_is_then_sized():
    case = cantilever_case("grounded_spring_y", 5e7)
    model, effect, base, loc, linear = _start(case, "grounded_spring_y")
    # The single fit the closure made before: from the baseline's factors and the screened size.
    only_update = fit_update(model, case["freqs"], case["amplitude"], base.alpha, effect, loc,
                             _start_value(effect, loc, linear), max_evaluations=100, tol=1e-6)
    both = _fit(case, effect, base, loc, linear, alpha_starts(model, base.alpha))
    # From the baseline's factors alone the fit stays in a wrong basin (sum of squares far above the
    # 0.5 % noise's 135 * 0.005^2 = 0.0034); from the nominal factors it reaches the noise.
    noise_rss = case["amplitude"].size * 0.005**2
    assert only_update.rss > 100 * noise_rss
    assert both.rss < 2 * noise_rss
    assert both.start.startswith("nominal alpha")
    assert both.values[0] == pytest.approx(5e7, rel=SIZE_RTOL)


def test_a_patch_damaged_by_90_percent_is_sized():
    case = plate_case(-0.9)
    model, effect, base, loc, linear = _start(case, "patch")
    fit = _fit(case, effect, base, loc, linear, alpha_starts(model, base.alpha))
    assert fit.values[0] == pytest.approx(-0.9, abs=SIZE_RTOL * 0.9)
    np.testing.assert_allclose(fit.alpha, case["truth"]["alpha"], atol=0.02)


def test_a_mass_beyond_the_plausible_20_percent_ends_on_the_bound_and_is_flagged():
    from tasks.closure.summary import _verdict_json

    case = cantilever_case("point_mass", 7.85)  # 25 % of the beam
    model, effect, base, loc, linear = _start(case, "point_mass")
    fit = _fit(case, effect, base, loc, linear, alpha_starts(model, base.alpha))
    bound = 0.2 * model.total_mass()
    assert fit.values[0] == pytest.approx(bound, rel=1e-6)
    assert bound_hit(effect, loc, fit.values) == f"upper mass = {bound:.4g} kg"
    c = Candidate(effect="point_mass", location=loc, n_locations=len(effect.locations()), linear_values=linear,
                  linear_rss=0.0, linear_explained=0.0, fit=fit, explained=0.9, implausible=True)
    record = _verdict_json("partly explained", [], [c], {"point_mass": effect}, base)
    assert record["implausible"][0]["at_bound"] == f"upper mass = {bound:.4g} kg"
    assert record["implausible"][0]["start"] == fit.start


def test_size_starts_are_multiples_of_the_linear_size_inside_the_plausible_box():
    patch = build_library(plate_model(), ["patch"])[0]
    loc = patch.locations()[0]
    lo, hi = patch.bounds_at(loc)
    starts = size_starts(patch, loc, [-0.2])
    values = [float(v[0]) for _, v in starts]
    # 1 x and 3 x; 10 x would pass the lower bound -1: kept a tenth of the way off it, above -0.9.
    assert values[:2] == pytest.approx([-0.2, -0.6])
    assert values[2] == pytest.approx(0.9 * lo[0])
    assert all(lo[0] < v < hi[0] for v in values)
