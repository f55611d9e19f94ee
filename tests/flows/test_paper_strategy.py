"""The paper's loop under the one driver: the stored run's stages and the same strategy in memory (the registry's
entry on an in-memory memo, run by ``run_loop``) make the same samples from the same FE results (the residual
emulation of the paper, and the modal emulation)."""

from __future__ import annotations

import numpy as np
import pytest

from flows import update
from flows.rerun import run_problem
from strategies import registry
from strategies.base import InMemory, Outcome, run_loop
from tasks.context import context
from tasks.record import history as run_history


#: How far the two drivers' samples may lie apart. The residual emulation selects among discrete candidate draws:
#: the same draws, the same choice. The modal emulation adds Gauss-Newton end points on the emulator's mean, run to
#: 1e-14: the emulator's hyper-parameters come from an optimiser whose result moves by an ulp between two calls on
#: the same data (numpy's summation order follows memory alignment), and a flat valley of the mean turns that into
#: up to 2.4e-5 in an end point (measured on this case), far below any step the loop takes.
SAME_SAMPLES = {"errors": 1e-12, "modes": 1e-4}


@pytest.mark.parametrize("emulate", ["errors", "modes"])
def test_the_loop_in_memory_makes_the_flows_samples(emulate, reduced_config, prefect_harness):
    config = reduced_config.replace(emulate=emulate, polish=False, max_iterations=3, max_fe_evaluations=16,
                                    run_id=f"paper-{emulate}")
    summary = update.update_flow(config)
    problem = run_problem(config)
    line, channel = problem.data.cells

    def evaluate(batch):
        out = []
        for x in batch.points:
            Z = problem.model.parameter_frf(x, problem.freqs_hz, problem.channels)
            modes = problem.model.modal_terms(x, problem.modes, problem.channels) if batch.modes else None
            out.append(Outcome(Z[line, channel], modes=modes))
        return out

    memo = InMemory()
    loop = registry.get(config.strategy).make(context(problem, memo), config)
    decision = run_loop(loop, evaluate)
    flow = run_history(config.resolve(config.runs_dir) / config.run_id)
    assert [k for k, _, _ in loop.history] == list(range(1, summary["iterations"] + 1))
    assert sorted(memo.steps) == [(k, s) for k in range(1, summary["iterations"])
                                  for s in ("distribution", "predict", "select", "train")]
    X = np.vstack([points for _, points, _ in loop.history])
    assert len(X) == len(flow) == summary["fe_evaluations"] == 16
    np.testing.assert_allclose(X, np.array([h["x"] for h in flow]), rtol=0, atol=SAME_SAMPLES[emulate])
    x, error = loop.best()
    assert error == pytest.approx(summary["overall_error"], rel=1e-3) and decision.stop
    assert loop.report().stop_reason == summary["stop_reason"]
