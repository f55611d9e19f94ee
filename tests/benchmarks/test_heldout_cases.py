"""The held-out cases' generator (``benchmarks.make.cases``) on a tiny structure (a cantilever of 30 hexahedra): deterministic
from its seed, its modal FRF equal to a direct complex solve, and the effect the truth names really in the data."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

pytest.importorskip("skfem")
pytest.importorskip("pypardiso")

from benchmarks.make.cases import build, case, effects, fem_data, solids  # noqa: E402


def _spec(kind, seed=11, set_="t"):
    return {"id": f"tiny-{kind}", "structure": "tiny_bar", "kind": kind, "seed": seed, "expected": "x", "set": set_}


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    import shutil

    root = tmp_path_factory.mktemp("held_out")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(fem_data, "CACHE", root / "cache")     # not the repository's runs/
        info = build.structure_info("tiny_bar", root)
        first = build.make_case(_spec("point_mass"), root)
        other = tmp_path_factory.mktemp("again")
        shutil.copytree(root / "structures", other / "structures")
        again = build.make_case(_spec("point_mass"), other)
        yield root, info, first, (other, again)


def test_the_same_seed_gives_the_same_files(made):
    root, info, first, (other, again) = made
    assert first["measured_sha256"] == again["measured_sha256"]
    assert (root / "t" / "tiny-point_mass" / "measured.csv").read_bytes() == \
        (other / "t" / "tiny-point_mass" / "measured.csv").read_bytes()
    other = build.make_case({**_spec("point_mass", seed=12), "id": "tiny-seed-12"}, root)
    assert other["measured_sha256"] != first["measured_sha256"]


def test_truth_says_what_was_drawn(made):
    _, info, truth, _ = made
    e = truth["effect"]
    assert 0.02 <= e["share_of_mass"] <= 0.08
    assert e["value"] == pytest.approx(e["share_of_mass"] * truth["structure_mass_kg"], rel=1e-12)
    # the structure's mass from its geometry: 0.3 x 0.01 x 0.01 m of steel
    assert truth["structure_mass_kg"] == pytest.approx(7850 * 0.3 * 0.01 * 0.01, rel=1e-10)
    assert all(-0.3 <= a <= 0.3 for a in truth["factors"])
    # the place: a surface node of the tool's mesh away from the clamp, where the data carry the mass
    nodes = solids.tiny_bar()["mesh"]()[0]
    assert np.allclose(nodes[e["node"]], e["xyz_m"]) and e["xyz_m"][0] >= case.CLEAR * 0.3
    n = truth["lines"]["count"]
    assert n == round(truth["lines"]["top_hz"] / truth["lines"]["step_hz"]) + 1
    assert truth["natural_frequencies_hz"][truth["lines"]["modes_in_band"] - 1] < truth["lines"]["top_hz"] \
        < truth["natural_frequencies_hz"][truth["lines"]["modes_in_band"]]


@functools.lru_cache(maxsize=1)
def _data_model():
    """The tiny bar's data model, assembled once for the tests that build systems from it (a few seconds each)."""
    s = solids.structure("tiny_bar")
    return s, fem_data.data_model(s, cache=False)


def _system(alpha, extra_M=None):
    s, d = _data_model()
    K, M = fem_data.assembled(d, alpha, None, extra_M)
    Kc, Mc = fem_data.condensed(K, M, d["free"])
    return s, d, Kc, Mc, d["outputs"][:, d["free"]], d["load"][d["free"]]


def test_modal_frf_equals_a_direct_complex_solve(made):
    _, info, truth, _ = made
    s, d, Kc, Mc, out, load = _system(np.asarray(truth["factors"]))
    a, b = info["damping"]
    top = truth["lines"]["top_hz"]
    spec = fem_data.spectral(Kc, Mc, out, load, fem_data.MODES_UP_TO * top)
    lines = np.array([0.37 * top, truth["natural_frequencies_hz"][2], top])
    H = fem_data.modal_frf(spec, (a, b), lines)
    for f, h in zip(lines, H):
        w = 2 * np.pi * f
        A = sp.csc_matrix(Kc - w**2 * Mc + 1j * w * (a * Mc + b * Kc))
        direct = out @ spla.spsolve(A, load.astype(complex))          # SuperLU, not PARDISO's real 2n system
        # the modes left out (above twice the top) enter to O((f / f_cut)^8) of their small part
        assert np.max(np.abs(h - direct)) <= 1e-6 * np.max(np.abs(direct))
    # the generator's own check of its lines (the solution put back into the equations)
    assert truth["check_equilibrium_residual"]["largest_relative"] < 1e-5   # 2.4 without the modes left out


def test_the_effect_is_in_the_data(made):
    """The measured FRF is the structure with the mass: against the same structure without it, the lines with
    a good coherence differ by far more than the noise; with it, by the noise."""
    root, info, truth, _ = made
    import pandas as pd

    table = pd.read_csv(root / "t" / "tiny-point_mass" / "measured.csv", comment="#")
    names = [n for n, _, _ in solids.tiny_bar()["sensors"]]
    f = np.sort(table["frequency_hz"].unique())[1:]
    Z = np.stack([table[table.response == n].sort_values("frequency_hz")[["real", "imag"]].to_numpy()[1:] @ [1, 1j]
                  for n in names], axis=1)
    good = np.stack([table[table.response == n].sort_values("frequency_hz")["coherence"].to_numpy()[1:]
                     for n in names], axis=1) >= 0.9
    alpha = np.asarray(truth["factors"])
    e = truth["effect"]
    s, d, Kc, Mc, out, load = _system(alpha)
    top = fem_data.MODES_UP_TO * truth["lines"]["top_hz"]
    without = fem_data.modal_frf(fem_data.spectral(Kc, Mc, out, load, top), info["damping"], f)
    v = int(np.argmin(np.linalg.norm(s["data_nodes"] - e["xyz_m"], axis=1)))
    s, d, Kc, Mc, out, load = _system(alpha, effects.point_mass(d, v, e["value"]))
    with_ = fem_data.modal_frf(fem_data.spectral(Kc, Mc, out, load, top), info["damping"], f)
    acc = -((2 * np.pi * f[:, None]) ** 2)
    r_with = np.log(np.abs(Z / (acc * with_)))[good]
    r_without = np.log(np.abs(Z / (acc * without)))[good]
    sigma = truth["noise"]["response_relative"]
    assert np.sqrt(np.mean(r_with**2)) < 3 * sigma
    assert np.sqrt(np.mean(r_without**2)) > 5 * np.sqrt(np.mean(r_with**2))
    assert max(abs(x) for x in truth["effect_frequency_shift_percent"]) > 0.5


def test_clean_and_outside_cases_of_the_tiny_bar(made):
    root, *_ = made
    clean = build.make_case(_spec("none"), root)
    assert clean["effect"] == {"kind": "none"} and clean["effect_rms_log_amplitude_change"] == 0.0
    layer = build.make_case(_spec("mass_layer"), root)
    assert layer["effect"]["value"] == pytest.approx(layer["effect"]["share_of_mass"] * layer["structure_mass_kg"])
    assert layer["effect"]["segments"] == ["root", "tip"] and layer["effect_rms_log_amplitude_change"] > 0.01
    assert json.loads((root / "t" / "tiny-none" / "truth.json").read_text())["expected"] == "x"


def test_the_data_at_the_tools_points_are_the_data_at_its_nodes_where_the_meshes_share_them(made):
    """``benchmarks.heldout_points`` evaluates the data at the points of the tool's sensor and hammer nodes. On the
    tiny bar (Q2 on the tool's own hexahedra: every tool node is a data vertex) those rows are the generator's own
    nodal rows; inside a cell the interpolation reproduces a linear field (u = (x, 2 y - z, 3 z)) exactly."""
    from benchmarks.heldout_points import tool_points
    from benchmarks.make.cases.fem_data import point_row
    from fe_core.io import read_model

    root, _, _, _ = made
    s, d = _data_model()
    model = read_model(root / "structures" / "tiny_bar" / "model.toml")
    sensors, hammer = tool_points(model)
    rows = np.array([point_row(d["basis"], p, dirn) for p, (_, _, dirn) in zip(sensors, s["sensors"])])
    np.testing.assert_allclose(rows, d["outputs"], atol=1e-12)
    np.testing.assert_allclose(point_row(d["basis"], hammer, s["excitation"][2]), d["load"], atol=1e-12)
    u = d["basis"].project(lambda x: np.array([x[0], 2 * x[1] - x[2], 3 * x[2]]))   # exact: linear is in Q2
    p = np.array([0.1234, 0.0037, 0.0061])
    for direction, value in (((1, 0, 0), p[0]), ((0, 1, 0), 2 * p[1] - p[2]), ((0, 0, 1), 3 * p[2])):
        assert point_row(d["basis"], p, direction) @ u == pytest.approx(value, rel=1e-12)


def test_the_second_held_out_set_takes_the_data_at_the_tools_node_points():
    """``points = "model"`` (the set heldout2): each sensor's row and the load are the data basis's shape functions
    at the point of the tool's node nearest the structure's point. With the tool's nodes moved off the data's
    vertices (shrunk by 0.9 about the bar's centre: all inside it) a linear field is read there exactly; the set's
    cases carry the flag, the other sets the nearest vertex."""
    from benchmarks.make.cases import sets

    s, _ = _data_model()
    centre = np.array([0.15, 0.005, 0.005])
    moved = centre + 0.9 * (s["model_nodes"] - centre)
    d = fem_data.data_model({**s, "model_nodes": moved, "points": "model"}, cache=False)
    u = d["basis"].project(lambda x: np.array([x[0], 2 * x[1] - x[2], 3 * x[2]]))

    def field(p, direction):
        v = np.array([p[0], 2 * p[1] - p[2], 3 * p[2]])
        return float(np.asarray(direction, float) / np.linalg.norm(direction) @ v)
    for row, (_, point, direction) in zip(d["outputs"], s["sensors"]):
        at = moved[np.argmin(np.linalg.norm(moved - np.asarray(point), axis=1))]
        assert row @ u == pytest.approx(field(at, direction), rel=1e-12, abs=1e-15)
    point, direction = s["excitation"][1:]
    at = moved[np.argmin(np.linalg.norm(moved - np.asarray(point), axis=1))]
    assert d["load"] @ u == pytest.approx(field(at, direction), rel=1e-12)
    assert {c["points"] for s in ("heldout2", "heldout3", "heldout4") for c in sets.cases(s)} == {"model"}
    assert {c["points"] for c in sets.cases("heldout") + sets.cases("dev")} == {"vertex"}
    seeds = [{c["seed"] for c in sets.cases(s)} for s in sets.SETS]
    assert sum(map(len, seeds)) == len(set().union(*seeds))  # no seed in two sets


def test_data_on_the_tools_tetrahedra_are_the_tools_model_assembled_elsewhere(tmp_path, monkeypatch):
    """The fifth held-out set's solids (``data_mesh = "model"``): scikit-fem's P2 on the tool's tet10 cells is the
    tool's own discretisation, assembled by another program. On a straight-edged block both integrate exactly
    (stiffness of degree 2, mass of degree 4), so their natural frequencies agree to the eigensolvers' precision,
    while the data of the mesh of half the size differ from the tool by its mesh's own error; a point mass drawn
    for such a case sits at a tool node, on which the data carry it."""
    from fe_core.io import read_model

    monkeypatch.setattr(fem_data, "CACHE", tmp_path / "cache")
    info = build.structure_info("tiny_block", tmp_path)
    model = read_model(tmp_path / "structures" / "tiny_block" / "model.toml")
    alpha = np.array([0.1, -0.2])
    s = solids.on_model_mesh(solids.structure("tiny_block"))
    d = fem_data.data_model(s, cache=False)
    K, M = fem_data.assembled(d, alpha)
    f_data = fem_data.modes(*fem_data.condensed(K, M, d["free"]), 1.0, start=6)[0][:6]
    f_tool = model.natural_frequencies(alpha, 6)
    np.testing.assert_allclose(f_tool, f_data, rtol=1e-8)
    assert np.max(np.abs(info["model_minus_data_percent"][:6])) > 0.05   # the finer data mesh: the tool's own error
    truth = build.make_case({**_spec("point_mass"), "structure": "tiny_block", "data_mesh": "model"}, tmp_path)
    e = truth["effect"]
    assert truth["data_mesh"] == "model"
    np.testing.assert_array_equal(e["xyz_m"], e["model_node_xyz_m"])


@pytest.mark.parametrize("which, seed, order", [("heldout5", "HELDOUT5_SEED", "HELDOUT5_ORDER"),
                                                 ("heldout6", "HELDOUT6_SEED", "HELDOUT6_ORDER"),
                                                 ("heldout7", "HELDOUT7_SEED", "HELDOUT7_ORDER"),
                                                 ("heldout8", "HELDOUT8_SEED", "HELDOUT8_ORDER"),
                                                 ("heldout9", "HELDOUT9_SEED", "HELDOUT9_ORDER"),
                                                 ("heldout10", "HELDOUT10_SEED", "HELDOUT10_ORDER"),
                                                 ("heldout11", "HELDOUT11_SEED", "HELDOUT11_ORDER"),
                                                 ("heldout12", "HELDOUT12_SEED", "HELDOUT12_ORDER")])
def test_the_later_sets_orders_are_their_seeds_permutations_of_every_case(which, seed, order):
    from benchmarks.make.cases import sets

    ids = [c["id"] for c in sets.cases(which)]
    permutation = np.random.default_rng(getattr(sets, seed)).permutation(len(ids))
    assert list(getattr(sets, order)) == [ids[i] for i in permutation]
    assert {c["data_mesh"] for c in sets.cases(which)} == {"fine" if which in ("heldout11", "heldout12") else "model"}
    assert {c["data_mesh"] for c in sets.cases("heldout4")} == {"fine"}
