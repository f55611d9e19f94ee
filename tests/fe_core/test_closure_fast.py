"""The closure's fits on the growing reduced model (fe_core.closure.fast, issue 28) against the plain fits.

Data: scikit-fem's FRF of the cantilever carrying a 0.6 kg point mass at node 208
(``data/examples/cantilever_matrices/measured_point_mass.csv``, an independent model). References: the
plain path's full Krylov evaluations and fits (``fe_core.closure.fits.fit_update``).
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from fe_core.closure import fast, fast_basis, fits, screening, selection
from fe_core.closure.effects import Applied, LinearisedResponse, PointMass
from fe_core.io import read_model
from flows.config import REPO
from tasks.io.measured import read_measured

DATA = REPO / "data/examples/cantilever_matrices"


@pytest.fixture(scope="module")
def beam():
    truth = json.loads((DATA / "truth.json").read_text())
    m = read_measured(DATA / "measured_point_mass.csv")
    return read_model(DATA / "model.toml"), m.frequencies_hz, m.amplitude, truth


def test_the_reduced_model_is_the_full_one_at_its_basis_point(beam):
    """With the full Krylov space of a point in the basis, the reduced receptance and its exact derivatives
    (alpha and the effect) are the full ones there. Both are Galerkin projections on the same space through
    different orthonormal bases: they differ by the reduced eigenproblems' round-off (2e-9 here), within the
    1e-8 the FRF solvers are held to against the direct solve (docs/results/performance.md)."""
    model, freqs, u, truth = beam
    mass = PointMass(model)
    alpha = np.asarray(truth["alpha"]) + 0.02
    applied = [Applied(mass, "node 208", np.array([0.3]))]
    full = LinearisedResponse(model, alpha, freqs, applied)
    basis = fast.ReducedBasis(model, freqs)
    basis.add(full.reduced.W)
    red = fast_basis._ReducedLinearised(basis, model, alpha, freqs, applied)
    assert np.max(np.abs(red.Z - full.Z)) < 1e-8 * np.max(np.abs(full.Z))
    Jf = np.column_stack([full.alpha_derivatives(), full.effect_derivatives(mass, "node 208")])
    Jr = np.column_stack([red.alpha_derivatives(), red.effect_derivatives(mass, "node 208")])
    # d ln|Z| divides by |Z|: near an antiresonance an entry is large; 1e-7 of the largest column entry
    assert np.max(np.abs(Jr - Jf)) < 1e-7 * np.max(np.abs(Jf))


def test_the_reduced_fit_ends_where_the_plain_fit_ends_with_fewer_fe_evaluations(beam):
    model, freqs, u, truth = beam
    mass = PointMass(model)
    start = np.asarray(truth["alpha"]) + 0.05  # the alpha-only update's factors absorb the mass: start off
    plain = fast._PLAIN_FIT(model, freqs, u, start, mass, "node 208", [0.1], tol=1e-8)
    quick = fast.fit_update(model, freqs, u, start, mass, "node 208", [0.1], tol=1e-8)
    # The same optimum to the optimiser's tolerance (ftol = xtol = 1e-8 on a well-posed 7-parameter fit).
    assert quick.rss == pytest.approx(plain.rss, rel=1e-6)
    assert np.max(np.abs(quick.alpha - plain.alpha)) < 1e-4
    assert quick.values[0] == pytest.approx(plain.values[0], rel=1e-4)
    # The fit's residual is the full model's at its end point.
    full = LinearisedResponse(model, quick.alpha, freqs, quick.applied)
    assert np.allclose(quick.residual, np.log(full.amplitude / u), rtol=0, atol=1e-9)
    assert quick.evaluations < plain.evaluations
    assert "reduced model" in quick.message


def test_a_coarse_fit_on_the_basis_ends_with_the_full_residual(beam):
    """A restart (coarse tolerance) starts on the basis an earlier fit left, without its own start's space,
    and ends where the reduced and the full sum of squares agree to its tolerance; its residual is the full
    model's at its end point, and the restarts' best, refined, is the plain path's optimum."""
    model, freqs, u, truth = beam
    start = np.asarray(truth["alpha"]) + 0.05
    with fast.enabled():
        fast.fit_update(model, freqs, u, start, tol=1e-8)  # the basis
        built = fast._BUILT[0]
        coarse = fast.fit_update(model, freqs, u, start - 0.1, tol=1e-4)
        assert fast._BUILT[0] - built == coarse.evaluations
        full = LinearisedResponse(model, coarse.alpha, freqs)
        assert np.allclose(coarse.residual, np.log(full.amplitude / u), rtol=0, atol=1e-9)
        best = fits.multistart_update(model, freqs, u, start, n_starts=2)
    plain = fast._PLAIN_FIT(model, freqs, u, start, tol=1e-8)
    assert best.rss == pytest.approx(plain.rss, rel=1e-6)
    assert np.max(np.abs(best.alpha - plain.alpha)) < 1e-4


def test_enabled_and_disabled_switch_the_closure_fits_and_restore_them():
    default = fits.fit_update  # the fast path unless MRGP_CLOSURE_FAST=0
    assert default is (fast.fit_update if fast.by_default() else fast._PLAIN_FIT)
    assert fast.by_default() == (os.environ.get("MRGP_CLOSURE_FAST") != "0")
    with fast.disabled():
        assert fits.fit_update is fast._PLAIN_FIT and screening.fit_update is fast._PLAIN_FIT
        assert screening.LinearisedResponse is LinearisedResponse
        with fast.enabled():
            assert fits.fit_update is fast.fit_update
            assert screening.fit_update is fast.fit_update and selection.fit_update is fast.fit_update
            assert screening.LinearisedResponse is fast.full_response
        assert fits.fit_update is fast._PLAIN_FIT and selection.fit_update is fast._PLAIN_FIT
    assert fits.fit_update is default and screening.fit_update is default and selection.fit_update is default


def test_a_segment_mass_at_another_factor_is_projected_from_the_held_projection(beam):
    """A change of many rows (a segment's mass) is projected once per basis and scaled after; the scaled one
    is the direct projection ``V^T A V`` (dense products: independent of the row-wise one), and a change of
    the same pattern that is not a multiple is projected afresh."""
    from fe_core.closure.effects import SegmentMass

    model, freqs, u, truth = beam
    basis = fast.ReducedBasis(model, freqs)
    basis.add(LinearisedResponse(model, np.asarray(truth["alpha"]), freqs).reduced.W)
    effect = SegmentMass(model)
    location = effect.locations()[-1]
    first = effect.terms(np.zeros(model.n_segments), location, [0.2]).mass
    assert np.count_nonzero(np.diff(first.tocsr().indptr)) > fast_basis.REMEMBER_ROWS
    V = basis.V
    zero = first.copy()
    zero.data[:] = 0.0  # stored zeros (a derivative that vanishes) first: projected, not remembered
    for A in (zero, first, effect.terms(np.zeros(model.n_segments), location, [-0.7]).mass, first.multiply(first)):
        direct = V.T @ (A.toarray() @ V)
        assert np.max(np.abs(basis.project(A) - direct)) <= 1e-12 * np.max(np.abs(direct))


def test_a_check_relocation_screen_at_a_fine_fit_end_builds_no_new_space(beam):
    """A check's relocation screen is linearised at its fit's end after the joint fit's coarse starts have
    built full spaces of their own: the full response at the last fine fits' ends is kept, so the screen
    costs no FE evaluation, and it is that point's (its receptance is the fit's model)."""
    model, freqs, u, truth = beam
    mass = PointMass(model)
    start = np.asarray(truth["alpha"]) + 0.05
    with fast.enabled():
        fine = fast.fit_update(model, freqs, u, start, mass, "node 208", [0.1], tol=1e-6)
        built = fast._BUILT[0]
        for shift in (-0.1, 0.1, 0.2):  # coarse starts elsewhere: their full spaces pass through the cache
            fast.fit_update(model, freqs, u, start + shift, mass, "node 208", [0.3], tol=1e-4)
        assert fast._BUILT[0] - built >= fast._FULL_SIZE
        built = fast._BUILT[0]
        lin = screening.LinearisedResponse(model, fine.alpha, freqs, fine.applied)
        assert fast._BUILT[0] == built
        assert np.allclose(np.log(lin.amplitude / u), fine.residual, rtol=0, atol=1e-9)
