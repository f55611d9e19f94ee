"""Measured channels matched to the model, line selection and the residual of an update."""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.benchmark import ALPHA_ACTUAL
from fe_core.inference.residual import relative_residual
from tasks.io.measured import MeasuredDataError, MeasuredFRF
from tasks.lines import resonance_windows, select_lines
from flows.problem import load_model as _load


def load_model(name):
    return _load(name)[0]
from tasks.update_data import update_data

FREQS = np.array([100.0, 112.0, 200.0, 291.0])
#: The FE core's promise between load layouts and solution paths.
FE_RTOL = 1e-9


@pytest.fixture(scope="module")
def model():
    return load_model("three_plate")


def _measured(model, responses, references, alpha=ALPHA_ACTUAL, signs=None, coherence=None):
    """Noise-free channel data made with the model itself (the matching is under test, not the FE)."""
    resp = [model.sensor_names.index(r) if r in model.sensor_names else int(r.split(":")[0]) - 1 for r in responses]
    refs = [model.excitation_names.index(e or model.excitation_name) if e is None or ":" not in e else 1
            for e in references]
    Z = model.frf_channels(alpha, FREQS, resp, refs)
    if signs is not None:
        Z = Z * np.asarray(signs)
    return MeasuredFRF(FREQS, np.arange(1, len(responses) + 1), np.abs(Z), Z, "m.csv", responses=tuple(responses),
                       references=tuple(references), coherence=coherence,
                       places=tuple(f"line {j + 2}" for j in range(len(responses))))


def test_names_and_test_nodes_match_the_models_channels(model):
    m = _measured(model, ["s1", "2:+z", "s5", "6:-z"], ["hammer", "5:+z", None, "hammer"], signs=[1, 1, 1, -1])
    d = update_data(m, model)
    np.testing.assert_array_equal(d.responses, [0, 1, 4, 5])
    np.testing.assert_array_equal(d.references, [1, 1, 0, 1])
    assert [c["sign"] for c in d.channel_info] == [1, 1, 1, -1]
    # The sign-corrected data equal the model's channels: the residual vanishes at the truth.
    Z = model.frf_channels(ALPHA_ACTUAL, FREQS, *d.channels)
    assert np.max(np.abs(d.residuals(Z))) <= 1e-12
    assert d.residual == "complex" and d.n_values == 2 * FREQS.size * 4


def test_the_models_own_channels_take_the_legacy_path(model):
    m = _measured(model, [f"s{j}" for j in range(1, 7)], [None] * 6)
    d = update_data(m, model, residuals="amplitude")
    assert d.channels is None
    Z = model.frf(ALPHA_ACTUAL, FREQS)
    # Eq. 5 of the model's own FRF (|Z| / u - 1 against (|Z| - u) / u: the same to the last bits of a division).
    np.testing.assert_allclose(d.residuals(Z[None])[0], relative_residual(np.abs(Z), m.amplitude).ravel(),
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(d.channel_errors(d.residuals(Z)),
                                  np.mean(np.abs(d.residuals(Z)).reshape(-1, 6), axis=0))


@pytest.mark.parametrize("responses, references, expected", [
    (["s9"], ["hammer"], ["m.csv: line 2: unknown response 's9'", "'s1', 's2'"]),
    (["s1"], ["shaker"], ["m.csv: line 2: unknown reference 'shaker'", "'combined', 'hammer'"]),
    (["17:+z"], ["hammer"], ["unknown response '17:+z'", "no sensor has test_node = 17", "[1, 2, 3, 4, 5, 6]"]),
    (["3:+x"], ["hammer"], ["response '3:+x': a direction the model cannot measure", "3:+z ('s3')",
                            'test_node = 3 and test_direction = "+x"']),
    (["3:+rz"], ["hammer"], ["response '3:+rz' is a rotation", "cannot measure"]),
    (["s1"], ["2:+z"], ["unknown reference '2:+z'", "no excitation has test_node = 2", "[5]"]),
    (["s1"], ["5:+y"], ["reference '5:+y': a direction the model cannot measure"]),
    (["s3", "3:-z"], ["hammer", "5:+z"], ["line 2 and line 3", "same model sensor and excitation (s3, hammer)"]),
], ids=["unknown sensor name", "unknown excitation name", "unknown test node", "direction not measured",
        "rotation", "unknown reference node", "reference direction", "one channel twice"])
def test_channels_the_model_cannot_give_are_refused(model, responses, references, expected):
    freqs = np.array([10.0, 20.0])
    n = len(responses)
    m = MeasuredFRF(freqs, np.arange(1, n + 1), np.ones((2, n)), None, "m.csv", responses=tuple(responses),
                    references=tuple(references), places=tuple(f"line {j + 2}" for j in range(n)))
    with pytest.raises(MeasuredDataError) as info:
        update_data(m, model)
    for text in expected:
        assert text in str(info.value), str(info.value)


def test_complex_residuals_need_phase(model):
    m = _measured(model, ["s1"], ["hammer"])
    amplitude_only = MeasuredFRF(m.frequencies_hz, m.sensors, m.amplitude, None, "m.csv", responses=m.responses,
                                 references=m.references)
    assert update_data(amplitude_only, model).residual == "amplitude"
    with pytest.raises(ValueError, match="holds amplitudes only"):
        update_data(amplitude_only, model, residuals="complex")


def test_channel_errors_average_each_channels_kept_values(model):
    m = _measured(model, ["s2", "s4"], ["hammer"] * 2)
    d = update_data(m, model)
    r = np.arange(d.n_values, dtype=float)
    # complex layout: real parts of (line, channel) frequency-major, then imaginary parts
    p = FREQS.size
    ch = np.tile([0, 1], p)
    expected = [np.mean(np.r_[r[:2 * p][ch == j], r[2 * p:][ch == j]]) for j in (0, 1)]
    np.testing.assert_allclose(d.channel_errors(r), expected, rtol=1e-15)


def test_the_single_reference_view_gives_the_channels(model):
    m = _measured(model, ["s6", "s2"], ["hammer"] * 2)
    d = update_data(m, model)
    view = d.single_reference_model(model)
    Z = view.frf(ALPHA_ACTUAL, FREQS)
    np.testing.assert_allclose(Z, model.frf_channels(ALPHA_ACTUAL, FREQS, *d.channels), rtol=FE_RTOL)
    mimo = update_data(_measured(model, ["s6", "s2"], ["hammer", None]), model)
    with pytest.raises(ValueError, match="2 references"):
        mimo.single_reference_model(model)


# --- lines ----------------------------------------------------------------------------------------


def test_windows_keep_the_lines_inside_edges_included():
    f = np.arange(1, 21) * 10.0
    sel = select_lines(f, np.ones((20, 2)), mode="windows", windows=[(30.0, 50.0), (195.0, 400.0)])
    np.testing.assert_array_equal(f[sel.lines], [30.0, 40.0, 50.0, 200.0])


@pytest.mark.parametrize("zeta", [0.01, 0.05])
def test_resonance_windows_are_the_half_power_bands_of_a_single_mode(zeta):
    """Against the analytic half-power points of a single mode, r^2 = 1 - 2 z^2 +- 2 z sqrt(1 - z^2)."""
    f0, df = 100.0, 0.01
    f = np.arange(50.0, 150.0, df)
    r = f / f0
    H = 1.0 / (1 - r**2 + 2j * zeta * r)
    lo, hi = f0 * np.sqrt(1 - 2 * zeta**2 + np.array([-2, 2]) * zeta * np.sqrt(1 - zeta**2))
    windows, peaks = resonance_windows(f, np.abs(H)[:, None], widen=1.0)
    assert len(windows) == 1 and peaks[0] == pytest.approx(f0 * np.sqrt(1 - 2 * zeta**2), abs=df)
    np.testing.assert_allclose(windows[0], [lo, hi], atol=df * 0.05)
    (wlo, whi), = resonance_windows(f, np.abs(H)[:, None], widen=2.0)[0]
    assert wlo == pytest.approx(peaks[0] - 2 * (peaks[0] - windows[0][0]))
    assert whi == pytest.approx(peaks[0] + 2 * (windows[0][1] - peaks[0]))


def test_coherence_below_the_threshold_drops_values_and_empty_lines():
    coherence = np.array([[0.95, 0.2], [0.1, 0.3], [1.0, 0.99]])
    sel = select_lines(np.array([1.0, 2.0, 3.0]), np.ones((3, 2)), coherence, min_coherence=0.9)
    np.testing.assert_array_equal(sel.lines, [True, False, True])
    np.testing.assert_array_equal(sel.mask, [[True, False], [True, True]])
    assert sel.coherence_dropped == 3 and sel.lines_dropped == 1
