"""MAC, pairing, frequency differences and COMAC against hand and analytic cases."""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.correlation import comac, frequency_differences, mac_matrix, modal_scale_factor, pair_modes


def test_mac_hand_values():
    # [1, 0] against [1, 1]: (1)^2 / (1 * 2) = 0.5; scale and sign do not matter.
    assert mac_matrix([1.0, 0.0], [1.0, 1.0])[0, 0] == pytest.approx(0.5, abs=1e-15)
    assert mac_matrix([1.0, 2.0, 3.0], [-7.0, -14.0, -21.0])[0, 0] == pytest.approx(1.0, abs=1e-15)
    assert mac_matrix([1.0, 0.0], [0.0, 5.0])[0, 0] == 0.0
    # complex shape with one phase everywhere is a real shape: MAC 1 with its real part
    assert mac_matrix(np.exp(0.7j) * np.array([1.0, -2.0]), [1.0, -2.0])[0, 0] == pytest.approx(1.0, abs=1e-14)


def test_mac_of_string_modes_at_equally_spaced_points_is_the_identity():
    # sin(k pi j / (N + 1)), j = 1..N, are exactly orthogonal for k != l (discrete sine transform).
    n = 12
    j = np.arange(1, n + 1)
    shapes = np.array([np.sin(k * np.pi * j / (n + 1)) for k in range(1, 7)])
    np.testing.assert_allclose(mac_matrix(shapes, shapes), np.eye(6), atol=1e-14)
    # a shape sampled with a scale error still pairs: MAC of sin(pi x) and sin(pi x)(1 + x) is analytic
    x = np.linspace(0, 1, 2001)[1:-1]
    a, b = np.sin(np.pi * x), np.sin(np.pi * x) * (1 + x)
    # integrals: int s^2 = 1/2, int x s^2 = 1/4, int x^2 s^2 = 1/6 - 1/(4 pi^2), so int s^2 (1+x) = 3/4 and
    # int s^2 (1+x)^2 = 1/2 + 2/4 + (1/6 - 1/(4 pi^2)); the Riemann sum on 2001 points is exact to ~1e-6
    i2 = 1.0 / 6.0 - 1.0 / (4 * np.pi ** 2)
    expected = 0.75 ** 2 / (0.5 * (1.0 + i2))
    assert mac_matrix(a, b)[0, 0] == pytest.approx(expected, rel=1e-5)


def test_modal_scale_factor_recovers_the_scale():
    b = np.array([[1.0, -2.0, 0.5]])
    assert modal_scale_factor(-3.5 * b, b)[0] == pytest.approx(-3.5, rel=1e-15)


def test_pairing_swapped_modes_and_assignment_rather_than_greedy():
    mac = np.array([[0.1, 0.97, 0.0], [0.96, 0.05, 0.0], [0.0, 0.0, 0.99]])
    p = pair_modes(mac, 0.8)
    assert p.test.tolist() == [0, 1, 2] and p.model.tolist() == [1, 0, 2]
    # greedy best-per-row would give model mode 1 to both test modes; the assignment gives 0->2, 1->1
    mac = np.array([[0.90, 0.85], [0.95, 0.10]])
    p = pair_modes(mac, 0.8)
    assert p.model.tolist() == [1, 0]
    np.testing.assert_allclose(p.mac, [0.85, 0.95])


def test_unpaired_modes_are_named_with_their_best_candidate():
    mac = np.array([[0.99, 0.0], [0.3, 0.55]])
    p = pair_modes(mac, 0.8, test_names=["T1", "T2"], model_names=["M1", "M2"])
    assert p.test.tolist() == [0] and p.unpaired_test == [1] and p.unpaired_model == [1]
    assert "T2: unpaired" in p.messages[0] and "M2" in p.messages[0] and "0.55" in p.messages[0]


def test_frequency_differences():
    mac = np.array([[0.0, 0.9], [0.9, 0.0]])
    p = pair_modes(mac, 0.8)
    np.testing.assert_allclose(frequency_differences([100.0, 200.0], [210.0, 101.0], p), [0.01, 0.05])


def test_comac_hand_case_and_a_local_error():
    # hand case: b2 = [1,1] scaled onto a1 = [1,0] by MSF 1/2; DOF 2: (0*0.5 + 1*1)^2 / (1 * (0.25 + 1)) = 0.8
    a = np.array([[1.0, 0.0], [0.0, 1.0]])
    b = np.array([[1.0, 1.0], [0.0, 1.0]])
    np.testing.assert_allclose(comac(a, b), [1.0, 0.8], atol=1e-15)
    # shapes equal up to scale and sign except at one DOF: that DOF has the lowest COMAC, the others 1
    rng = np.random.default_rng(0)
    a = rng.normal(size=(4, 10))
    b = -2.0 * a
    b[:, 6] += rng.normal(size=4)
    c = comac(a, b)
    assert np.argmin(c) == 6 and c[6] < 0.99
    assert np.all(c[np.arange(10) != 6] > 0.97)
    np.testing.assert_allclose(comac(a, -2.0 * a), np.ones(10), atol=1e-14)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="non-finite"):
        mac_matrix([1.0, np.nan], [1.0, 0.0])
    with pytest.raises(ValueError, match="different DOFs"):
        mac_matrix([1.0, 0.0], [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="zero at every DOF"):
        mac_matrix([0.0, 0.0], [1.0, 0.0])
