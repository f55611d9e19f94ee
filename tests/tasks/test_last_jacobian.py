"""The intervals of a large model start from its best full-order FE run: tasks.jacobian_memo.last_jacobian serves one of
the flow's process's last full-order FE runs with their Jacobians only when it was made at exactly that point, for
those channels, on lines that include theirs; tasks.record.best_run picks a full-order run over the rounds a reduced
basis served (approximate)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ, three_plate
from fe_core.solvers.sensitivity import frf_jacobian
from tasks.fe_runs import evaluate_sample_jacobian
from tasks.jacobian_memo import KEPT_JACOBIANS, last_jacobian
from tasks.record import best_run


class _Ref:
    def __init__(self, model):
        self.model = model

    def load(self):
        return self.model


def test_the_last_full_order_jacobian_is_served_only_at_its_point_channels_and_lines():
    model = three_plate.__wrapped__()  # a model of its own: the memo lives on it
    freqs = np.asarray(MEASUREMENT_FREQUENCIES_HZ, float)
    theta = np.array([-0.3, -0.1, -0.2, -0.1, -0.1, -0.2])
    evaluate_sample_jacobian(_Ref(model), 7, theta, freqs)  # a worker's run: nothing kept
    assert last_jacobian(model, theta, freqs) is None
    frame = evaluate_sample_jacobian(_Ref(model), 7, theta, freqs, keep_factor=True)  # the flow's own run
    assert (frame["status"] == "ok").all()
    Z, dZ = frf_jacobian(model, theta, freqs)  # an independent call: the same Krylov computation
    some = freqs[[2, 5, 11]]
    Zk, dZk = last_jacobian(model, theta, some)
    np.testing.assert_allclose(Zk, Z[[2, 5, 11]], rtol=1e-10)
    np.testing.assert_allclose(dZk, dZ[[2, 5, 11]], rtol=1e-9, atol=1e-12 * np.abs(dZ).max())
    assert last_jacobian(model, theta + 1e-12, some) is None  # another point
    assert last_jacobian(model, theta, some, channels=(np.array([0, 1]), np.array([0, 0]))) is None  # other channels
    assert last_jacobian(model, theta, np.append(some, freqs[-1] + 1.0)) is None  # a line it was not run on


def test_the_last_few_full_order_runs_are_kept():
    model = three_plate.__wrapped__()
    freqs = np.asarray(MEASUREMENT_FREQUENCIES_HZ, float)[:4]
    points = [np.full(6, -0.01 * (k + 1)) for k in range(KEPT_JACOBIANS + 1)]
    for k, x in enumerate(points):
        evaluate_sample_jacobian(_Ref(model), k, x, freqs, keep_factor=True)
    assert last_jacobian(model, points[0], freqs) is None  # the oldest dropped
    assert all(last_jacobian(model, x, freqs) is not None for x in points[1:])


def test_the_best_run_is_a_full_order_one_when_there_is_one():
    runs = pd.DataFrame({"sample_id": [0, 1, 2, 3], "status": ["ok"] * 4,
                         "overall_error": [0.9, 0.0056, 0.005601, 0.0056005],
                         "reduced": [False, True, False, np.nan]})  # NaN: a stage without served rounds
    assert int(best_run(runs)["sample_id"]) == 3
    assert int(best_run(runs.iloc[:2])["sample_id"]) == 0
    assert int(best_run(runs.assign(reduced=True))["sample_id"]) == 1  # only served rounds: the best of them
    assert int(best_run(runs.drop(columns="reduced"))["sample_id"]) == 1  # a small model's record
