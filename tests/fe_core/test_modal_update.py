"""Modal updating core: Nelson's derivatives against finite differences, the scale-free shape residual
(its squared norm is 1 - MAC), mode tracking through a crossing, identifiability, Laplace intervals."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from fe_core.assembly import SegmentedMatrix
from fe_core.benchmark import ALPHA_ACTUAL, three_plate
from fe_core.correlation import mac_matrix
from fe_core.model import ParametricModel
from fe_core.modal_update import ModalResidual, eigen_derivatives, fit_modes, identifiability
from fe_core.modal_update.nelson import parameter_matrices
from fe_core.solvers.modal import eigenmodes


def test_nelson_matches_central_differences_on_the_benchmark():
    model = three_plate()
    K, M = model.stiffness(ALPHA_ACTUAL), model.mass()
    f, v = eigenmodes(K, M, 4)
    dlam, dphi = eigen_derivatives(K, M, (2 * np.pi * f) ** 2, v, parameter_matrices(model))
    h = 1e-5  # central differences: truncation ~ h^2 * (third derivative), well below 1e-6 relative here
    for i in (0, 3):
        e = np.zeros(6)
        e[i] = h
        fp, vp = eigenmodes(model.stiffness(ALPHA_ACTUAL + e), M, 4)
        fm, vm = eigenmodes(model.stiffness(ALPHA_ACTUAL - e), M, 4)
        vp, vm = vp * np.sign(np.sum(vp * v, 0)), vm * np.sign(np.sum(vm * v, 0))
        fd_lam = ((2 * np.pi * fp) ** 2 - (2 * np.pi * fm) ** 2) / (2 * h)
        np.testing.assert_allclose(dlam[:, i], fd_lam, rtol=1e-5, atol=1e-6 * np.abs(fd_lam).max())
        for r in range(4):
            fd = (vp[:, r] - vm[:, r]) / (2 * h)
            assert np.linalg.norm(dphi[r, :, i] - fd) <= 1e-4 * np.linalg.norm(fd)
    # the derivative keeps the mass normalisation: d(phi^T M phi) = 2 phi^T M dphi = 0
    own = np.einsum("nr,nr->r", v, M @ dphi[:, :, 0].T)
    np.testing.assert_allclose(own, 0.0, atol=1e-10 * np.abs(dphi[:, :, 0]).max())


def _oscillators(k=(1.0, 2.0, 4.0), outputs=None):
    """Three uncoupled unit masses: modes are the unit vectors, f_i = sqrt(k_i (1 + alpha_i)) / 2 pi."""
    parts = [sp.csr_matrix(([k[i]], ([i], [i])), shape=(3, 3)) for i in range(3)]
    mass = [sp.csr_matrix(([1.0], ([i], [i])), shape=(3, 3)) for i in range(3)]
    return ParametricModel(mesh=None, free_dofs=np.arange(3), stiffness_segments=SegmentedMatrix.from_matrices(parts),
                           mass_segments=SegmentedMatrix.from_matrices(mass), segment_names=["a", "b", "c"],
                           damping=(0.0, 0.0), outputs=sp.identity(3, format="csr") if outputs is None else outputs,
                           n_total_dofs=3)


def test_shape_residual_is_scale_free_and_its_squared_norm_is_one_minus_mac():
    model = _oscillators()
    shapes = np.array([[1.0, 0.2, 0.0], [0.1, -1.0, 0.05]])
    f = np.sqrt([1.0, 2.0]) / (2 * np.pi)
    r1 = ModalResidual(model, sp.identity(3), f, shapes, sigma_f=0.01, sigma_s=1.0, n_model=2)
    r2 = ModalResidual(model, sp.identity(3), f, shapes * np.array([[-7.0], [0.01]]), sigma_f=0.01, sigma_s=1.0,
                       n_model=2)
    a, b = r1.evaluate(np.zeros(3)), r2.evaluate(np.zeros(3))
    np.testing.assert_allclose(a["r"], b["r"], atol=1e-12)
    sigma_u = 1.0 / np.sqrt(3)
    mac = mac_matrix(shapes, np.eye(3)[:2])
    shape_part = a["r"][1:4] * sigma_u
    assert shape_part @ shape_part == pytest.approx(1 - mac[0, 0], rel=1e-12)
    # at the exact model the frequency residuals are zero
    np.testing.assert_allclose(a["r"][[0, 4]], 0.0, atol=1e-9)


def test_jacobian_of_the_residual_matches_finite_differences():
    model = _oscillators()
    shapes = np.array([[1.0, 0.2, -0.1], [0.1, -1.0, 0.05]])
    res = ModalResidual(model, sp.identity(3), [0.17, 0.23], shapes, sigma_f=0.01, sigma_s=0.05, n_model=2)
    theta = np.array([0.1, -0.2, 0.3])
    J = res.evaluate(theta)["J"]
    h = 1e-6
    fd = np.column_stack([(res.evaluate(theta + h * e, False)["r"] - res.evaluate(theta - h * e, False)["r"]) / (2 * h)
                          for e in np.eye(3)])
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())


def test_mode_tracking_through_a_crossing_and_the_fit_beyond_it():
    # measured: mode of DOF 0 at sqrt(1 * 2.5) and of DOF 1 at sqrt(2): DOF 0's mode is now the *second*
    model = _oscillators()
    truth = np.array([1.5, 0.0, 0.0])
    f = np.sqrt([1.0 * 2.5, 2.0]) / (2 * np.pi)
    res = ModalResidual(model, sp.identity(3), f, np.eye(3)[:2], sigma_f=0.001, sigma_s=0.01, n_model=2)
    pairing = res.set_active(np.zeros(3))
    assert pairing.model.tolist() == [0, 1]
    assert res.evaluate(truth)["pairing"].model.tolist() == [1, 0]  # paired by shape, not by order
    assert res.swaps and "model mode 1 -> 2" in res.swaps[0]
    # mode 3 (DOF 2) is not measured: its factor is not identifiable; fit the two others
    fit = fit_modes(res, np.array([-0.5, -0.5, -0.5]), np.array([2.0, 2.0, 2.0]), n_starts=1)
    np.testing.assert_allclose(fit.theta[:2], truth[:2], atol=1e-6)


def test_identifiability_names_what_the_frequencies_cannot_fix():
    # two paired frequencies, three parameters; the third column carries nothing
    S = np.array([[1.0, 0.2, 0.0], [0.1, 1.0, 0.0]])
    assert identifiability(S, ["alpha_1", "alpha_2", "alpha_3"]) == ["alpha_3"]
    assert identifiability(np.eye(3), ["a", "b", "c"]) == []


def _chain(n=6, groups=((0, 1), (2, 3), (4, 5))):
    """A fixed-free chain of n unit masses and unit springs; spring k joins mass k-1 (ground for k = 0) and k;
    the springs are grouped into segments."""
    parts = []
    for group in groups:
        K = sp.lil_matrix((n, n))
        for k in group:
            if k == 0:
                K[0, 0] += 1.0
            else:
                K[k - 1, k - 1] += 1.0
                K[k, k] += 1.0
                K[k - 1, k] -= 1.0
                K[k, k - 1] -= 1.0
        parts.append(K.tocsr())
    mass = [sp.identity(n, format="csr")] + [sp.csr_matrix((n, n))] * (len(groups) - 1)
    return ParametricModel(mesh=None, free_dofs=np.arange(n), stiffness_segments=SegmentedMatrix.from_matrices(parts),
                           mass_segments=SegmentedMatrix.from_matrices(mass), segment_names=["a", "b", "c"],
                           damping=(0.0, 0.0), outputs=sp.identity(n, format="csr"), n_total_dofs=n)


def test_laplace_intervals_cover_at_their_rate_with_frequencies_and_unscaled_shapes():
    # Monte Carlo on a chain: 3 measured modes at 6 DOFs, 0.2 % frequency noise and 2 % shape noise (of the RMS),
    # each set's shapes scaled and signed at random (OMA); 200 sets: coverage of each factor 0.95 +- 0.015
    # (binomial), accepted within 0.90-0.99. This checks the shape weights sigma_u = sigma_s / sqrt(n_dofs) too.
    model = _chain()
    truth = np.array([0.2, -0.3, 0.1])
    alpha, _ = model.factors(truth)
    f, v = eigenmodes(model.stiffness(alpha), model.mass(), 3)
    shapes = v.T
    rng = np.random.default_rng(5)
    inside, z = [], []
    for _ in range(200):
        fn = f * (1 + 0.002 * rng.standard_normal(3))
        rms = np.sqrt(np.mean(shapes ** 2, axis=1, keepdims=True))
        sn = (shapes + 0.02 * rms * rng.standard_normal(shapes.shape)) * rng.choice([-1, 1], (3, 1)) \
            * rng.uniform(0.1, 10, (3, 1))
        res = ModalResidual(model, sp.identity(6), fn, sn, sigma_f=0.002, sigma_s=0.02, n_model=5)
        fit = fit_modes(res, np.full(3, -0.9), np.full(3, 1.0), n_starts=1)
        inside.append((fit.lower95 <= truth) & (truth <= fit.upper95))
        z.append((fit.theta - truth) / fit.sd)
    coverage = np.mean(inside, axis=0)
    assert np.all((coverage > 0.90) & (coverage < 0.99)), coverage
    # and the standardised errors have unit spread (sd of 200 N(0,1) values: 1 +- 0.05)
    assert np.all(np.abs(np.std(z, axis=0) - 1) < 0.15), np.std(z, axis=0)
