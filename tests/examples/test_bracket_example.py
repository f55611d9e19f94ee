"""Example (a), the tet10 L-bracket (data/examples/bracket/), on its coarse mesh (model_coarse.toml).

The stored ``measured.csv`` comes from the fine mesh (105,114 DOFs, too expensive here), so it
is never recomputed: the tests check that the model files describe what the example's script
says, that sensors and the hammer land where the file puts them, and that a few least-squares
steps on the coarse model move it toward the truth in ``truth.json``.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fe_core.assembly import DOFS_PER_NODE
from fe_core.io import read_model
from fe_core.inference.residual import relative_residual
from strategies.polish import polish
from tasks.io.measured import read_measured

FOLDER = Path(__file__).resolve().parents[2] / "data" / "examples" / "bracket"
SEGMENTS = ["foot_inner", "foot_outer", "web_lower", "web_upper", "rib_left", "rib_right"]


@pytest.fixture(scope="module")
def coarse():
    return read_model(FOLDER / "model_coarse.toml")


def _spec(name: str) -> dict:
    return tomllib.loads((FOLDER / name).read_text())


def test_the_coarse_and_default_model_files_differ_only_in_the_mesh(coarse):
    default, small = _spec("model.toml"), _spec("model_coarse.toml")
    assert (default["mesh"], small["mesh"]) == ("bracket.msh", "bracket_coarse.msh")
    for key in ("mesh", "point_tolerance"):
        default.pop(key), small.pop(key)
    assert default == small
    assert coarse.segment_names == SEGMENTS
    assert coarse.parameter_bounds.tolist() == [[-0.5, 0.5]] * 6
    assert coarse.total_mass() == pytest.approx(2.027e-4 * 7850.0, rel=1e-3)  # CAD volume x steel
    truth = json.loads((FOLDER / "truth.json").read_text())
    assert truth["segments"] == SEGMENTS
    measured = read_measured(FOLDER / "measured.csv")
    assert measured.amplitude.shape == (len(truth["frequencies_hz"]), coarse.n_sensors)
    np.testing.assert_allclose(measured.frequencies_hz, truth["frequencies_hz"])


def _placed(model, vector: np.ndarray) -> tuple[int, np.ndarray]:
    """(node, unit direction) that a sensor's output vector or the load reads/pushes."""
    rows = np.flatnonzero(vector)
    dofs = model.free_dofs[rows]
    nodes = np.unique(dofs // DOFS_PER_NODE)
    assert nodes.size == 1
    direction = np.zeros(3)
    direction[dofs % DOFS_PER_NODE] = vector[rows]
    return int(nodes[0]), direction


def test_sensors_and_hammer_land_within_tolerance_along_their_directions(coarse):
    spec = _spec("model_coarse.toml")
    tol = spec["point_tolerance"]
    nodes = coarse.mesh.nodes
    L = coarse.outputs.toarray()
    entries = [(s, L[:, j]) for j, s in enumerate(spec["sensors"])] + [(spec["excitations"][0], coarse.load)]
    axes = set()
    for entry, vector in entries:
        node, direction = _placed(coarse, vector)
        distance = np.linalg.norm(nodes[node] - entry["point"])
        assert distance <= tol
        # The nearest node: no other node is closer to the point.
        assert distance <= np.linalg.norm(nodes - entry["point"], axis=1).min() + 1e-12
        d = entry["direction"]
        want = np.eye(3)["xyz".index(d)] if isinstance(d, str) else np.asarray(d) / np.linalg.norm(d)
        np.testing.assert_allclose(direction, want, atol=1e-12)
        axes.add(int(np.argmax(np.abs(want))))
    assert axes == {0, 1, 2}  # the bracket's modes move it along x, y and z


@pytest.mark.slow
def test_a_few_least_squares_steps_move_the_coarse_model_toward_the_truth(coarse):
    """The four plate segments from alpha = 0 (ribs left at 0), one Jacobian and a few steps (11 FE runs).

    The coarse mesh's natural frequencies are 1-2 % above the fine mesh's (truth.json lists the
    default mesh's 0.2-0.6 %), which the fit turns into alpha errors of several hundredths, and
    the ribs' factors (truth 0.2, -0.1) are not fitted; so the test asks for a halved error and
    a third less parameter error, not the truth (the flow's result on the default mesh is in
    the example's README).
    """
    measured = read_measured(FOLDER / "measured.csv")
    truth = np.array(json.loads((FOLDER / "truth.json").read_text())["alpha"])[:4]

    def evaluate(points):
        return [relative_residual(np.abs(coarse.frf(np.r_[x, 0.0, 0.0], measured.frequencies_hz)),
                                  measured.amplitude).ravel() for x in points]

    result = polish(evaluate, np.zeros(4), np.full(4, -0.5), np.full(4, 0.5), max_evaluations=11, stall_window=0)
    assert result.error < 0.5 * result.error_start  # measured: 21.2 % -> 9.7 %
    assert np.linalg.norm(result.x - truth) < 0.75 * np.linalg.norm(truth)  # measured: 0.255 -> 0.147
