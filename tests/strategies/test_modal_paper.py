"""The paper's MRGP loop on measured modes (strategies.modal_paper): on a spring chain with noisy
frequencies and unscaled shapes, the loop (MRGP over the modal residual outputs) narrows from the whole box
to an FE run at the noise, and the local fit from it reaches the optimum the Gauss-Newton path reaches, with
the truth inside its intervals."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from fe_core.modal_update import ModalResidual, fit_modes
from strategies.modal_paper import noise_threshold
from fe_core.solvers.modal import eigenmodes
from strategies.paper import PaperOptions

from tests.fe_core.test_modal_update import _chain


def _data(truth, seed):
    model = _chain()
    alpha, _ = model.factors(truth)
    f, v = eigenmodes(model.stiffness(alpha), model.mass(), 3)
    rng = np.random.default_rng(seed)
    shapes = v.T
    rms = np.sqrt(np.mean(shapes ** 2, axis=1, keepdims=True))
    fn = f * (1 + 0.002 * rng.standard_normal(3))
    sn = (shapes + 0.02 * rms * rng.standard_normal(shapes.shape)) * rng.uniform(0.1, 10, (3, 1))
    return model, fn, sn


def test_noise_threshold_is_the_mean_absolute_value_of_normal_residuals():
    # independent reference: Monte Carlo of mean |N(0,1)| over n = 40 values, its 97.7 % quantile
    rng = np.random.default_rng(0)
    means = np.mean(np.abs(rng.standard_normal((20000, 40))), axis=1)
    assert abs(noise_threshold(40) - np.quantile(means, 0.977)) < 0.01


TRUTH = np.array([0.2, -0.3, 0.1])
LOWER, UPPER = np.full(3, -0.9), np.full(3, 1.0)
OPTIONS = PaperOptions(q=12, s=8, z=8, w=3000, max_iterations=10, max_fe=100)


def _residual(model, fn, sn):
    return ModalResidual(model, sp.identity(6), fn, sn, sigma_f=0.002, sigma_s=0.02, n_model=5)


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    """The loop run once as the flow's stage (tasks.modal_stages.paper_task: every iteration stored)."""
    from tasks.modal_stages import paper_task

    folder = tmp_path_factory.mktemp("paper")
    model, fn, sn = _data(TRUTH, seed=3)
    res = _residual(model, fn, sn)
    info = paper_task.fn(str(folder), res, LOWER, UPPER, OPTIONS)
    return folder, (model, fn, sn), res, info


def test_the_paper_loop_on_modes_reaches_the_truth_within_the_noise(first_run):
    _, (model, fn, sn), res, info = first_run
    assert info["converged"], info["reason"]  # an FE run at the noise, found by the loop itself
    threshold = noise_threshold(res.evaluate(np.asarray(info["best"]), False)["r"].size)
    assert info["threshold"] == threshold
    assert info["per_iteration"][0]["best_error"] > 3 * threshold  # the box's uniform samples were far from it
    assert info["best_error"] <= threshold
    n_loop = res.n_evaluations
    # the local fit from the loop's best FE run: a few FE runs, the same optimum as from the nominal model
    fit = fit_modes(res, LOWER, UPPER, n_starts=1, x0=np.asarray(info["best"]))
    assert res.n_evaluations - n_loop <= 8
    ref = fit_modes(_residual(model, fn, sn), LOWER, UPPER, n_starts=1)
    assert np.all(np.abs(fit.theta - ref.theta) < 0.05 * fit.sd)
    # the truth within the noise: every factor within 3 sd (0.27 % chance per factor to fail by chance)
    assert np.all(np.abs(fit.theta - TRUTH) < 3 * fit.sd), (fit.theta - TRUTH) / fit.sd
    # and the loop's FE runs are logged with their stage
    stages = {h["stage"] for h in res.history}
    assert {f"paper-{k}" for k in range(1, info["iterations"] + 1)} <= stages


def test_the_paper_stages_are_stored_and_a_resume_replays_them_without_an_eigen_solve(first_run):
    from tasks.modal_stages import paper_task
    from tasks.runstore import RunStore

    folder, (model, fn, sn), _, a = first_run
    assert a["fe_runs_computed"] == a["fe_runs"] > 0
    store = RunStore(folder)
    assert all(store.is_finished(1, f"paper-{k}") for k in range(1, a["iterations"] + 1))
    # the loop's steps are stages too (under the one driver), read back on the resume: no MRGP trained again
    steps = [f"paper-{k}-{s}" for k in range(1, a["iterations"]) for s in ("distribution", "train", "predict", "select")]
    assert all(store.is_finished(1, s) for s in steps)
    trained = {s: store.stage_info(1, s)["seconds"] for s in steps if s.endswith("-train")}
    again = _residual(model, fn, sn)
    b = paper_task.fn(str(folder), again, LOWER, UPPER, OPTIONS)
    assert b["fe_runs_computed"] == 0 and b["fe_runs"] == a["fe_runs"]
    assert np.allclose(b["best"], a["best"]) and b["iterations"] == a["iterations"]
    assert all(h["stage"] == "fit" for h in again.history)  # only the nominal pairing: no loop eigen-solve
    assert {s: store.stage_info(1, s)["seconds"] for s in trained} == trained  # the training records unchanged
