"""The effect library: matrices against independent constructions, validation, registry, sensitivities."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from fe_core.closure import effects as E
from fe_core.assembly import DOFS_PER_NODE
from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ

FREQS = MEASUREMENT_FREQUENCIES_HZ[[0, 3, 9]]  # a resonance-side, the peak and the upper band


@pytest.fixture(scope="module")
def library(benchmark_model):
    return {e.kind: e for e in E.build_library(benchmark_model)}


def rigid(model, component: int) -> np.ndarray:
    """Unit rigid translation along ``component`` on the free DOFs."""
    full = np.zeros(model.mesh.n_nodes * DOFS_PER_NODE)
    full[component::DOFS_PER_NODE] = 1.0
    return full[model.free_dofs]


def test_builtin_effects_are_registered_with_their_candidates(library, benchmark_model):
    assert list(library) == ["segment_mass", "point_mass", "grounded_spring", "joint_band", "damping",
                             "grounded_spring_x", "grounded_spring_y", "sensor_mass", "sensor_gain", "patch"]
    top_free = benchmark_model.mesh.node_sets["top"]
    # 615 top nodes, 30 of them on the clamped faces.
    assert top_free.size == 615 and len(library["point_mass"].locations()) == 585
    assert library["joint_band"].locations() == ["joint x=230 mm", "joint x=396 mm"]
    assert library["segment_mass"].locations() == [f"segment{i}" for i in range(1, 7)]
    assert library["damping"].locations() == ["a", "b"]


def test_point_mass_adds_its_mass_to_every_rigid_translation(library, benchmark_model):
    t = library["point_mass"].terms(ALPHA_ACTUAL, "node 337", np.array([0.25]))
    for c in range(3):
        v = rigid(benchmark_model, c)
        assert v @ (t.mass @ v) == pytest.approx(0.25, rel=1e-14)
    assert t.mass.nnz == 3 and t.stiffness is None


def test_grounded_spring_acts_on_u_z_of_its_node_only(library, benchmark_model):
    t = library["grounded_spring"].terms(ALPHA_ACTUAL, "node 633", np.array([4e5]))
    assert t.stiffness.nnz == 1
    (row,), (col,) = t.stiffness.nonzero()
    assert row == col and benchmark_model.free_dofs[row] == 3 * 633 + 2
    assert t.stiffness[row, row] == 4e5


def test_segment_mass_matches_the_models_own_mass_factors(library, benchmark_model):
    t = library["segment_mass"].terms(ALPHA_ACTUAL, "segment5", np.array([0.3]))
    gamma = np.array([0, 0, 0, 0, 0.3, 0])
    diff = benchmark_model.mass(gamma) - benchmark_model.mass() - t.mass
    assert abs(diff).max() <= 1e-15 * abs(benchmark_model.mass()).max()


def test_an_element_band_over_a_whole_segment_is_that_segments_stiffness(benchmark_model):
    cells = benchmark_model.mesh.cell_sets["segment3"]
    band = E.ElementBand(benchmark_model, {"all of segment 3": cells})
    t = band.terms(ALPHA_ACTUAL, "all of segment 3", np.array([1.0]))
    expected = (1 + ALPHA_ACTUAL[2]) * benchmark_model.stiffness_segments.segment(2)
    assert abs(t.stiffness - expected).max() <= 1e-9 * abs(expected).max()


def test_joint_bands_are_the_cells_touching_each_joint_plane(library, benchmark_model):
    band = library["joint_band"]
    for label, x in (("joint x=230 mm", 0.230), ("joint x=396 mm", 0.396)):
        cells = band.bands[label]
        # One column of the wide plate (14 cells across) and one of the narrow plate (6).
        assert cells.size == 14 + 6
        xs = benchmark_model.mesh.cell_coords[cells][:, :, 0]
        assert np.all(np.any(np.isclose(xs, x, atol=1e-9), axis=1))


def test_joint_band_terms_scale_with_the_segment_factors(library):
    band = library["joint_band"]
    a0 = band.terms(np.zeros(6), "joint x=230 mm", np.array([-0.5])).stiffness
    a1 = band.terms(ALPHA_ACTUAL, "joint x=230 mm", np.array([-0.5])).stiffness
    # The band straddles segments 2 and 3 (alpha -0.1 and -0.3): the ratio lies between 0.7 and 0.9.
    ratio = abs(a1).sum() / abs(a0).sum()
    assert 0.7 < ratio < 0.9


@pytest.mark.parametrize(
    ("kind", "location", "value", "message"),
    [
        ("joint_band", "joint x=230 mm", -1.0, "beta = -1.0"),
        ("segment_mass", "segment2", -1.5, "gamma = -1.5"),
        ("point_mass", "node 337", -0.1, "mass = -0.1"),
        ("grounded_spring", "node 337", np.nan, "k = nan"),
        ("damping", "b", -2e-4, "would be negative"),
        ("point_mass", "node 0", 0.1, "no location 'node 0'"),  # a clamped node is no candidate
    ],
)
def test_invalid_effect_values_are_refused_naming_the_parameter(library, benchmark_model, kind, location, value,
                                                                message):
    with pytest.raises(ValueError, match=message):
        E.extended_frf(benchmark_model, ALPHA_ACTUAL, FREQS, [E.Applied(library[kind], location, np.array([value]))])


def test_user_effects_can_be_registered_and_are_built_for_the_model(benchmark_model):
    class TipMass(E.Effect):
        kind = "tip_mass"
        parameters = ("mass",)
        units = ("kg",)
        lower = (0.0,)
        upper = (np.inf,)
        scale = (0.1,)

        def locations(self):
            return ["mid-span"]

        def terms(self, alpha, location, values):
            node = self.model.mesh.nearest_node([0.313, 0.0, 0.010], atol=0.01)
            rows = self.model.free_dofs.searchsorted(3 * node + np.arange(3))
            return E.Terms(mass=sp.csr_matrix((np.full(3, values[0]), (rows, rows)),
                                              shape=(self.model.n_dofs,) * 2))

    E.register_effect("tip_mass", TipMass)
    try:
        with pytest.raises(ValueError, match="already registered"):
            E.register_effect("tip_mass", TipMass)
        lib = E.build_library(benchmark_model, ["tip_mass", "damping"])
        assert [e.kind for e in lib] == ["tip_mass", "damping"]
        Z0 = E.extended_frf(benchmark_model, ALPHA_ACTUAL, FREQS)
        Z1 = E.extended_frf(benchmark_model, ALPHA_ACTUAL, FREQS, [E.Applied(lib[0], "mid-span", np.array([0.2]))])
        assert not np.allclose(Z0, Z1)
    finally:
        E.unregister_effect("tip_mass")
    assert "tip_mass" not in E.registered_effects()
    with pytest.raises(ValueError, match="unknown effect 'tip_mass'"):
        E.build_library(benchmark_model, ["tip_mass"])


def test_extended_krylov_frf_matches_the_direct_solver_with_every_effect(library, benchmark_model):
    applied = [E.Applied(library["point_mass"], "node 337", np.array([0.12])),
               E.Applied(library["grounded_spring"], "node 633", np.array([4e5])),
               E.Applied(library["joint_band"], "joint x=230 mm", np.array([-0.75])),
               E.Applied(library["segment_mass"], "segment5", np.array([0.3])),
               E.Applied(library["damping"], "b", np.array([3e-5]))]
    fast = E.extended_frf(benchmark_model, ALPHA_ACTUAL, FREQS, applied)
    ref = E.extended_frf(benchmark_model, ALPHA_ACTUAL, FREQS, applied, method="direct")
    assert np.max(np.abs(fast - ref)) <= 1e-8 * np.max(np.abs(ref))
    base = E.extended_frf(benchmark_model, ALPHA_ACTUAL, FREQS)
    assert np.max(np.abs(base - benchmark_model.frf(ALPHA_ACTUAL, FREQS))) == 0.0


@pytest.mark.parametrize(
    ("kind", "location", "step"),
    [("point_mass", "node 397", 1e-3), ("grounded_spring", "node 633", 1e2), ("joint_band", "joint x=396 mm", 1e-3),
     ("segment_mass", "segment2", 1e-3), ("damping", "a", 1e-2), ("damping", "b", 1e-7),
     ("sensor_mass", "all sensors", 1e-4), ("grounded_spring_x", "node 633", 1e2), ("patch", "node 331 r2", 1e-3),
     ("sensor_gain", "sensor 4", 1e-3)],
)
def test_linearised_sensitivities_match_central_differences_of_the_direct_solver(library, benchmark_model, kind,
                                                                                location, step):
    """The reciprocity-based derivative against finite differences of an independent (direct LU) FRF."""
    effect = library[kind]
    # Linearise at a point that already carries another effect, so the reference point is not special.
    carried = [E.Applied(library["point_mass"], "node 337", np.array([0.05]))]
    lin = E.LinearisedResponse(benchmark_model, ALPHA_ACTUAL, FREQS, carried)
    analytic = lin.effect_derivatives(effect, location)[:, 0]
    lo = 0.0 if kind in ("point_mass", "grounded_spring", "sensor_mass", "grounded_spring_x") else -step  # masses and springs are >= 0
    plus = E.extended_frf(benchmark_model, ALPHA_ACTUAL, FREQS, carried + [E.Applied(effect, location, [step])],
                          method="direct")
    minus = E.extended_frf(benchmark_model, ALPHA_ACTUAL, FREQS, carried + [E.Applied(effect, location, [lo])],
                           method="direct")
    fd = (np.log(np.abs(plus)) - np.log(np.abs(minus))).ravel() / (step - lo)
    tol = 1e-4 if lo < 0 else 5e-3  # central vs one-sided difference
    assert np.max(np.abs(analytic - fd)) <= tol * np.max(np.abs(fd))


def test_alpha_sensitivities_include_the_alpha_dependence_of_a_band(library, benchmark_model):
    carried = [E.Applied(library["joint_band"], "joint x=230 mm", np.array([-0.6]))]
    J = E.LinearisedResponse(benchmark_model, ALPHA_ACTUAL, FREQS, carried).alpha_derivatives()
    h = 1e-5
    for i in (1, 2, 4):  # segments 2 and 3 hold the band; 5 does not
        ap, am = ALPHA_ACTUAL.copy(), ALPHA_ACTUAL.copy()
        ap[i] += h
        am[i] -= h
        fd = (np.log(np.abs(E.extended_frf(benchmark_model, ap, FREQS, carried, method="direct")))
              - np.log(np.abs(E.extended_frf(benchmark_model, am, FREQS, carried, method="direct")))).ravel() / (2 * h)
        assert np.max(np.abs(J[:, i] - fd)) <= 1e-5 * np.max(np.abs(fd))


def test_sensor_mass_puts_one_mass_on_every_translation_of_every_sensor_node(library, benchmark_model):
    t = library["sensor_mass"].terms(ALPHA_ACTUAL, "all sensors", np.array([0.025]))
    for c in range(3):  # an accelerometer is a rigid point mass: all three translations
        v = rigid(benchmark_model, c)
        assert v @ (t.mass @ v) == pytest.approx(6 * 0.025, rel=1e-12)
    nodes = benchmark_model.free_dofs[t.mass.nonzero()[0]] // DOFS_PER_NODE
    assert set(nodes) == set(benchmark_model.sensor_nodes)
    # plausible: all six together at most 20 % of the structure
    assert library["sensor_mass"].bounds_at("all sensors")[1][0] == pytest.approx(0.2 * 5.83726 / 6, rel=1e-5)


def test_sensor_gain_scales_one_sensors_amplitude_and_leaves_the_structure_alone(library, benchmark_model):
    applied = [E.Applied(library["sensor_gain"], "sensor 2", np.array([0.08]))]
    K, M, a, b = E.extended_matrices(benchmark_model, ALPHA_ACTUAL, applied)
    K0, M0, _, _ = E.extended_matrices(benchmark_model, ALPHA_ACTUAL)
    assert abs(K - K0).max() == 0 and abs(M - M0).max() == 0
    ratio = E.extended_frf(benchmark_model, ALPHA_ACTUAL, FREQS, applied) / benchmark_model.frf(ALPHA_ACTUAL, FREQS)
    assert np.allclose(ratio, [1, 1.08, 1, 1, 1, 1], rtol=1e-9)


def test_grounded_springs_act_along_their_own_axis(library, benchmark_model):
    for kind, c in (("grounded_spring_x", 0), ("grounded_spring_y", 1), ("grounded_spring", 2)):
        t = library[kind].terms(ALPHA_ACTUAL, "node 633", np.array([1e5]))
        for d in range(3):
            v = rigid(benchmark_model, d)
            assert v @ (t.stiffness @ v) == pytest.approx(1e5 if d == c else 0.0)
    with pytest.raises(ValueError, match="direction"):
        E.GroundedSpring(benchmark_model, component=3)


def test_patches_grow_by_rings_of_cells_around_their_node(library, benchmark_model):
    cells = benchmark_model.mesh.cells
    bands = library["patch"].bands
    ring1, ring2 = bands["node 331 r1"], bands["node 331 r2"]
    assert set(ring1) == set(np.flatnonzero(np.any(cells == 331, axis=1)))
    assert set(ring1) < set(ring2)
    assert set(ring2) == set(np.flatnonzero(np.any(np.isin(cells, np.unique(cells[ring1])), axis=1)))


def test_plausible_limits_can_be_set_and_default_to_a_fifth_of_the_structure(benchmark_model):
    pm = E.PointMass(benchmark_model)
    assert pm.bounds_at("node 337")[1][0] == pytest.approx(0.2 * benchmark_model.total_mass())
    pm.set_limits(upper=0.5)
    assert pm.bounds_at("node 337")[1][0] == 0.5
    with pytest.raises(ValueError, match="below"):
        pm.set_limits(lower=1.0)


# -- any model (issue 15): a model given as matrices, a tetrahedral mesh from a model file -------------
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def cantilever():
    """scikit-fem's cantilever as exported matrices: no mesh, DOF-table node ids, tip load along y + z/2."""
    from fe_core.io import read_model

    return read_model(REPO / "data" / "examples" / "cantilever_matrices" / "model.toml")


@pytest.fixture(scope="module")
def tet_bar(tmp_path_factory):
    """A 0.4 x 0.04 x 0.02 m tet4 bar from a model file: segment ``left`` (x < 0.2), the ``right`` cell
    set is the fixed remainder; clamped at x = 0; sensors y and z at the tip, load along (0, 1, 1)."""
    import meshio

    from fe_core.io import read_model
    from fe_core.tet_mesh import box_tets

    nodes, cells = box_tets((0.4, 0.04, 0.02), (8, 2, 1))
    x = nodes[cells].mean(axis=1)[:, 0]
    folder = tmp_path_factory.mktemp("tet_bar")
    meshio.write(folder / "bar.inp", meshio.Mesh(
        nodes, [("tetra", cells)], cell_sets={"left": [np.flatnonzero(x < 0.2)], "right": [np.flatnonzero(x > 0.2)]},
        point_sets={"clamped": np.flatnonzero(np.isclose(nodes[:, 0], 0.0))}), file_format="abaqus")
    tip = [0.4, 0.04, 0.02]
    (folder / "model.toml").write_text("\n".join([
        'mesh = "bar.inp"', "[damping]", "a = 5.0", "b = 2e-5",
        "[[materials]]", "E = 2e11", "nu = 0.3", "rho = 7800.0",
        "[[segments]]", 'set = "left"', "[[supports]]", 'nodes = "clamped"',
        "[[sensors]]", f"point = {tip}", 'direction = "y"', "[[sensors]]", f"point = {tip}", 'direction = "z"',
        "[[excitations]]", f"point = {tip}", "direction = [0.0, 1.0, 1.0]", ""]))
    return read_model(folder / "model.toml")


def test_a_model_given_as_matrices_gets_the_nodal_effects_and_refuses_the_cell_ones(cantilever):
    lib = {e.kind: e for e in E.build_library(cantilever)}
    assert set(lib) == {"segment_mass", "point_mass", "grounded_spring", "damping", "grounded_spring_x",
                        "grounded_spring_y", "sensor_mass", "sensor_gain"}
    table = cantilever.dof_table
    clamped = {0, 1, 2, 78, 79, 80, 156, 157, 158}
    assert len(lib["point_mass"].locations()) == np.unique(table[:, 0]).size - len(clamped)
    assert "node 0" not in lib["point_mass"].locations() and "node 233" in lib["point_mass"].locations()
    t = lib["point_mass"].terms(np.zeros(4), "node 233", np.array([0.3]))
    for c in range(3):  # the node's three translations, found through the DOF table
        v = (table[:, 1] == c).astype(float)[cantilever.free_dofs]
        assert v @ (t.mass @ v) == pytest.approx(0.3, rel=1e-14)
    (row,), _ = lib["grounded_spring_y"].terms(np.zeros(4), "node 233", np.array([1e5])).stiffness.nonzero()
    assert tuple(table[cantilever.free_dofs[row]]) == (233, 1)
    # The sensors' nodes come from the output vectors (the model file's sensor nodes).
    assert lib["sensor_mass"].nodes.tolist() == [173, 188, 203, 218, 233]
    # Placed with the model's node table (nodes.csv): node 233 is on the sensors' edge at the free end, x = 1 m.
    assert lib["point_mass"].describe("node 233") == pytest.approx({"node": 233, "x_m": 1.0, "y_m": 0.08, "z_m": 0.05})
    assert "node 232" in lib["point_mass"].neighbours("node 233")  # coupled through K
    with pytest.raises(ValueError, match="'patch' does not apply to the model .*model.toml: it needs a mesh"):
        E.build_library(cantilever, ["patch"])
    with pytest.raises(ValueError, match="has no mesh"):
        E.ElementBand(cantilever, {"some cells": np.arange(3)})


def test_bands_on_a_tetrahedral_model_file_split_into_segments_and_the_fixed_remainder(tet_bar):
    alpha = np.array([-0.3])
    everything = E.ElementBand(tet_bar, {"all": np.arange(tet_bar.mesh.n_cells)})
    K = tet_bar.stiffness(alpha)  # the reader's assembly: the independent reference
    assert abs(everything.terms(alpha, "all", np.array([0.5])).stiffness - 0.5 * K).max() <= 1e-12 * abs(K).max()
    lib = {e.kind: e for e in E.build_library(tet_bar)}
    # "left" is a whole segment (its factor is alpha_1): only "right", the remainder, is a cell-set effect.
    assert lib["cell_set"].locations() == ["set right"]
    K0 = tet_bar.stiffness_segments.remainder()
    right = lib["cell_set"].terms(alpha, "set right", np.array([-0.4])).stiffness
    assert abs(right + 0.4 * K0).max() <= 1e-12 * abs(K0).max()
    assert abs(lib["cell_set"].alpha_derivative(alpha, "set right", np.array([-0.4]), 0).stiffness).max() == 0
    patches = lib["patch"].bands
    assert patches and all(label.endswith((" r1", " r2")) for label in patches)


@pytest.mark.parametrize(("model_name", "kind", "step"), [
    ("cantilever", "point_mass", 1e-3), ("cantilever", "grounded_spring_y", 1e2), ("cantilever", "sensor_mass", 1e-3),
    ("cantilever", "sensor_gain", 1e-3), ("cantilever", "damping", 1e-2),
    ("tet_bar", "patch", 1e-3), ("tet_bar", "cell_set", 1e-3), ("tet_bar", "point_mass", 1e-3),
])
def test_linearised_sensitivities_on_any_model_match_differences_of_the_direct_solver(request, model_name, kind,
                                                                                     step):
    """The load is not the sum of the output vectors here (tip y + z/2, or along (0, 1, 1)): the
    linearisation solves for the load and the sensors separately."""
    model = request.getfixturevalue(model_name)
    lib = {e.kind: e for e in E.build_library(model)}
    effect = lib[kind]
    location = effect.locations()[len(effect.locations()) // 2] if kind != "damping" else "a"
    alpha = np.full(model.n_segments, 0.1)
    freqs = np.array([20.0, 90.0, 300.0]) if model_name == "cantilever" else np.array([200.0, 900.0, 3000.0])
    carried = [E.Applied(lib["sensor_gain"], "sensor 2", np.array([0.05]))]
    lin = E.LinearisedResponse(model, alpha, freqs, carried)
    assert np.allclose(lin.Z, E.extended_frf(model, alpha, freqs), rtol=1e-8)  # the gain is not in Z
    analytic = lin.effect_derivatives(effect, location)[:, 0]
    lo = 0.0 if kind in ("point_mass", "grounded_spring_y", "sensor_mass") else -step
    plus, minus = (E.extended_frf(model, alpha, freqs, carried + [E.Applied(effect, location, [v])], method="direct")
                   for v in (step, lo))
    fd = (np.log(np.abs(plus)) - np.log(np.abs(minus))).ravel() / (step - lo)
    assert np.max(np.abs(analytic - fd)) <= (1e-4 if lo < 0 else 5e-3) * np.max(np.abs(fd))


def test_a_matrices_model_offers_only_the_nodes_its_node_table_places():
    """A solver's own nodes (CalculiX's expanded shell nodes carry DOFs in its matrices but no place in the deck)
    are not candidate places: a mass there is not a claim about the structure."""
    from dataclasses import replace

    from fe_core.closure.effects.base import candidate_nodes, node_rows
    from tasks.problem import read_model_ref

    model, _ = read_model_ref("data/examples/cantilever_matrices/model.toml")
    nodes, _ = node_rows(model)
    every = candidate_nodes(model)
    assert model.node_coordinates is not None and every.size > 10
    xyz = np.array(model.node_coordinates, float)
    unplaced = every[::7]
    xyz[np.searchsorted(nodes, unplaced)] = np.nan  # as the table leaves a solver's own nodes
    fewer = candidate_nodes(replace(model, node_coordinates=xyz))
    assert set(fewer) == set(every) - set(unplaced)
    assert set(E.PointMass(replace(model, node_coordinates=xyz)).nodes) == set(fewer)


def test_a_sensor_mass_with_no_node_to_sit_on_is_left_out_of_the_library_and_refused_by_name(benchmark_model):
    """Sensors reading only DOFs no node of the model owns (a solver's internal nodes): the transducers' mass would
    load nothing; it is not offered, and asked for by name it is refused saying what it needs."""
    import copy

    from fe_core.closure.effects import base, build_library

    model = copy.copy(benchmark_model)
    model.outputs = sp.csr_matrix(benchmark_model.outputs.shape)  # reads nothing a node owns
    model.sensor_nodes = None  # the sensors' nodes found from what they read
    assert "sensor_mass" not in {e.kind for e in build_library(model)}
    with pytest.raises(ValueError, match="sensor_mass.*sensors that read the DOFs of nodes"):
        build_library(model, ["sensor_mass"])
    assert "sensor_mass" in {e.kind for e in build_library(benchmark_model)}
    assert base._sensor_nodes(model).tolist() == [-1] * model.outputs.shape[1]
