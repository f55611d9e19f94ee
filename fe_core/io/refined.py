"""A model file of the same structure on its once-refined mesh (ten-node tetrahedra, :func:`fe_core.refine.refine_tet10`;
eight-node hexahedra, :func:`fe_core.refine.refine_hex8`).

``write_refined(model_toml, out_dir)`` writes ``out_dir/refined.vtu`` and ``out_dir/model.toml``: the model file's text
with its ``mesh`` pointing to the refined mesh, everything else as written (materials, segments by cell set,
supports, sensors, damping). The refined mesh keeps the coarse file's node numbers (a support or sensor given by
node number means the same node), its new nodes after them; cell sets and node sets are written as 0/1 cell and
point data, which :func:`fe_core.io.mesh_file.read_mesh` reads back as sets. A ``point`` placed at its nearest node
(``point_placement = "nearest"``, the default) becomes that coarse node (``node = N``): the refined mesh has nodes
nearer the point, and a sensor or hammer moved by part of an element would change the FRF by more than the mesh
does (on the generator's block, 9-15 % rms of ln|H| against 0.1-0.3 % from the mesh at the resonances); the
refined model is to differ from the model by its discretisation alone.
"""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import numpy as np

from ..refine import refine_hex8, refine_tet10
from .mesh_file import read_mesh
from .model_toml.spec import ModelFileError, _load

__all__ = ["write_refined", "refined_model", "RefinementError", "MAX_FINE_DOFS"]

_MESH_KEY = re.compile(r"""^(?P<key>[ \t]*mesh[ \t]*=[ \t]*)(?P<q>["']).*?(?P=q)""", re.MULTILINE)
_POINT_KEY = re.compile(r"^(?P<indent>[ \t]*)point[ \t]*=[ \t]*(?P<value>\[[^\]\n]*\])", re.MULTILINE)


#: The cell types refined, each by its own splitting (:mod:`fe_core.refine`).
_REFINE = {"tetra10": refine_tet10, "hexahedron": refine_hex8}


class RefinementError(ValueError):
    """A model that cannot be refined (not a mesh model, cells other than ten-node tetrahedra or eight-node
    hexahedra); the message names the file."""


def write_refined(model_toml: str | Path, out_dir: str | Path) -> Path:
    """Write the model file on the once-refined mesh into ``out_dir``; returns its ``model.toml``.

    Raises :class:`RefinementError` for a model file without a mesh (matrices, a solver deck) or a mesh of other
    cells than ``tetra10`` or ``hexahedron``; an existing refinement of the same model file (same text and mesh) is kept.
    """
    import meshio

    model_toml = Path(model_toml).resolve()
    out_dir = Path(out_dir)
    spec = _load(model_toml)
    if "mesh" not in spec.data:
        raise RefinementError(f"{model_toml}: the model has no mesh file (matrices or a solver deck): its own "
                              "discretisation error is not measured by refinement")
    mesh_path = spec.file("mesh", spec.data["mesh"])
    text = model_toml.read_text()
    stamp = {"model": str(model_toml), "model_text": text, "mesh_bytes": mesh_path.stat().st_size,
             "mesh_mtime_ns": mesh_path.stat().st_mtime_ns}
    target, vtu, record = out_dir / "model.toml", out_dir / "refined.vtu", out_dir / "refined.json"
    if target.is_file() and vtu.is_file() and record.is_file() and json.loads(record.read_text()) == stamp:
        return target
    mf = read_mesh(mesh_path)
    if mf.cell_type not in _REFINE:
        raise RefinementError(f"{model_toml}: its mesh {mesh_path.name} has {mf.cell_type} cells; refinement is "
                              "implemented for ten-node tetrahedra (tetra10) and eight-node hexahedra (hexahedron)")
    coarse = mf.mesh
    fine = _REFINE[mf.cell_type](coarse)
    n_coarse, n_file = coarse.n_nodes, int(mf.file_node.max()) + 1
    file_index = np.concatenate([mf.file_node, n_file + np.arange(fine.n_nodes - n_coarse)])
    points = np.zeros((n_file + fine.n_nodes - n_coarse, 3))
    points[:n_file] = coarse.nodes[0]  # gaps (file nodes in no volume cell) hold a used node's place: read drops them
    points[file_index] = fine.nodes
    cell_data, point_data = {}, {}
    for name, idx in fine.cell_sets.items():
        flag = np.zeros(fine.n_cells, np.int8)
        flag[idx] = 1
        cell_data[name] = [flag]
    for name, idx in fine.node_sets.items():
        flag = np.zeros(len(points), np.int8)
        flag[file_index[idx]] = 1
        point_data[name] = flag
    out_dir.mkdir(parents=True, exist_ok=True)
    meshio.write(vtu, meshio.Mesh(points, [(mf.cell_type, file_index[fine.cells])], cell_data=cell_data,
                                  point_data=point_data))
    new_text, n = _MESH_KEY.subn(lambda m: f'{m["key"]}"{vtu.resolve().as_posix()}"', text, count=1)
    if spec.data.get("point_placement", "nearest") == "nearest":
        def at_node(m):
            point = np.asarray(tomllib.loads(f"p = {m['value']}")["p"], float)
            i = int(np.argmin(np.linalg.norm(coarse.nodes - point, axis=1)))
            return f"{m['indent']}node = {int(mf.file_node[i])}  # point = {m['value']}: its nearest node"
        new_text = _POINT_KEY.sub(at_node, new_text)
    if n != 1:
        raise ModelFileError(f"{model_toml}: no top-level 'mesh = \"...\"' line to point at the refined mesh")
    target.write_text(f"# {model_toml} on its once-refined mesh (python -m flows.model_error; fe_core.io.refined)\n"
                      + new_text)
    record.write_text(json.dumps(stamp))
    return target


#: The most free DOFs a refined model may have for :func:`refined_model` to build it (eight times the model's, about:
#: a model of up to ~50,000 DOFs); its assembly and one response then take under a minute and 2-3 GB.
MAX_FINE_DOFS = 420_000

_MEMO: dict = {}


def refined_model(model, max_dofs: int = MAX_FINE_DOFS):
    """The model (a :class:`fe_core.model.ParametricModel` read from a model file) on its once-refined mesh, read
    and assembled, and None with the reason when it cannot be: no model file, cells that are not refined (:data:`_REFINE`),
    more than ``max_dofs`` free DOFs expected (``CHILDREN_PER_CELL`` times the model's). Built once per model file
    and text in a process (the update's evidence and the closure share it); the file is written to a temporary
    folder and read back as any model file is."""
    import tempfile

    from ..refine import CHILDREN_PER_CELL
    from .model_toml import read_model_toml

    source = getattr(model, "source", None)
    if not source or not str(source).endswith(".toml") or not Path(source).is_file():
        return None, "the model has no model file to refine"
    expected = CHILDREN_PER_CELL * int(model.n_dofs)
    if expected > max_dofs:
        return None, (f"its refined mesh would have about {expected:,} free DOFs (more than {max_dofs:,}): "
                      "too large to build beside the model")
    key = (str(Path(source).resolve()), Path(source).read_text())
    if key in _MEMO:
        return _MEMO[key]
    try:
        with tempfile.TemporaryDirectory(prefix="refined-") as tmp:
            fine = read_model_toml(write_refined(source, tmp))
        out = (fine, "")
    except RefinementError as exc:
        out = (None, str(exc))
    _MEMO.clear()   # one refined model held at a time
    _MEMO[key] = out
    return out
