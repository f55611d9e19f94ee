"""Candidate damaged patches (``fe_core.closure.effects.bands``): a patch round a node that is not among the coarse
centres is found by the refinement round the best-screened ones.

Data: issue 28's plate with 2 % damage (``data/cases/own_structures``, plate-patch-2%): scikit-fem's own assembly and
direct solve with the cells within 2 rings of top-surface node 143 softened (beta = -0.0917), 0.5 % noise --
not the model that is fitted here. The coarse centres (``patch_centres``, a box grid of mostly mid-plane nodes)
do not hold node 143; alone they place the damage 53 mm away (the closure's answer before the refinement, 8.9 %
of the plate's 0.6 m). The criterion is the issue's: located within 5 % of the structure's size.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fe_core.closure import fits, screening
from fe_core.closure.effects import PatchBands, patch_centres
from fe_core.io import read_model
from flows.config import REPO
from tasks.io.measured import read_measured

TRUTH = json.loads((REPO / "data/cases/own_structures/truth.json").read_text())
CASE = TRUTH["cases"]["plate-patch-2%"]
SIZE = TRUTH["structures"]["plate"]["size_m"]


@pytest.fixture(scope="module")
def plate():
    model = read_model(REPO / CASE["model"])
    measured = read_measured(REPO / CASE["measured"])
    freqs, u = measured.frequencies_hz, measured.amplitude
    alpha = np.asarray(TRUTH["structures"]["plate"]["alpha"], float)
    base = fits.fit_update(model, freqs, u, alpha, max_evaluations=50, tol=1e-6)  # alpha alone, from the truth
    return model, freqs, base


def _best_patch(model, freqs, base, effect):
    best = screening.screen(model, freqs, base, [effect])[0]
    return best, float(np.linalg.norm(effect.position(best.location) - CASE["xyz_m"]))


def test_a_patch_round_a_node_outside_the_coarse_centres_is_found_by_the_refinement(plate):
    model, freqs, base = plate
    coarse = patch_centres(model)
    assert CASE["node"] not in coarse  # the true centre is not a coarse candidate
    fixed, far = _best_patch(model, freqs, base, PatchBands(model, coarse, refinable=False))
    assert far > 0.05 * SIZE  # the coarse centres alone: not located
    refined = PatchBands(model, coarse)
    best, near = _best_patch(model, freqs, base, refined)
    assert len(refined.locations()) > 2 * coarse.size  # refined centres were added ...
    assert int(best.location.split()[1]) not in coarse  # ... and one of them wins
    assert near <= 0.05 * SIZE  # located, as the issue asks
    assert best.linear_explained > fixed.linear_explained
    assert f"node {CASE['node']} r2" in refined.locations()  # the true patch is a candidate now
    # Linearised at zero damage, the size is within 10 % of the truth's (the full fit refines it).
    assert best.linear_values[0] == pytest.approx(CASE["value"], rel=0.10)


def test_a_refined_patch_named_elsewhere_is_made_on_first_use(plate):
    """A check in a worker process builds its own library from the coarse centres: the label of a refined patch
    (from the screen's stored table) must mean the same cells there."""
    model, _, base = plate
    label = CASE["location"]
    fresh = PatchBands(model, patch_centres(model))
    assert label not in fresh.locations()
    K = fresh.terms(base.alpha, label, fresh.check(label, [-0.1])).stiffness
    whole = PatchBands(model, [CASE["node"]], rings=(2,))
    assert abs(K - whole.terms(base.alpha, label, [-0.1]).stiffness).max() == 0.0
    assert np.allclose(fresh.position(label), CASE["xyz_m"])
    assert fresh.maker("node 143 r7") == {} and fresh.maker("point 3") == {}


def test_a_patch_place_is_the_mean_of_its_cells_centroids(plate):
    """``position`` and ``describe`` read only the patch's cells (``Mesh.centroids_of``), the same numbers as
    the whole mesh's centroids indexed, bit for bit."""
    model = plate[0]
    bands = PatchBands(model, patch_centres(model, 12))
    mesh = model.mesh
    for location in bands.locations()[:5]:
        cells = bands.bands[location]
        assert np.array_equal(mesh.centroids_of(cells), mesh.centroids[cells])
        assert np.array_equal(bands.position(location), mesh.centroids[cells].mean(axis=0))
        assert bands.describe(location)["x_min_m"] == float(mesh.centroids[cells][:, 0].min())
