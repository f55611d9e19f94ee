"""The one residual (fe_core/inference/frf_data.py): Eqs. 5, 6b and 15 written out by hand, the complex residual,
the log residual on the complete lines, and the Jacobian against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.inference.frf_data import FRFData


def test_residual_layout_and_errors_follow_eqs_5_6b_15(rng):
    p, n = 4, 3
    measured = rng.uniform(1.0, 2.0, (p, n))
    model = measured * (1 + rng.normal(0, 0.1, (p, n)))
    data = FRFData.grid(np.arange(1.0, p + 1), measured)
    res = data.residuals(model)
    # Eq. 5: [du_11 .. du_n1, du_12, ..., du_np] -- sensors fastest.
    expected = [(model[j, i] - measured[j, i]) / measured[j, i] for j in range(p) for i in range(n)]
    np.testing.assert_allclose(res, expected, rtol=1e-14)
    overall = sum(abs(model[j, i] - measured[j, i]) / measured[j, i] for i in range(n) for j in range(p)) / (n * p)
    assert data.error(data.kept(model)) == pytest.approx(overall, rel=1e-14)
    sensor = [np.mean([abs(model[j, i] / measured[j, i] - 1) for j in range(p)]) for i in range(n)]
    np.testing.assert_allclose(data.channel_errors(res), sensor, rtol=1e-14)


def test_residuals_broadcast_over_many_samples(rng):
    measured = rng.uniform(1.0, 2.0, (5, 2))
    models = measured * (1 + rng.normal(0, 0.1, (7, 5, 2)))
    data = FRFData.grid(np.arange(5.0), measured)
    res = data.residuals(models)
    assert res.shape == (7, 10)
    np.testing.assert_array_equal(res[3], data.residuals(models[3]))
    assert data.channel_errors(res).shape == (7, 2)


def test_a_value_left_out_is_not_in_any_residual_and_its_line_is_not_complete(rng):
    measured = rng.uniform(1.0, 2.0, (4, 2))
    mask = np.ones((4, 2), bool)
    mask[1, 0] = False
    data = FRFData(np.arange(4.0), measured, None, mask)
    model = measured * 1.1
    model[1, 0] = 1e9  # would dominate every residual if it entered
    assert data.n_values == 7 and data.residuals(model).shape == (7,)
    assert data.error(data.kept(model)) == pytest.approx(0.1, rel=1e-12)
    assert list(data.complete_lines) == [True, False, True, True]
    freqs, u = data.complete()
    np.testing.assert_array_equal(freqs, [0.0, 2.0, 3.0])
    assert data.log_rss(data.kept(model)) == pytest.approx(6 * np.log(1.1) ** 2, rel=1e-12)
    assert np.isnan(data.log_grid(data.kept(model))[1, 0])


def test_the_complex_residual_is_real_then_imaginary_parts_over_the_measured_modulus(rng):
    H = rng.normal(size=(3, 2)) + 1j * rng.normal(size=(3, 2))
    Z = H + 0.01 * (rng.normal(size=(3, 2)) + 1j * rng.normal(size=(3, 2)))
    data = FRFData.grid(np.arange(3.0), np.abs(H), H)
    r = data.residuals(Z)
    d = ((Z - H) / np.abs(H)).ravel()
    np.testing.assert_allclose(r, np.concatenate([d.real, d.imag]), rtol=1e-13, atol=1e-16)
    assert data.n_values == 12 and data.channel_errors(r).shape == (2,)


@pytest.mark.parametrize("kind", ["amplitude", "complex"])
def test_the_residual_jacobian_matches_finite_differences(rng, kind):
    """A model z(theta) = A exp(B theta) (complex, k values, m parameters): the chain rule of the residual."""
    k, m = 6, 2
    A = rng.normal(size=k) + 1j * rng.normal(size=k)
    B = 0.3 * (rng.normal(size=(k, m)) + 1j * rng.normal(size=(k, m)))

    def z(theta):
        return A * np.exp(B @ theta)

    theta = rng.normal(size=m)
    H = z(theta) * (1 + 0.05 * rng.normal(size=k))
    data = FRFData.grid(np.arange(float(k)), np.abs(H), H if kind == "complex" else None, residual=kind)
    J = data.jacobian(z(theta), (B * z(theta)[:, None]))
    h = 1e-6
    fd = np.column_stack([(data(z(theta + h * e)) - data(z(theta - h * e))) / (2 * h) for e in np.eye(m)])
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-9)


def test_complex_residuals_need_the_phase():
    with pytest.raises(ValueError, match="phase"):
        FRFData(np.arange(2.0), np.ones((2, 1)), None, np.ones((2, 1), bool), "complex")
