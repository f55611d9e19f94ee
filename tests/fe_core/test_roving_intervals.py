"""Intervals of multi-reference data (roving hammer, MIMO): the references stacked in one error model.

Independent reference: reciprocity. A roving-hammer test (one accelerometer at s3, the hammer at each
of the six sensor points) measures the column of the receptance matrix that a fixed hammer at s3 with
six accelerometers measures as its row; the FE matrices are symmetric, so the two FRFs agree to the
solver's round-off (checked below). The same amplitudes fitted through the stacked six-reference path
(``channels=``) and through the one-reference model (a hammer at s3, the path the intervals used before)
must give the same estimate and intervals, to the Krylov solvers' 1e-9 agreement propagated through a
Gauss-Newton solve (1e-6 of the interval width). The coverage over 20 noisy data sets is
``python -m benchmarks.roving_coverage`` (docs/guide/measured-data.md).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from benchmarks.roving_coverage import roving_channels, roving_model
from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ as FREQS
from fe_core.inference.intervals import parameter_intervals

LOWER, UPPER = -0.999, 1.0


def test_stacked_references_give_the_reciprocal_single_reference_intervals(benchmark_model):
    rov = roving_model(benchmark_model)
    channels = roving_channels(rov)
    h3 = channels[1][2]  # the hit point at the accelerometer's own point (sensor s3)
    single = dataclasses.replace(rov, load=rov.excitation_loads[:, h3].copy(), excitation_name=rov.excitation_names[h3])
    Z_rov = rov.frf_channels(ALPHA_ACTUAL, FREQS, *channels, method="direct")
    Z_one = single.frf(ALPHA_ACTUAL, FREQS, method="direct")
    np.testing.assert_allclose(Z_rov, Z_one, rtol=1e-10)  # reciprocity: column = row
    rng = np.random.default_rng(30)
    u = np.abs(Z_rov) * (1.0 + 0.01 * rng.standard_normal(Z_rov.shape))
    start = ALPHA_ACTUAL + rng.uniform(-0.03, 0.03, 6)
    stacked = parameter_intervals(rov, FREQS, u, start, LOWER, UPPER, channels=channels, max_jacobians=4)
    reference = parameter_intervals(single, FREQS, u, start, LOWER, UPPER, max_jacobians=4)
    a, b = stacked.intervals, reference.intervals
    width = b.high - b.low
    assert stacked.at_optimum and reference.at_optimum
    np.testing.assert_allclose(a.estimate, b.estimate, rtol=0, atol=1e-6 * width.min())
    np.testing.assert_allclose(a.low, b.low, rtol=0, atol=1e-6 * width.min())
    np.testing.assert_allclose(a.high, b.high, rtol=0, atol=1e-6 * width.min())
    assert abs(a.noise_sigma / b.noise_sigma - 1) < 1e-6
    assert np.all(width < 0.2)  # 1 % noise pins every factor (the data see all six segments)
