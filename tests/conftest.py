"""Shared fixtures: seeded generators and the (cached) benchmark model."""

from __future__ import annotations

import json
import os

# One BLAS thread, as the flow uses: OpenBLAS's threads make the small dense algebra of
# the MRGP and the closure several times slower on 2 cores. The variables reach the
# subprocesses the tests start; threadpoolctl limits this process, whose numpy may
# already be loaded by a plugin.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

threadpool_limits(1)

REPO = Path(__file__).resolve().parents[1]
#: The benchmark's independent reference values, kept in the repository (data/benchmark/EXPECTED.md says whence).
EXPECTED = REPO / "data" / "benchmark" / "expected.json"


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261121)


@pytest.fixture(scope="session")
def benchmark_model():
    from fe_core.benchmark import three_plate

    return three_plate()


@pytest.fixture(scope="session")
def expected() -> dict:
    return json.loads(EXPECTED.read_text())


# -- a small tet model file (mesh pictures, model.vtu) ------------------------------------------------
BOX_SIZE = (0.3, 0.04, 0.03)  # m: a steel cantilever along x, clamped at x = 0
BOX_TOML = """units = "SI"
mesh = "{mesh}"
[damping]
a = 10.0
b = 2e-6
[[materials]]
E = 2.06e11
nu = 0.3
rho = 7850.0
[[segments]]
set = "root"
[[segments]]
set = "middle"
[[supports]]
nodes = "clamped"
fix = ["x", "y", "z"]
[[sensors]]
name = "tip_z"
point = [0.3, 0.0, 0.03]
direction = "z"
[[sensors]]
name = "tip_y"
point = [0.3, 0.04, 0.03]
direction = [0.0, 1.0, 0.0]
[[sensors]]
name = "mid_z"
point = [0.15, 0.0, 0.03]
direction = "z"
[[excitations]]
name = "tip"
dofs = [{{ point = [0.3, 0.02, 0.03], direction = "z", weight = 1.0 }},
        {{ point = [0.3, 0.02, 0.03], direction = "y", weight = 0.5 }}]
"""


def write_box_model(folder: Path, cells=(6, 2, 1), order: int = 2) -> Path:
    """A tet10 (order 2) or tet4 cantilever box as ``<folder>/model.toml`` beside its ``box.vtu``.

    Segments ``root`` (x < 0.1 m) and ``middle`` (0.1 < x < 0.2 m); the cells beyond are
    the fixed remainder. Sets travel as 0/1 cell and point data (the VTK convention of
    :mod:`fe_core.io.mesh_file`).
    """
    import meshio

    from fe_core.tet_mesh import box_tets

    nodes, tets = box_tets(BOX_SIZE, cells, order)
    x = nodes[tets[:, :4]].mean(axis=1)[:, 0]
    sets = {"root": x < 0.1, "middle": (x > 0.1) & (x < 0.2)}
    folder.mkdir(parents=True, exist_ok=True)
    meshio.write(folder / "box.vtu", meshio.Mesh(
        nodes, [("tetra10" if order == 2 else "tetra", tets)],
        cell_data={k: [v.astype(np.int32)] for k, v in sets.items()},
        point_data={"clamped": (np.abs(nodes[:, 0]) < 1e-12).astype(np.int32)}))
    path = folder / "model.toml"
    path.write_text(BOX_TOML.format(mesh="box.vtu"))
    return path


@pytest.fixture
def box_model_file(tmp_path) -> Path:
    """``write_box_model`` in tmp_path (tet10, 72 cells)."""
    return write_box_model(tmp_path / "box")


@pytest.fixture(scope="session")
def box_model_writer():
    """``write_box_model`` itself, for module-scoped fixtures (test folders are not packages)."""
    return write_box_model
