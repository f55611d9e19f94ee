"""Trainers: Table 1 settings, finding known minima inside bounds, reproducibility."""

from __future__ import annotations

import numpy as np
import pytest

from mrgp_core import optimizers
from mrgp_core.optimizers import annealing, particle_swarm

BOUNDS = np.array([[-2.0, 3.0], [-1.0, 4.0]])
MINIMUM = np.array([1.2, 0.7])
LOCATION_ATOL = {"gradient": 1e-6, "sao": 3e-2, "pso": 1e-3}
# Quick settings so each run costs a few thousand cheap evaluations at most.
QUICK = {
    "gradient": {},
    "sao": {"iterations_per_temperature": 100},
    "pso": {"swarm_size": 30, "max_evaluations": 3000},
}


def bumpy(x):
    """Global minimum 0 at MINIMUM, with ripples that trap a local search started far away."""
    z = np.asarray(x) - MINIMUM
    return float(np.sum(z**2) + 0.5 * np.sum(1 - np.cos(3 * np.pi * z)))


def bumpy_value_and_grad(x):
    z = np.asarray(x) - MINIMUM
    return bumpy(x), 2 * z + 1.5 * np.pi * np.sin(3 * np.pi * z)


def run(name, seed, fun=bumpy, **kw):
    return optimizers.get_trainer(name)(
        fun, BOUNDS, np.random.default_rng(seed), QUICK[name], value_and_grad=bumpy_value_and_grad, **kw
    )


def test_unknown_trainer_name_lists_the_valid_ones():
    with pytest.raises(ValueError, match="valid trainers are gradient, pso, sao"):
        optimizers.get_trainer("genetic")
    assert set(optimizers.TRAINERS) == {"gradient", "sao", "pso"}


def test_annealing_schedule_is_table_1():
    temps = annealing.temperature_levels(100.0, 3.0, 0.8)
    assert temps[0] == 100.0 and temps[-1] >= 3.0 > temps[-1] * 0.8
    np.testing.assert_allclose(temps[1:] / temps[:-1], 0.8)
    assert len(temps) == 16
    calls = []
    res = annealing.minimize(lambda x: calls.append(1) or float(np.sum(x**2)), BOUNDS, np.random.default_rng(0))
    assert res.nfev == len(calls) == 1 + 16 * 400
    assert res.nit == 16


def test_particle_swarm_defaults_are_table_1():
    assert particle_swarm.DEFAULTS["swarm_size"] == 100
    assert particle_swarm.DEFAULTS["max_evaluations"] == 10_000
    calls = []
    res = particle_swarm.minimize(lambda x: calls.append(1) or float(np.sum(x**2)), BOUNDS, np.random.default_rng(0))
    assert res.nfev == len(calls) == 10_000
    assert res.nit == 100


@pytest.mark.parametrize("name", ["sao", "pso"])
def test_stochastic_trainer_finds_the_global_minimum_of_a_rippled_bowl(name):
    res = run(name, seed=3, x0=np.array([-1.8, 3.8]))
    np.testing.assert_allclose(res.x, MINIMUM, atol=LOCATION_ATOL[name])
    assert res.fun == pytest.approx(bumpy(res.x))
    assert res.fun < 1e-2


def two_wells(x):
    """Two compactly supported wells, exactly flat elsewhere (like a GP likelihood far from the data).

    Deep well (depth 1, radius 2) at MINIMUM, shallow well (depth 0.5, radius 1) at SHALLOW; they do
    not overlap, so the global minimum is -1 at MINIMUM.
    """
    x = np.asarray(x, dtype=float)
    value, grad = 0.0, np.zeros(2)
    d1 = np.sum((x - MINIMUM) ** 2) / 4
    if d1 < 1:
        value -= (1 - d1) ** 3
        grad += 1.5 * (1 - d1) ** 2 * (x - MINIMUM)
    d2 = np.sum((x - SHALLOW) ** 2)
    if d2 < 1:
        value -= 0.5 * (1 - d2) ** 3
        grad += 3.0 * (1 - d2) ** 2 * (x - SHALLOW)
    return float(value), grad


SHALLOW = np.array([-1.5, 3.5])


@pytest.mark.parametrize("seed", range(5))
def test_gradient_trainer_screens_past_the_plateau_and_the_shallow_well(seed):
    # x0 sits on the flat part, where the gradient vanishes: L-BFGS-B alone would stop there.
    x0 = np.array([3.0, -1.0])
    res = optimizers.get_trainer("gradient")(lambda x: two_wells(x)[0], BOUNDS, np.random.default_rng(seed),
                                             x0=x0, value_and_grad=two_wells)
    np.testing.assert_allclose(res.x, MINIMUM, atol=LOCATION_ATOL["gradient"])
    assert res.fun == pytest.approx(-1.0, abs=1e-10)
    # Without screening, the single run from x0 stops at once on the plateau.
    alone = optimizers.get_trainer("gradient")(lambda x: two_wells(x)[0], BOUNDS, np.random.default_rng(seed),
                                               {"n_screen": 0, "n_starts": 1}, x0=x0, value_and_grad=two_wells)
    assert alone.fun == 0.0


@pytest.mark.parametrize("name", ["gradient", "sao", "pso"])
def test_trainer_never_leaves_the_box_and_reports_true_counts(name):
    seen = []

    def recording(x):
        seen.append(np.array(x, float))
        return bumpy(x)

    def recording_vg(x):
        seen.append(np.array(x, float))
        return bumpy_value_and_grad(x)

    res = optimizers.get_trainer(name)(recording, BOUNDS, np.random.default_rng(1), QUICK[name],
                                       value_and_grad=recording_vg)
    pts = np.array(seen)
    assert np.all(pts >= BOUNDS[:, 0]) and np.all(pts <= BOUNDS[:, 1])
    assert res.nfev == len(seen)


def test_minimum_on_a_bound_is_found_there():
    # Unconstrained minimum at (5, 0.7) lies outside; the constrained one is on the upper x bound.
    shifted = lambda x: float((x[0] - 5.0) ** 2 + (x[1] - 0.7) ** 2)  # noqa: E731
    for name in ("sao", "pso"):
        res = optimizers.get_trainer(name)(shifted, BOUNDS, np.random.default_rng(2), QUICK[name])
        np.testing.assert_allclose(res.x, [3.0, 0.7], atol=LOCATION_ATOL[name])


@pytest.mark.parametrize("name", ["gradient", "sao", "pso"])
def test_trainer_is_reproducible_for_a_fixed_seed_and_uses_its_generator(name):
    a, b, c = run(name, seed=11), run(name, seed=11), run(name, seed=12)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history, b.history)
    assert a.nfev == b.nfev
    assert not np.array_equal(a.history, c.history) or not np.array_equal(a.x, c.x)


def test_non_finite_objective_values_are_rejected_not_accepted():
    # NaN on half of the box: the trainers must return a finite best in the other half.
    fun = lambda x: float("nan") if x[0] < 0.5 else float((x[0] - 1.0) ** 2 + x[1] ** 2)  # noqa: E731
    for name in ("sao", "pso"):
        res = optimizers.get_trainer(name)(fun, BOUNDS, np.random.default_rng(4), QUICK[name])
        assert np.isfinite(res.fun) and res.x[0] >= 0.5


def test_swarm_stall_option_stops_early():
    res = particle_swarm.minimize(lambda x: float(np.sum(x**2)), BOUNDS, np.random.default_rng(5),
                                  {"stall_generations": 10, "function_tolerance": 1e-3})
    assert res.nfev < 10_000 and "stalled" in res.message


def test_unknown_options_are_refused():
    with pytest.raises(ValueError, match="valid options"):
        annealing.minimize(bumpy, BOUNDS, np.random.default_rng(0), {"temperature": 5})
    with pytest.raises(ValueError, match="bounds"):
        particle_swarm.minimize(bumpy, [[1.0, 0.0]], np.random.default_rng(0))
