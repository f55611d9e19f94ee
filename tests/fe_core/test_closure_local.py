"""The local flexibility a reduced space lacks at a candidate's place (:mod:`fe_core.closure.far.local`).

Data and model: the far-off tet4 plate of ``test_closure_far`` (a 6 % point mass, factors far from nominal). The
references are independent of the reduced model: the full FE solve with the effect (``extended_frf``, one sparse
factorisation a line) and the dense inverse of the stiffness.
"""

from __future__ import annotations

import numpy as np
import pytest

from fe_core.closure.effects import Applied, PointMass, extended_frf, extended_matrices
from fe_core.closure.far import ReducedModel, lowrank_factors
from fe_core.closure.far import search as S

from .test_closure_far import ALPHA, far_plate  # noqa: F401  (the fixture)


def test_residual_is_the_static_flexibility_the_space_misses(far_plate):  # noqa: F811
    """``R + W_r diag(1/mu) W_r^T`` is the inverse of K at the node's rows (the dense inverse), and R is positive
    semi-definite: the space holds part of the node's static flexibility, never more."""
    model, freqs, _, node, _ = far_plate
    effect = PointMass(model)
    rows = effect.diagonal([f"node {node}", "node 100"])[1]
    rm = ReducedModel(model, freqs, ALPHA)
    R = rm.local.residual(rows)
    K, _, _, _ = extended_matrices(model, ALPHA)
    inv = np.linalg.inv(K.toarray())
    for k in range(rows.shape[0]):
        Wr = rm.W[rows[k]]
        ref = inv[np.ix_(rows[k], rows[k])]
        assert np.max(np.abs(R[k] + (Wr / rm.mu) @ Wr.T - ref)) < 1e-8 * np.max(np.abs(ref))
        assert np.linalg.eigvalsh(R[k]).min() > -1e-10 * np.abs(ref).max()
        assert np.max(np.diag(R[k]) / np.diag(ref)) > 0.05  # and misses a fair part of it along some axis


@pytest.mark.parametrize("place", ["true", "100", "250"])
def test_a_point_mass_anywhere_is_exact_in_the_space_with_its_static_vectors(far_plate, place):  # noqa: F811
    """At the reduced model's point, a point mass at any node and size: the space with the node's three static
    vectors reproduces the full FE model's ``ln|Z|`` to the truncation of the modes above the band (observed
    2e-5), where the plain space is off by 0.05-1.5; the scan with the residual flexibility added to its Woodbury
    term gives that space's sum of squares to within 1 % (the residual's dynamic part neglected)."""
    model, freqs, u, node, mass = far_plate
    loc = f"node {node}" if place == "true" else f"node {place}"
    effect = PointMass(model)
    rm = ReducedModel(model, freqs, ALPHA)
    rows = effect.diagonal([loc])[1]
    bordered = rm.with_local(rows)
    assert bordered.d == rm.d + 3
    log_u = np.log(u)
    matrix, U = lowrank_factors(rm, effect, [loc])
    for size in (mass, 3 * mass):
        applied = [Applied(effect, loc, np.array([size]))]
        full = np.log(np.abs(extended_frf(model, ALPHA, freqs, applied)))
        plain = rm.evaluate(ALPHA, applied)[0]
        joined = bordered.evaluate(ALPHA, applied)[0]
        assert np.max(np.abs(joined - full)) < 1e-4
        assert np.max(np.abs(plain - full)) > 1e-2
        rss = float(np.sum((joined - log_u) ** 2))
        scanned = rm.scan(ALPHA, U, matrix, np.array([size]), log_u, residual=rm.local.residual(rows))[0, 0]
        assert scanned == pytest.approx(rss, rel=0.01)


def test_the_search_fits_each_low_rank_candidate_in_its_own_space(far_plate):  # noqa: F811
    """``local_space`` joins a point mass's static vectors (LOCAL), leaves a kind that is not low-rank alone, and
    the switch turns it off."""
    model, freqs, _, node, _ = far_plate
    rm = ReducedModel(model, freqs, ALPHA)
    effect = PointMass(model)
    assert S.local_space(rm, effect, f"node {node}").d == rm.d + 3
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(S, "LOCAL", False)
        assert S.local_space(rm, effect, f"node {node}") is rm
    with pytest.raises(ValueError, match="bordered"):
        _ = S.local_space(rm, effect, f"node {node}").local


def test_a_shifted_flexibility_serves_where_k_is_singular(far_plate):  # noqa: F811
    """The path of a free structure (K singular: K + s M solved instead), taken here by asking for a shift: the
    residual is the dense inverse of ``K + s M`` less the space's ``W_r diag(1/(mu + s)) W_r^T``, and the space joined
    by the shifted vectors reproduces the full model nearly as the static ones do (observed 1.8e-4 in ``ln|Z|``
    at twice the mass, a tenth of a per cent: far below any test's noise)."""
    from fe_core.closure.far.local import LocalFlexibility

    model, freqs, _, node, mass = far_plate
    effect = PointMass(model)
    loc = f"node {node}"
    rows = effect.diagonal([loc])[1]
    rm = ReducedModel(model, freqs, ALPHA)
    s = (2 * np.pi * freqs.min()) ** 2
    rm._local = LocalFlexibility(rm, shift=s)
    K, M, _, _ = extended_matrices(model, ALPHA)
    ref = np.linalg.inv((K + s * M).toarray())[np.ix_(rows[0], rows[0])]
    Wr = rm.W[rows[0]]
    R = rm.local.residual(rows)[0]
    assert np.max(np.abs(R + (Wr / (rm.mu + s)) @ Wr.T - ref)) < 1e-8 * np.max(np.abs(ref))
    applied = [Applied(effect, loc, np.array([2 * mass]))]
    full = np.log(np.abs(extended_frf(model, ALPHA, freqs, applied)))
    assert np.max(np.abs(rm.with_local(rows).evaluate(ALPHA, applied)[0] - full)) < 1e-3
