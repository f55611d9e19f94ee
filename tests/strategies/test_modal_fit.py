"""The modal Gauss-Newton fit as an ask-tell strategy (strategies.modal_fit, a callback optimiser in a thread,
strategies.callback): in memory it gives exactly the direct call's fit (fe_core.modal_update.fit_modes: the same
end point, starts, intervals, eigen-solves and Jacobians); under the driver its evaluations are stages of the
run folder and a resume reads them back without an eigen-solve; the worker thread ends however the loop does."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from fe_core.modal_update import fit_modes
from strategies.base import Batch, Outcome, run_loop
from strategies.callback import CallbackStrategy
from strategies.modal_fit import ModalFitStrategy, residual_evaluations

from tests.strategies.test_modal_paper import LOWER, TRUTH, UPPER, _data, _residual

STARTS, SEED = 3, 1


@pytest.fixture(scope="module")
def chain():
    """A spring chain's three modes with 0.2 % frequency and 2 % shape noise, unscaled shapes."""
    return _data(TRUTH, seed=3)


def test_the_strategy_in_memory_gives_exactly_the_direct_fit(chain):
    ref_res, res = _residual(*chain), _residual(*chain)
    calls, direct = [], ref_res.evaluate
    ref_res.evaluate = lambda x, jacobian=True: calls.append(jacobian) or direct(x, jacobian)
    ref = fit_modes(ref_res, LOWER, UPPER, n_starts=STARTS, seed=SEED)
    strategy = ModalFitStrategy(LOWER, UPPER, STARTS, SEED)
    decision = run_loop(strategy, residual_evaluations(res))
    fit = strategy.result
    assert decision.stop and decision.converged
    # the same procedure, the same residual evaluations: equal to the last bit, not just close
    assert np.array_equal(fit.theta, ref.theta) and fit.cost == ref.cost and fit.starts == ref.starts
    for name in ("sd", "lower95", "upper95", "covariance"):
        assert np.array_equal(getattr(fit, name), getattr(ref, name)), name
    assert (res.n_evaluations, res.n_jacobians) == (ref.n_fe_runs, ref.n_jacobians)
    assert [h["theta"] for h in res.history] == [h["theta"] for h in ref_res.history]  # the same eigen-solves
    # one ask per call the direct fit makes of the residual (scipy's fun and jac, the end point's Jacobian; not
    # fit_modes' last call, which takes the end point's pairing from the residual's cache)
    assert strategy.asked == len(calls) - 1 > res.n_evaluations
    assert not strategy._thread.is_alive()
    # and a fit worth the name: the three starts reach one optimum, the truth within 3 sd of it
    assert np.ptp([s["end"] for s in fit.starts], axis=0).max() < 1e-6
    assert np.all(np.abs(fit.theta - TRUTH) < 3 * fit.sd)


def test_an_exception_in_the_evaluation_ends_the_worker_thread(chain):
    res = _residual(*chain)
    evaluate = residual_evaluations(res)
    calls = []

    def failing(batch):
        calls.append(batch)
        if len(calls) == 3:
            raise RuntimeError("the eigen-solver failed")
        return evaluate(batch)

    strategy = ModalFitStrategy(LOWER, UPPER, STARTS, SEED)
    before = threading.active_count()
    with pytest.raises(RuntimeError, match="eigen-solver failed"):
        run_loop(strategy, failing)
    strategy._thread.join(timeout=10)  # run_loop closed it already: no wait here
    assert not strategy._thread.is_alive() and threading.active_count() <= before
    assert strategy.stop().stop and not strategy.stop().converged


def test_an_exception_in_the_optimiser_is_raised_in_the_callers_thread(chain):
    res = _residual(*chain)
    evaluate = residual_evaluations(res)

    def non_finite(batch):  # scipy refuses a residual that is not finite at its start
        return [Outcome(np.full_like(o.Z, np.nan), o.dZ) for o in evaluate(batch)]

    strategy = ModalFitStrategy(LOWER, UPPER, 1)
    with pytest.raises(ValueError, match="not finite"):
        run_loop(strategy, non_finite)
    assert not strategy._thread.is_alive()
    with pytest.raises(ValueError, match="not finite"):  # and again, not a hang, when asked once more
        strategy.stop()


def test_a_body_closed_while_it_waits_stops_and_its_thread_ends():
    seen = []

    def body(ask):
        try:
            while True:
                seen.append(ask(Batch(np.zeros((1, 1)), (False,)))[0])
        except Exception:  # an optimiser's own handler does not swallow the stop
            seen.append("swallowed")
            raise

    strategy = CallbackStrategy(body, "endless")
    for k in range(3):
        assert not strategy.stop().stop
        batch = strategy.propose()
        strategy.update(batch, [k])
    strategy.close()
    assert not strategy._thread.is_alive() and seen == [0, 1, 2]
    decision = strategy.stop()
    assert decision.stop and not decision.converged and "closed" in decision.reason
    with pytest.raises(RuntimeError, match="after it stopped"):
        strategy.propose()


def test_the_stored_fit_resumes_by_replay_without_an_eigen_solve(chain, tmp_path, monkeypatch):
    from tasks.modal_fit import fit_stage
    from tasks.modal_stages import fit_task
    from tasks.runstore import RunStore

    root = str(tmp_path / "run")
    first_res = _residual(*chain)
    first = fit_task.fn(root, first_res, LOWER, UPPER, STARTS, SEED, True)
    ref = fit_modes(_residual(*chain), LOWER, UPPER, n_starts=STARTS, seed=SEED)
    assert np.array_equal(first["theta"], ref.theta.tolist()) and first["starts"] == ref.starts
    assert (first["fe_runs"], first["jacobians"]) == (ref.n_fe_runs, ref.n_jacobians)
    store = RunStore(root)
    stages = [fit_stage(k) for k in range(1, STARTS + 1)]
    assert all(store.is_finished(1, s) for s in stages)
    assert first["evaluations_computed"] == sum(store.stage_info(1, s)["evaluations"] for s in stages)
    assert sum(store.stage_info(1, s)["fe_runs"] for s in stages) + 1 == ref.n_fe_runs  # + the nominal pairing
    assert {h["stage"] for h in first_res.history} == {"fit", *stages}  # fit: the nominal pairing

    def no_fe_run(*args, **kwargs):
        raise AssertionError("an FE run (eigen-solve) on resume")

    import fe_core.modal_update.residual as residual_module

    # interrupted after the evaluations were stored, before the fit's record: replayed, no eigen-solve
    (store.stage_dir(1, "fit") / "_stage.json").unlink()
    with monkeypatch.context() as patch:
        patch.setattr(residual_module, "eigenmodes", no_fe_run)
        again = fit_task.fn(root, _residual(*chain), LOWER, UPPER, STARTS, SEED, True)
    assert again["evaluations_computed"] == 0
    for key in ("theta", "sd", "covariance", "starts", "fe_runs", "jacobians", "pairing", "unpaired", "swaps",
                "active", "chi2"):
        assert again[key] == first[key], key
    # interrupted inside the last start: the first two read back, the last computed again, the same result
    (store.stage_dir(1, "fit") / "_stage.json").unlink()
    (store.stage_dir(1, stages[-1]) / "_stage.json").unlink()
    res = _residual(*chain)
    partly = fit_task.fn(root, res, LOWER, UPPER, STARTS, SEED, True)
    last = store.stage_info(1, stages[-1])
    assert {h["stage"] for h in res.history} == {stages[-1]} and len(res.history) == last["fe_runs"] > 0
    assert partly["evaluations_computed"] == last["ran_now"] == last["evaluations"]
    for key in ("theta", "sd", "starts", "fe_runs", "jacobians", "pairing"):
        assert partly[key] == first[key], key
