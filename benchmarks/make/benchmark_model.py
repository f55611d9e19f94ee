"""Write the benchmark as a model file: ``data/benchmark/model.toml`` and its mesh ``three_plate.inp``.

    python -m benchmarks.make.benchmark_model

The mesh is :func:`fe_core.benchmark.three_plate`'s hex8 mesh, written with meshio as
Abaqus input (17 significant digits) with the element sets ``plate1..3`` and
``segment1..6`` and the node sets ``clamped`` and ``top``. The model file names the
sensors by the SPEC's positions (points, nearest node) with test nodes 1..6 and two
excitations: the combined one (a unit z force at each sensor; the default, the SPEC's
load) and a hammer at sensor 5 (test node 5, for ``data/benchmark/hammer.uff``), so
reading it goes through the general path
(:func:`fe_core.io.read_model`); ``tests/fe_core/test_model_file.py`` checks that
its FRF equals ``three_plate()``'s.
"""

from __future__ import annotations

import sys
from pathlib import Path

import meshio

from fe_core import benchmark as b

OUT = Path(__file__).resolve().parents[2] / "data" / "benchmark"
#: The sensor whose point and direction (u_z) the hammer hits: s5 has the largest driving-point
#: response of the second mode (291 Hz) and a strong first mode.
HAMMER_SENSOR = 5


def model_toml(mesh_name: str) -> str:
    """The benchmark's model file text."""
    points = [[float(f"{v:.12g}") for v in p] for p in b.sensor_positions()]
    lines = [
        "# The three-plate benchmark (shared/benchmark/SPEC.md) as a model file.",
        "# Written by python -m benchmarks.make.benchmark_model; the name three_plate is a shortcut to it.",
        'units = "SI"',
        f'mesh = "{mesh_name}"',
        "point_tolerance = 1e-6  # m: the sensors sit on nodes",
        'excitation = "combined"  # drives the FRF of data without a reference (sensor columns, UFF ref node 0)',
        "",
        "[damping]",
        f"a = {b.DAMPING[0]!r}  # 1/s",
        f"b = {b.DAMPING[1]!r}  # s",
        "",
        "[elements.hexahedron]",
        'formulation = "incompatible"',
        "",
        "[[materials]]",
        f"E = {b.STEEL.E!r}",
        f"nu = {b.STEEL.nu!r}",
        f"rho = {b.STEEL.rho!r}",
        "",
    ]
    for s in range(1, 7):
        lines += ["[[segments]]", f'set = "segment{s}"', ""]
    lines += ["[[supports]]", 'nodes = "clamped"', 'fix = ["x", "y", "z"]', ""]
    for j, p in enumerate(points, start=1):
        lines += ["[[sensors]]", f'name = "s{j}"', f"point = {p}", 'direction = "z"',
                  f"test_node = {j}  # the test's node id (UFF58), direction +z", ""]
    lines += ["[[excitations]]", 'name = "combined"  # a unit force along z at every sensor, in phase', "dofs = ["]
    lines += [f'  {{ point = {p}, direction = "z", weight = 1.0 }},' for p in points]
    lines += ["]", ""]
    lines += ["[[excitations]]", f'name = "hammer"  # an impact hammer at sensor s{HAMMER_SENSOR}\'s point along z '
              "(data/benchmark/hammer.uff)", f"point = {points[HAMMER_SENSOR - 1]}", 'direction = "z"',
              f"test_node = {HAMMER_SENSOR}", ""]
    return "\n".join(lines)


def main() -> int:
    model = b.three_plate()
    mesh = model.mesh
    n_cells = mesh.n_cells
    cell_sets = {name: [cells] for name, cells in mesh.cell_sets.items()}
    point_sets = {name: mesh.node_sets[name] for name in ("clamped", "top")}
    out = meshio.Mesh(mesh.nodes, [("hexahedron", mesh.cells)], cell_sets=cell_sets, point_sets=point_sets)
    assert all(len(c[0]) <= n_cells for c in cell_sets.values())
    OUT.mkdir(parents=True, exist_ok=True)
    meshio.write(OUT / "three_plate.inp", out, file_format="abaqus")
    (OUT / "model.toml").write_text(model_toml("three_plate.inp"))
    print(f"wrote {OUT / 'three_plate.inp'} and {OUT / 'model.toml'}")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.benchmark_model", __doc__)
    sys.exit(main())
