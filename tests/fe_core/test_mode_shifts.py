"""Per-mode frequency shifts fitted to a residual (fe_core.closure.far.shifts) against analytic shifts.

The data are the benchmark model's own FRFs with every segment 2 % stiffer: every natural frequency is then exactly
sqrt(1.02) times its own (the mode shapes are the same, a sparse eigen-solve confirms it independently of the fit),
and the shifts fitted to the residual of the model as it was must be those.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as sla

from fe_core.benchmark import ALPHA_ACTUAL
from fe_core.closure.effects import extended_frf, extended_matrices
from fe_core.closure.far.reduced import ReducedModel
from fe_core.closure.far.shifts import mode_shifts


def _frequencies(model, alpha, n: int) -> np.ndarray:
    K, M, _, _ = extended_matrices(model, alpha, [])
    lam = sla.eigsh(K.tocsc(), k=n, M=M.tocsc(), sigma=-1.0, which="LM", return_eigenvectors=False)
    return np.sqrt(np.sort(lam)) / (2 * np.pi)


def test_the_shifts_fitted_to_a_uniformly_stiffer_models_residual_are_its_frequency_ratio(benchmark_model):
    freqs = np.arange(20.0, 600.0, 0.5)                           # lines across the band, as a test exports
    alpha = np.asarray(ALPHA_ACTUAL, float)
    stiffer = 1.02 * (1.0 + alpha) - 1.0                          # every modulus 2 % up
    f0, f1 = _frequencies(benchmark_model, alpha, 20), _frequencies(benchmark_model, stiffer, 20)
    assert np.allclose(f1 / f0, np.sqrt(1.02), rtol=1e-9)         # the reference: the model has no unscaled part
    u = np.abs(extended_frf(benchmark_model, stiffer, freqs))
    rm = ReducedModel(benchmark_model, freqs, alpha)
    ms = mode_shifts(rm, alpha, u, sigma=1e-3)
    inside = (f0 >= freqs.min()) & (f0 <= freqs.max())
    assert np.allclose(ms.frequencies_hz, f0[inside], rtol=1e-6) and ms.shifts.size == inside.sum() >= 3
    # the reduced model holds the modes' vectors, which a uniform scaling keeps: exact to the fit's tolerance (the
    # modes above the band share one shift: held, they bent the band's last shift to 3.4 %)
    assert np.allclose(ms.shifts, np.sqrt(1.02) - 1.0, rtol=1e-6)
    assert ms.before > 0.02 and ms.after < 1e-6 and ms.taken > 0.999
    same = mode_shifts(rm, alpha, np.abs(extended_frf(benchmark_model, alpha, freqs)), sigma=1e-3)
    assert same.largest < 1e-6 and same.before == 0.0


def _data(model, applied, freqs, noise, seed=5):
    u = np.abs(extended_frf(model, ALPHA_ACTUAL, freqs, applied))
    return u * np.exp(noise * np.random.default_rng(seed).standard_normal(u.shape))


def test_structure_smaller_than_one_mode_half_a_per_cent_off_is_the_models_own_error_and_called_noise(
        benchmark_model):
    """Data from the model with its stiffness distribution a little off (twelve small patches of cells, each
    softened or stiffened by up to 30 %: the model's own error, its largest frequency shift 0.4 %) at 0.1 % noise.
    The alpha-only fit leaves structure (chi-square), smaller than one mode 0.5 % off would leave; the selection
    fits a patch, which leaves structure: the closure claims nothing and says noise (it said `partly explained`).
    A 0.15 kg point mass (its shifts up to 1.2 %) leaves four times what one mode off would: not the model's own
    error."""
    from fe_core.closure.effects import Applied, PointMass, build_library
    from fe_core.closure.fits import baseline
    from fe_core.closure.far.shifts import own_error
    from fe_core.closure.loop import close_loop

    freqs = np.arange(20.0, 600.0, 1.0)
    patch = {e.kind: e for e in build_library(benchmark_model, ["patch"])}["patch"]
    small = [loc for loc in patch.locations() if loc.endswith("r1")]
    rng = np.random.default_rng(11)
    off = [Applied(patch, small[i], np.array([v])) for i, v in zip(rng.choice(len(small), 12, replace=False),
                                                                   rng.uniform(-0.3, 0.3, 12))]
    u = _data(benchmark_model, off, freqs, 0.001)
    library = build_library(benchmark_model, ["point_mass", "patch"])
    result = close_loop(benchmark_model, freqs, u, np.asarray(ALPHA_ACTUAL), library, noise=0.001)
    assert result.before.structured and result.own_error.within
    assert result.own_error.largest < 0.005 and result.own_error.before < result.own_error.single
    assert result.verdict == "noise" and not result.steps and result.stopped == "the model's own error"
    assert result.final is result.baseline and result.after is result.before   # the model after: alpha only
    mass = _data(benchmark_model, [Applied(PointMass(benchmark_model), "node 201", np.array([0.15]))], freqs, 0.001)
    base, before = baseline(benchmark_model, freqs, mass, ALPHA_ACTUAL, noise=0.001)
    far = own_error(benchmark_model, freqs, mass, base, before.sigma)
    assert before.structured and not far.within and far.before > 3 * far.single and far.largest > 0.005


def test_nothing_is_claimed_only_within_the_models_own_error_and_short_of_the_noise():
    from fe_core.closure.far.shifts import ModeShifts, unclaimed

    within = ModeShifts(np.ones(3), np.zeros(3), before=0.01, after=0.01, single=0.02)
    beyond = ModeShifts(np.ones(3), np.zeros(3), before=0.03, after=0.03, single=0.02)
    assert within.within and not beyond.within
    assert unclaimed(within.within, 0, True) and unclaimed(within.within, 2, True)   # nothing, or short of the noise
    assert not unclaimed(within.within, 1, False)                  # an effect that takes it to the noise stands
    assert not unclaimed(beyond.within, 0, True)
    assert not unclaimed(within.within, 0, True, finished=False)   # stopped by the time limit: not looked enough
