"""Issue 28's own cases (``data/cases/own_structures``, ``python -m benchmarks.make.own_cases``): measured by scikit-fem's own
assembly and direct solve, with an effect the model file does not declare. Our model reads the same structure
from its model file; with the truth's effect added through the closure's library, it must leave the noise and
nothing else (the data differ from our model by the effect only), and the truth file's sizes must be what its
README says (a share of the structure's mass / static stiffness / segment stiffness), computed here from our
model, not from the generator's scikit-fem model.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from fe_core.closure.effects import Applied, ElementBand, GroundedSpring, PointMass, extended_frf, patch_bands
from fe_core.io import read_model
from flows.config import REPO
from tasks.io.measured import read_measured

TRUTH = json.loads((REPO / "data/cases/own_structures/truth.json").read_text())
#: The smallest structure with a node effect and the smallest with a patch (the cantilever has no cells).
CASES = ("cantilever-mount-5%", "plate-patch-2%")


@pytest.fixture(scope="module")
def models():
    return {c: read_model(REPO / TRUTH["cases"][c]["model"]) for c in CASES}


def _effect(model, t):
    if t["effect"] == "point_mass":
        return PointMass(model, [t["node"]])
    if t["effect"].startswith("grounded_spring"):
        return GroundedSpring(model, [t["node"]], component="xyz".index(t["effect"][-1]))
    return ElementBand(model, patch_bands(model, [t["node"]], rings=(2,)), kind="patch")


@pytest.mark.parametrize("case", CASES)
def test_the_data_differ_from_our_model_by_the_effect_only(models, case):
    t = TRUTH["cases"][case]
    model, measured = models[case], read_measured(REPO / t["measured"])
    alpha = TRUTH["structures"][t["structure"]]["alpha"]
    applied = [Applied(_effect(model, t), t["location"], np.array([t["value"]]))]
    freqs, amplitude = measured.frequencies_hz[::2], measured.amplitude[::2]  # every other line: half the solves
    with_effect = extended_frf(model, alpha, freqs, applied, method="direct")
    without = extended_frf(model, alpha, freqs, [], method="direct")
    r = np.log(amplitude / np.abs(with_effect)).ravel()
    r0 = np.log(amplitude / np.abs(without)).ravel()
    noise = TRUTH["noise"]
    # n >= 70 values of 0.5 % noise: the sample deviation is within 1 +- 4/sqrt(2n) (< 0.34) of sigma.
    assert abs(r.std() / noise - 1) < 4 / np.sqrt(2 * r.size) and abs(r.mean()) < 4 * noise / np.sqrt(r.size)
    assert r0.std() > 5 * noise  # the effect is far above the noise: a case for the closure, not the noise


@pytest.mark.parametrize("case", CASES)
def test_the_truths_sizes_are_the_shares_the_readme_names(models, case):
    t = TRUTH["cases"][case]
    model = models[case]
    alpha = TRUTH["structures"][t["structure"]]["alpha"]
    if t["effect"] == "point_mass":
        assert t["value"] == pytest.approx(t["share"] * model.total_mass(), rel=1e-9)
    elif t["effect"].startswith("grounded_spring"):
        row = GroundedSpring(model, [t["node"]], component="xyz".index(t["effect"][-1])).diagonal([t["location"]])[1]
        unit = np.zeros(model.n_dofs)
        unit[row[0, 0]] = 1.0
        compliance = spla.spsolve(model.stiffness(alpha).tocsc(), unit)[row[0, 0]]
        assert t["value"] == pytest.approx(t["share"] / compliance, rel=1e-6)
    else:
        band = patch_bands(model, [t["node"]], rings=(2,))[t["location"]]
        a, b, c, d = (model.mesh.nodes[model.mesh.cells[:, m]] for m in range(4))
        volume = np.abs(np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)) / 6.0  # tet4
        segment = max((model.mesh.cell_sets[n] for n in model.segment_names),
                      key=lambda cells: np.intersect1d(cells, band).size)
        assert t["value"] == pytest.approx(-t["share"] * volume[segment].sum() / volume[band].sum(), rel=1e-9)
        assert np.allclose(model.mesh.centroids[band].mean(axis=0), t["xyz_m"])
    if model.mesh is not None and t["effect"] != "patch":
        assert np.allclose(model.mesh.nodes[t["node"]], t["xyz_m"])
