"""tasks.fe_runs.last_jacobian: the intervals start from the local phase's last full-order FE run with its Jacobian
(a large model's, made in the flow's process) only when it was made at exactly that point, for those channels, on
lines that include theirs."""

from __future__ import annotations

import numpy as np

from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ, three_plate
from fe_core.solvers.sensitivity import frf_jacobian
from tasks.fe_runs import evaluate_sample_jacobian, last_jacobian


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
