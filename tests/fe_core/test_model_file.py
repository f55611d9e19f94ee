"""The model file (``fe_core.io``): the benchmark through it, mesh formats, units, remainder, outputs, matrices."""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from fe_core import Material, build_model, three_plate
from fe_core.benchmark import ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ
from fe_core.io import ModelFileError, read_model
from fe_core.mesh import Block, mesh_blocks

REPO = Path(__file__).resolve().parents[2]
FREQS = np.array([150.0, 400.0, 900.0])


def test_the_benchmark_model_file_gives_three_plates_frf():
    model = read_model(REPO / "data" / "benchmark" / "model.toml")
    ref = three_plate()
    assert model.n_dofs == ref.n_dofs == 3510 and model.segment_names == [f"segment{i}" for i in range(1, 7)]
    Z, Z0 = model.frf(ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ), ref.frf(ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ)
    assert np.max(np.abs(Z - Z0) / np.abs(Z0)) <= 1e-10
    H, H0 = model.frf_matrix(ALPHA_ACTUAL, [112.0]), ref.frf_matrix(ALPHA_ACTUAL, [112.0])
    assert np.max(np.abs(H - H0)) <= 1e-10 * np.abs(H0).max()
    assert model.total_mass() == pytest.approx(ref.total_mass(), rel=1e-12)
    assert model.modes(ALPHA_ACTUAL, 4)[2] == ref.modes(ALPHA_ACTUAL, 4)[2]
    assert np.array_equal(model.sensor_dofs, ref.sensor_dofs)


def test_the_benchmark_model_file_against_expected_json():
    """The file's sensor points and FRF against data/benchmark/expected.json (an independent implementation)."""
    import json
    import tomllib

    expected = json.loads((REPO / "data" / "benchmark" / "expected.json").read_text())
    spec = tomllib.loads((REPO / "data" / "benchmark" / "model.toml").read_text())
    xyz = np.array(expected["frf"]["sensor_xyz_m"])
    # Decimal literals in two text files, parsed to the nearest double on any CPU: equal to round-off.
    np.testing.assert_allclose([s["point"] for s in spec["sensors"]], xyz, rtol=0, atol=1e-12)
    np.testing.assert_allclose([d["point"] for d in spec["excitations"][0]["dofs"]], xyz, rtol=0, atol=1e-12)
    model = read_model(REPO / "data" / "benchmark" / "model.toml")
    amp = np.abs(model.frf(expected["actual"]["alpha"], expected["frf"]["frequencies_Hz"]))
    # The SPEC's agreement between identical formulations (about 1e-6 or better), not one CPU's round-off.
    np.testing.assert_allclose(amp, expected["frf"]["amplitude_m_per_N"], rtol=1e-6)
    # Mass = rho x volume of brick cells summed (round-off ~1e-15 on any CPU); the SPEC states 5.83726 kg,
    # which is exact for these plates, so 1e-9 bounds the summation, not a machine.
    assert model.total_mass() == pytest.approx(expected["total_mass_kg"], rel=1e-9)


# -- a small two-block bar, written in each format ------------------------------------------------
STEEL = Material(E=2.0e11, nu=0.3, rho=7800.0)


def _bar():
    """A 0.4 x 0.04 x 0.02 m bar, 8 x 2 x 1 hex8 in two cell sets, clamped at x = 0."""
    mesh = mesh_blocks([Block(np.linspace(0, 0.2, 5), np.linspace(0, 0.04, 3), np.array([0, 0.02]), "left"),
                        Block(np.linspace(0.2, 0.4, 5), np.linspace(0, 0.04, 3), np.array([0, 0.02]), "right")])
    mesh.add_node_set("clamped", mesh.nodes_where(x=0.0))
    return mesh


def _toml(mesh_name: str, scale: float = 1.0, units: str = "SI", E: float = STEEL.E, rho: float = STEEL.rho,
          segments=("left", "right"), sensor_direction='"z"', extra: str = "") -> str:
    """A model file for the bar; ``extra`` goes at the top level."""
    p = [[0.4 * scale, 0.04 * scale, 0.02 * scale], [0.2 * scale, 0.0, 0.0]]
    text = [extra, f'units = "{units}"', f'mesh = "{mesh_name}"', "[damping]", "a = 5.0", "b = 2e-5", "",
            "[[materials]]", f"E = {E!r}", "nu = 0.3", f"rho = {rho!r}", ""]
    for s in segments:
        text += ["[[segments]]", f'set = "{s}"', ""]
    text += ["[[supports]]", 'nodes = "clamped"', "",
             "[[sensors]]", 'name = "tip"', f"point = {p[0]}", f"direction = {sensor_direction}", "",
             "[[sensors]]", 'name = "middle"', f"point = {p[1]}", 'direction = "y"', "",
             "[[excitations]]", 'name = "tip z"', f"point = {p[0]}", 'direction = "z"', ""]
    return "\n".join(text)


def _write(mesh, path: Path, fmt: str, scale: float = 1.0) -> None:
    pts = mesh.nodes * scale
    if fmt == "abaqus":
        out = meshio.Mesh(pts, [("hexahedron", mesh.cells)], cell_sets={k: [v] for k, v in mesh.cell_sets.items()},
                          point_sets=dict(mesh.node_sets))
    else:  # vtu: 0/1 integer arrays
        cell = {k: [np.isin(np.arange(mesh.n_cells), v).astype(np.int32)] for k, v in mesh.cell_sets.items()}
        point = {k: np.isin(np.arange(mesh.n_nodes), v).astype(np.int32) for k, v in mesh.node_sets.items()}
        out = meshio.Mesh(pts, [("hexahedron", mesh.cells)], cell_data=cell, point_data=point)
    meshio.write(path, out, file_format=fmt)


def _reference(mesh):
    """The bar by the benchmark's own builder (no model file), with the same sensors and load."""
    tip = mesh.nearest_node([0.4, 0.04, 0.02])
    model = build_model(mesh, STEEL, {"left": mesh.cell_sets["left"], "right": mesh.cell_sets["right"]},
                        mesh.node_sets["clamped"], [tip], (5.0, 2e-5))
    return model, tip


@pytest.mark.parametrize("fmt, suffix", [("abaqus", ".inp"), ("vtu", ".vtu")])
def test_each_mesh_format_gives_the_same_model(fmt, suffix, tmp_path):
    mesh = _bar()
    _write(mesh, tmp_path / f"bar{suffix}", fmt)
    (tmp_path / "model.toml").write_text(_toml(f"bar{suffix}"))
    model = read_model(tmp_path / "model.toml")
    ref, tip = _reference(mesh)
    alpha = [0.3, -0.2]
    Z = model.frf(alpha, FREQS)[:, 0]  # the tip's u_z under the tip's z force
    Z0 = ref.frf(alpha, FREQS)[:, 0]
    assert np.max(np.abs(Z - Z0) / np.abs(Z0)) <= 1e-10
    assert model.n_dofs == ref.n_dofs


def _gmsh_two_boxes(path: Path, size: tuple, names: tuple, support: str, hexahedra: bool) -> None:
    """Two boxes ``size`` (x, y, z) side by side along x, meshed by gmsh itself: physical volumes
    ``names``, the physical surface ``support`` at x = 0. Hexahedra (transfinite, recombined: 4 x 2 x 1
    cells per box) or linear tetrahedra (size 0.03)."""
    import gmsh

    lx, ly, lz = size
    gmsh.initialize(["-noenv"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.03)
        first = gmsh.model.occ.addBox(0, 0, 0, lx, ly, lz)
        second = gmsh.model.occ.addBox(lx, 0, 0, lx, ly, lz)
        gmsh.model.occ.fragment([(3, first)], [(3, second)])
        gmsh.model.occ.synchronize()
        if hexahedra:
            for dim, tag in gmsh.model.getEntities(1):
                x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(dim, tag)  # padded boxes: compare halves
                n = 5 if x1 - x0 > lx / 2 else 3 if y1 - y0 > ly / 2 else 2
                gmsh.model.mesh.setTransfiniteCurve(tag, n)
            for dim, tag in gmsh.model.getEntities(2):
                gmsh.model.mesh.setTransfiniteSurface(tag)
                gmsh.model.mesh.setRecombine(dim, tag)
            for dim, tag in gmsh.model.getEntities(3):
                gmsh.model.mesh.setTransfiniteVolume(tag)
        vols = sorted(gmsh.model.getEntities(3), key=lambda e: gmsh.model.occ.getCenterOfMass(*e)[0])
        for (_, tag), name in zip(vols, names):
            gmsh.model.addPhysicalGroup(3, [tag], name=name)
        end = [t for d, t in gmsh.model.getEntities(2) if abs(gmsh.model.occ.getCenterOfMass(d, t)[0]) < 1e-12]
        gmsh.model.addPhysicalGroup(2, end, name=support)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


def test_a_gmsh_msh4_file_with_physical_groups(tmp_path):
    _gmsh_two_boxes(tmp_path / "bar.msh", (0.2, 0.04, 0.02), ("left", "right"), "clamped", hexahedra=True)
    assert (tmp_path / "bar.msh").read_text().splitlines()[1].startswith("4.1")
    (tmp_path / "model.toml").write_text(_toml("bar.msh"))
    model = read_model(tmp_path / "model.toml")
    # The reference: gmsh's nodes and hexahedra through the benchmark's builder, sets by coordinates.
    raw = meshio.read(tmp_path / "bar.msh")
    cells = np.vstack([c.data for c in raw.cells if c.type == "hexahedron"])
    used = np.unique(cells)
    index = np.full(len(raw.points), -1)
    index[used] = np.arange(used.size)
    from fe_core.mesh import Mesh

    mesh = Mesh(nodes=raw.points[used], cells=index[cells])
    x = mesh.centroids[:, 0]
    mesh.add_cell_set("left", np.flatnonzero(x < 0.2))
    mesh.add_cell_set("right", np.flatnonzero(x > 0.2))
    mesh.add_node_set("clamped", mesh.nodes_where(x=0.0))
    assert mesh.n_cells == 16 and mesh.node_sets["clamped"].size == 6
    ref, _ = _reference(mesh)
    Z, Z0 = model.frf([0.3, -0.2], FREQS)[:, 0], ref.frf([0.3, -0.2], FREQS)[:, 0]
    assert np.max(np.abs(Z - Z0) / np.abs(Z0)) <= 1e-10


def test_mm_t_s_units_give_the_si_model(tmp_path):
    mesh = _bar()
    _write(mesh, tmp_path / "si.inp", "abaqus")
    _write(mesh, tmp_path / "mm.inp", "abaqus", scale=1000.0)
    (tmp_path / "si.toml").write_text(_toml("si.inp"))
    (tmp_path / "mm.toml").write_text(_toml("mm.inp", 1000.0, "mm-t-s", E=STEEL.E / 1e6, rho=STEEL.rho * 1e-12,
                                            extra="point_tolerance = 1e-3"))
    Z_si = read_model(tmp_path / "si.toml").frf([0.1, 0.2], FREQS, method="direct")
    Z_mm = read_model(tmp_path / "mm.toml").frf([0.1, 0.2], FREQS, method="direct")
    # Unit conversion rounds the inputs at 1e-16; the solve amplifies that by the dynamic stiffness's
    # condition, so the error is measured against the largest response at each frequency (the middle
    # sensor's response is 1e-3 of the tip's).
    scale = np.abs(Z_si).max(axis=1, keepdims=True)
    assert np.max(np.abs(Z_mm - Z_si) / scale) <= 1e-10


def test_cells_in_no_segment_are_the_fixed_remainder(tmp_path):
    mesh = _bar()
    _write(mesh, tmp_path / "bar.inp", "abaqus")
    (tmp_path / "both.toml").write_text(_toml("bar.inp"))
    (tmp_path / "left.toml").write_text(_toml("bar.inp", segments=("left",)))
    both, left = read_model(tmp_path / "both.toml"), read_model(tmp_path / "left.toml")
    assert left.n_segments == 1
    Z = left.frf([-0.4], FREQS, method="direct")
    Z0 = both.frf([-0.4, 0.0], FREQS, method="direct")  # the right block at its nominal stiffness
    # the sums differ in order (round-off 1e-16), amplified by the condition: against each frequency's largest
    assert np.max(np.abs(Z - Z0) / np.abs(Z0).max(axis=1, keepdims=True)) <= 1e-10
    assert left.total_mass() == pytest.approx(both.total_mass(), rel=1e-12)
    assert left.total_mass() == pytest.approx(7800.0 * 0.4 * 0.04 * 0.02, rel=1e-12)


def test_a_sensor_along_a_vector_reads_the_combination_of_components(tmp_path):
    mesh = _bar()
    _write(mesh, tmp_path / "bar.inp", "abaqus")
    (tmp_path / "x.toml").write_text(_toml("bar.inp", sensor_direction='"x"'))
    (tmp_path / "z.toml").write_text(_toml("bar.inp", sensor_direction='"z"'))
    (tmp_path / "v.toml").write_text(_toml("bar.inp", sensor_direction="[3.0, 0.0, 4.0]"))
    zx, zz, zv = (read_model(tmp_path / f"{k}.toml").frf([0.0, 0.0], FREQS)[:, 0] for k in "xzv")
    assert np.allclose(zv, 0.6 * zx + 0.8 * zz, rtol=1e-9, atol=0)
    with pytest.raises(ValueError, match="combines several DOFs"):
        _ = read_model(tmp_path / "v.toml").sensor_dofs


def test_excitation_weights_scale_and_add(tmp_path):
    mesh = _bar()
    _write(mesh, tmp_path / "bar.inp", "abaqus")
    base = _toml("bar.inp").split("[[excitations]]")[0]
    one = base + '[[excitations]]\nname = "tip"\npoint = [0.4, 0.04, 0.02]\ndirection = "z"\n'
    two = base + ('[[excitations]]\nname = "pair"\ndofs = [{ point = [0.4, 0.04, 0.02], direction = "z", weight = 2.0 },'
                  ' { point = [0.2, 0.0, 0.0], direction = "y", weight = -1.0 }]\n')
    mid = base + '[[excitations]]\nname = "mid"\npoint = [0.2, 0.0, 0.0]\ndirection = "y"\n'
    Z = {}
    for name, text in (("one", one), ("two", two), ("mid", mid)):
        (tmp_path / f"{name}.toml").write_text(text)
        Z[name] = read_model(tmp_path / f"{name}.toml").frf([0.0, 0.1], FREQS, method="direct")
    assert np.allclose(Z["two"], 2 * Z["one"] - Z["mid"], rtol=1e-9, atol=1e-9 * np.abs(Z["one"]).max())


def test_several_excitations_need_a_choice(tmp_path):
    mesh = _bar()
    _write(mesh, tmp_path / "bar.inp", "abaqus")
    text = _toml("bar.inp") + '\n[[excitations]]\nname = "mid"\npoint = [0.2, 0.0, 0.0]\ndirection = "y"\n'
    (tmp_path / "m.toml").write_text(text)
    with pytest.raises(ModelFileError, match="key 'excitation': 2 excitations"):
        read_model(tmp_path / "m.toml")
    (tmp_path / "m.toml").write_text('excitation = "mid"\n' + text)
    assert read_model(tmp_path / "m.toml").excitation_name == "mid"


# -- matrices exported by scikit-fem ------------------------------------------------------------
def test_imported_scikit_fem_matrices_give_scikit_fems_frf(tmp_path):
    """A coarser mesh of example (b): our FRF from the files against scikit-fem + scipy's direct solve."""
    from benchmarks.make.matrix_example import DAMPING, skfem_model, write_files
    from skfem import condense

    fem = skfem_model(n_x=10, n_y=1, n_z=1)
    write_files(fem, tmp_path)
    model = read_model(tmp_path / "model.toml")
    alpha = np.array([-0.3, 0.2, 0.1, -0.1])
    freqs = np.array([50.0, 80.0, 300.0, 700.0, 1300.0])
    # scikit-fem's own: its matrices, its condensation, scipy's sparse LU per frequency
    K = sum((1 + a) * Ki for a, Ki in zip(alpha, fem["K"][:-1])) + fem["K"][-1]
    M = sum(fem["M"])
    a, b = DAMPING
    ref = []
    for w in 2 * np.pi * freqs:
        A, F, _, interior = condense((K - w**2 * M + 1j * w * (a * M + b * K)).tocsc(),
                                     fem["load"].astype(complex), D=fem["fixed"])
        u = np.zeros(K.shape[0], complex)
        u[interior] = spla.spsolve(sp.csc_matrix(A), F)
        ref.append(u[fem["sensors"]])
    ref = np.array(ref)
    for method in ("krylov", "direct"):
        Z = model.frf(alpha, freqs, method=method)
        assert np.max(np.abs(Z - ref) / np.abs(ref)) <= 1e-8, method
    assert model.mesh is None
    freqs_, shapes, labels = model.modes(alpha, 3)
    assert labels == ["mode 1", "mode 2", "mode 3"] and shapes.shape == (3, fem["basis"].N)
    assert model.total_mass() == pytest.approx(7850.0 * 1.0 * 0.08 * 0.05, rel=1e-12)


def _update_masses(text: str, names, bounds=(-0.3, 0.3)) -> str:
    """A model file's text with the mass factors of the named segments updated too."""
    for name in names:
        text = text.replace(f'name = "{name}"\n',
                            f'name = "{name}"\nupdate = ["stiffness", "mass"]\nmass_bounds = {list(bounds)}\n')
    return text


def test_segment_mass_factors_are_updated_where_asked_and_recovered_from_scikit_fems_frf(tmp_path):
    """``update = ["stiffness", "mass"]`` on seg2 and seg3: the parameter vector is [alpha_1..4, gamma_2, gamma_3];
    scikit-fem's own FRF with those segments' mass matrices scaled (an independent path) is the model's, and
    least squares from the nominal model (exact Jacobian with the gamma columns) recovers every factor."""
    from benchmarks.make.matrix_example import skfem_frf, skfem_model, write_files
    from fe_core.inference.intervals import fit_log_amplitudes

    fem = skfem_model(n_x=10, n_y=1, n_z=1)
    write_files(fem, tmp_path)
    (tmp_path / "model.toml").write_text(_update_masses((tmp_path / "model.toml").read_text(), ("seg2", "seg3")))
    model = read_model(tmp_path / "model.toml")
    assert model.parameter_names == ["alpha_1", "alpha_2", "alpha_3", "alpha_4", "gamma_2", "gamma_3"]
    np.testing.assert_array_equal(model.parameter_bounds, [[-0.5, 0.5]] * 4 + [[-0.3, 0.3]] * 2)
    alpha, gamma = np.array([-0.1, 0.1, 0.05, -0.05]), np.array([0.0, 0.15, -0.1, 0.0])
    theta = np.concatenate([alpha, gamma[1:3]])
    assert model.total_mass(model.factors(theta)[1]) == pytest.approx(
        sum((1 + g) * M.sum() / 3 for g, M in zip(np.append(gamma, 0.0), fem["M"])), rel=1e-12)
    f0 = model.natural_frequencies(alpha, 5, gamma)
    freqs = np.round(np.concatenate([f * np.array([0.9, 0.95, 1.0, 1.05, 1.1]) for f in f0[[0, 2, 4]]]), 1)
    ref = skfem_frf(fem, alpha, freqs, gamma)
    assert np.max(np.abs(model.parameter_frf(theta, freqs) - ref) / np.abs(ref)) <= 1e-8  # as the import test
    lower, upper = model.parameter_bounds.T
    fit = fit_log_amplitudes(model, freqs, np.abs(ref), np.zeros(6), lower, upper, max_fe_runs=30)
    # noise-free data: the optimum is the truth, to the solver's step tolerance
    np.testing.assert_allclose(fit.alpha, theta, rtol=0, atol=1e-6)


def test_npz_matrices_read_as_the_mtx_ones(tmp_path):
    from benchmarks.make.matrix_example import skfem_model, write_files

    write_files(skfem_model(n_x=6, n_y=1, n_z=1), tmp_path)
    text = (tmp_path / "model.toml").read_text()
    for f in tmp_path.glob("*.mtx"):
        import scipy.io

        sp.save_npz(tmp_path / f"{f.stem}.npz", sp.csr_matrix(scipy.io.mmread(str(f))))
    (tmp_path / "npz.toml").write_text(text.replace(".mtx", ".npz"))
    alpha, freqs = [0.1, -0.2, 0.3, 0.0], [60.0, 500.0]
    Z_mtx = read_model(tmp_path / "model.toml").frf(alpha, freqs, method="direct")
    Z_npz = read_model(tmp_path / "npz.toml").frf(alpha, freqs, method="direct")
    assert np.array_equal(Z_mtx, Z_npz)


# -- a tetrahedral gmsh mesh through the registry's tet4 (fe_core/elements/tet4.py) -----------------
def test_a_tetrahedral_gmsh_mesh_through_the_tet4_family(tmp_path):
    """Gmsh tetrahedra, a physical surface as support: the model file's FRF is scikit-fem's on the same mesh."""
    from skfem import Basis, BilinearForm, ElementTetP1, ElementVector, MeshTet, asm, condense
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    _gmsh_two_boxes(tmp_path / "tets.msh", (0.1, 0.04, 0.03), ("a", "b"), "foot", hexahedra=False)
    tip = [0.2, 0.04, 0.03]
    (tmp_path / "model.toml").write_text("\n".join([
        'mesh = "tets.msh"', "[damping]", "a = 3.0", "b = 1e-5",
        "[[materials]]", "E = 7e10", "nu = 0.33", "rho = 2700.0",
        '[[segments]]', 'set = "a"', '[[segments]]', 'set = "b"',
        '[[supports]]', 'nodes = "foot"',
        '[[sensors]]', f"point = {tip}", 'direction = "y"',
        '[[excitations]]', f"point = {tip}", "direction = [0.0, 1.0, 1.0]", ""]))
    model = read_model(tmp_path / "model.toml")
    alpha, freqs = np.array([0.2, -0.3]), np.array([500.0, 2000.0, 5000.0])
    Z = model.frf(alpha, freqs, method="direct")[:, 0]

    # scikit-fem alone on gmsh's tetrahedra: global assembly per physical volume, its condensation
    raw = meshio.read(tmp_path / "tets.msh")
    cells = np.vstack([c.data for c in raw.cells if c.type == "tetra"])
    used = np.unique(cells)
    index = np.full(len(raw.points), -1)
    index[used] = np.arange(used.size)
    p, t = raw.points[used], index[cells]
    neg = np.linalg.det(p[t[:, 1:]] - p[t[:, :1]]) < 0
    t[neg] = t[neg][:, [0, 2, 1, 3]]
    mesh = MeshTet(p.T.copy(), t.T.copy())
    e = ElementVector(ElementTetP1())
    x = p[t].mean(axis=1)[:, 0]

    @BilinearForm
    def mass(u, v, w):
        return 2700.0 * dot(u, v)

    stiff = linear_elasticity(*lame_parameters(7e10, 0.33))
    Ks = [asm(stiff, Basis(mesh, e, elements=np.flatnonzero(sel))) for sel in (x < 0.1, x > 0.1)]
    M = asm(mass, Basis(mesh, e))
    K = (1 + alpha[0]) * Ks[0] + (1 + alpha[1]) * Ks[1]
    basis = Basis(mesh, e)
    fixed = basis.nodal_dofs[:, np.flatnonzero(np.isclose(p[:, 0], 0.0))].ravel()
    node = int(np.argmin(np.linalg.norm(p - tip, axis=1)))
    F = np.zeros(basis.N)
    F[basis.nodal_dofs[1:, node]] = 1 / np.sqrt(2)
    ref = []
    for w in 2 * np.pi * freqs:
        A, f, _, interior = condense((K - w**2 * M + 1j * w * (3.0 * M + 1e-5 * K)).tocsc(), F.astype(complex),
                                     D=fixed)
        u = np.zeros(basis.N, complex)
        u[interior] = spla.spsolve(sp.csc_matrix(A), f)
        ref.append(u[basis.nodal_dofs[1, node]])
    ref = np.array(ref)
    assert np.max(np.abs(Z - ref) / np.abs(ref)) <= 1e-9


def test_the_checker_command_prints_the_model_or_refuses(tmp_path, capsys):
    from fe_core.io.__main__ import main

    assert main([str(REPO / "data" / "benchmark" / "model.toml")]) == 0
    out = capsys.readouterr().out
    assert "3510 free DOFs" in out and "alpha_6: segment 'segment6'" in out and "148.32" in out
    (tmp_path / "bad.toml").write_text('mesh = "x.inp"\nmatrices = {}\n')
    assert main([str(tmp_path / "bad.toml")]) == 2
    assert "exactly one of 'mesh'" in capsys.readouterr().err
