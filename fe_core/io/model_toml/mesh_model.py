"""A model file with a mesh: materials per cell set, segments, element matrices of any registered element
family, supports (refused if they leave rigid-body motions free), assembled into a
:class:`fe_core.model.ParametricModel` (:func:`_mesh_model`)."""

from __future__ import annotations

import logging
import re
from typing import Any

import numpy as np

from ...assembly import DOFS_PER_NODE, SegmentedMatrix, assemble_free, cell_dofs, free_dof_map
from ...material import Material
from ...model import ParametricModel
from ..mesh_file import MeshFile, MeshFileError, read_mesh
from .sensors import _Locator, _point_placement, _sensors_and_excitation
from .spec import UNITS, _fixed_dofs, _get, _keys, _segment_parameters, _Spec, _tables

log = logging.getLogger(__name__)

#: Cells whose element matrices are computed and assembled at once (memory ~ 20 kB a tet10 cell).
ASSEMBLY_CHUNK = 20_000


def _mesh_model(spec: _Spec, units: str, damping: tuple[float, float]) -> ParametricModel:
    from ...elements import element_family

    length, stress, density = UNITS[units]
    placement = _point_placement(spec, mesh=True)
    mesh_name = _get(spec, spec.data, "mesh", "", (str,))
    try:
        mf = read_mesh(spec.file("mesh", mesh_name))
    except MeshFileError as exc:
        raise spec.error("mesh", str(exc)) from None
    mesh = mf.mesh
    try:
        family = element_family(mf.cell_type)
    except ValueError as exc:
        raise spec.error("mesh", f"{mf.path.name}: {exc}") from None
    options = _element_options(spec, mf.cell_type)
    n_cells, n_nodes = mesh.n_cells, mesh.n_nodes
    n_total = n_nodes * DOFS_PER_NODE

    def cell_set(name: Any, key: str) -> np.ndarray:
        if not isinstance(name, str):
            raise spec.error(key, f"must be the name of a cell set, got {name!r}")
        if name not in mesh.cell_sets:
            known = ", ".join(sorted(mesh.cell_sets)) or "none"
            raise spec.error(key, f"no cell set {name!r} of volume cells in {mf.path.name} (cell sets: {known})")
        return mesh.cell_sets[name]

    # Materials, one per cell.
    material_of = np.full(n_cells, -1)
    materials = []
    for i, tab in enumerate(_tables(spec, "materials")):
        where = f"materials[{i}]"
        _keys(spec, tab, {"cells", "E", "nu", "rho", "name"}, where)
        E, nu, rho = (_get(spec, tab, k, where, (float,)) for k in ("E", "nu", "rho"))
        try:
            materials.append(Material(E=E * stress, nu=nu, rho=rho * density))
        except ValueError as exc:
            raise spec.error(where, str(exc)) from None
        sets = tab.get("cells")
        names = [sets] if isinstance(sets, str) else sets
        if sets is None:
            cells = np.arange(n_cells)
        elif isinstance(names, list):
            cells = np.unique(np.concatenate([cell_set(n, f"{where}.cells") for n in names]))
        else:
            raise spec.error(f"{where}.cells", f"must be a cell set name or a list of them, got {sets!r}")
        clash = cells[material_of[cells] >= 0]
        if clash.size:
            raise spec.error(f"{where}.cells", f"{clash.size} cells already have the material of "
                                               f"materials[{material_of[clash[0]]}] (e.g. cell {clash[0]})")
        material_of[cells] = i
    if np.any(material_of < 0):
        raise spec.error("materials", f"{int(np.sum(material_of < 0))} cells have no material "
                                      f"(e.g. cell {int(np.flatnonzero(material_of < 0)[0])})")

    # Segments: cell sets, no overlaps; the rest is the fixed remainder.
    seg_tables = _tables(spec, "segments")
    owner = np.full(n_cells, -1)
    seg_names = []
    for i, seg in enumerate(seg_tables):
        where = f"segments[{i}]"
        _keys(spec, seg, {"set", "bounds", "name", "update", "mass_bounds"}, where)
        name = _get(spec, seg, "set", where, (str,))
        cells = cell_set(name, f"{where}.set")
        taken = cells[owner[cells] >= 0]
        if taken.size:
            other = seg_names[owner[taken[0]]]
            raise spec.error(f"{where}.set", f"segments overlap: {taken.size} cells of {name!r} are also in segment "
                                             f"{other!r} (e.g. cell {taken[0]}); a cell belongs to one segment")
        owner[cells] = i
        seg_names.append(_get(spec, seg, "name", where, (str,), name))
    mass_parameters, bounds = _segment_parameters(spec, seg_tables, seg_names)

    # Element matrices and assembly: a chunk of cells at a time, straight onto the free DOFs (a large mesh
    # never holds every cell's element matrices at once).
    coords = mesh.nodes[mesh.cells] * length
    fixed = _mesh_supports(spec, mf)
    free = free_dof_map(n_total, fixed)
    _check_rigid_body_modes(spec, mesh.nodes * length, fixed)
    position = np.full(n_total, -1, dtype=np.int32 if free.size < 2**31 else np.int64)
    position[free] = np.arange(free.size)
    cell_matrices = _CellMatrices(mf.cell_type, coords, materials, material_of, options)

    def part(cells):
        masses = []

        def blocks(kind):
            for start in range(0, cells.size, ASSEMBLY_CHUNK):
                chunk = cells[start:start + ASSEMBLY_CHUNK]
                try:
                    Ae = cell_matrices.stiffness(chunk) if kind == "K" else cell_matrices.mass(chunk)
                except (ValueError, np.linalg.LinAlgError) as exc:
                    raise spec.error("mesh", f"{mf.path.name}: {mf.cell_type} {exc}") from None
                if kind == "M":  # a rigid translation in x picks up each node's share of the mass once
                    masses.append(float(Ae[:, 0::DOFS_PER_NODE, 0::DOFS_PER_NODE].sum()))
                yield Ae, cell_dofs(mesh.cells[chunk])

        K = assemble_free(blocks("K"), n_total, free)
        M = assemble_free(blocks("M"), n_total, free)
        return K, M, float(sum(masses))

    K_parts, M_parts, masses = zip(*(part(np.flatnonzero(owner == i)) for i in range(len(seg_tables))))
    rest = np.flatnonzero(owner < 0)
    K0 = M0 = None
    rest_mass = 0.0
    if rest.size:
        K0, M0, rest_mass = part(rest)
    stiffness_segments = SegmentedMatrix.from_matrices(K_parts, K0)
    del K_parts, K0
    mass_segments = SegmentedMatrix.from_matrices(M_parts, M0)
    del M_parts, M0

    tol = _get(spec, spec.data, "point_tolerance", "", (float,), 0.01 * float(np.ptp(mesh.nodes, axis=0).max()))
    locator = _Locator(spec, mf, mesh.nodes, None, tol, placement=placement, cells=mesh.cells,
                       cell_type=mf.cell_type)

    def dof_of(node: int, component: int) -> int:
        return int(position[DOFS_PER_NODE * node + component])

    outputs, load, names, placements, exc_name, extra = _sensors_and_excitation(spec, locator, dof_of, free.size)
    mesh.nodes = mesh.nodes * length  # the model's mesh is in m
    model = ParametricModel(
        mesh=mesh, free_dofs=free,
        stiffness_segments=stiffness_segments, mass_segments=mass_segments,
        segment_names=seg_names, damping=damping, segment_masses=list(masses),
        material=materials[0] if len(materials) == 1 else None,
        formulation=options.get("formulation") if mf.cell_type == "hexahedron" else None,
        outputs=outputs, load=load, sensor_names=names, excitation_name=exc_name, n_total_dofs=n_total,
        parameter_bounds=bounds, source=str(spec.path), remainder_mass=rest_mass, placements=placements,
        cell_segment=owner,
        cell_stiffness=cell_matrices.stiffness,
        mass_parameters=mass_parameters, **extra,
    )
    log.info("%s: %d %s cells, %d nodes, %d free DOFs, %d segments, %d remainder cells", spec.path, n_cells,
             mf.cell_type, n_nodes, free.size, len(seg_names), rest.size)
    return model


class _CellMatrices:
    """Element matrices of a mesh model's cells, each with its material: ``stiffness(cells)`` and
    ``mass(cells)``, shape ``(len(cells), d, d)`` (N/m, kg); the assembly uses both and the model keeps
    ``stiffness`` for effects that stiffen or weaken a set of cells (:mod:`fe_core.closure.effects`).
    A plain object (the element family by its cell type), so a model can be pickled
    (:mod:`fe_core.io.cache`)."""

    def __init__(self, cell_type: str, coords: np.ndarray, materials: list, material_of: np.ndarray,
                 options: dict):
        self.cell_type, self.coords, self.materials = cell_type, coords, materials
        self.material_of, self.options = material_of, options

    def _matrices(self, cells, kind: str) -> np.ndarray:
        from ...elements import element_family

        family = element_family(self.cell_type)
        cells = np.asarray(cells, dtype=int)
        d = self.coords.shape[1] * DOFS_PER_NODE
        out = np.empty((cells.size, d, d))
        for i, mat in enumerate(self.materials):
            mine = self.material_of[cells] == i
            if not mine.any():
                continue
            sub = cells[mine]
            try:
                out[mine] = (family.element_stiffness(self.coords[sub], mat.D, **self.options)
                             if kind == "K" else family.element_mass(self.coords[sub], mat.rho))
            except (ValueError, np.linalg.LinAlgError) as exc:  # name the mesh's cell, not the batch's element
                msg = re.sub(r"element (\d+)", lambda m: f"cell {sub[int(m.group(1))]}", str(exc), count=1)
                raise type(exc)(msg) from None
        return out

    def stiffness(self, cells) -> np.ndarray:
        return self._matrices(cells, "K")

    def mass(self, cells) -> np.ndarray:
        return self._matrices(cells, "M")


def _element_options(spec: _Spec, cell_type: str) -> dict:
    elements = spec.data.get("elements", {})
    if not isinstance(elements, dict) or not all(isinstance(v, dict) for v in elements.values()):
        raise spec.error("elements", "must be a table of tables, e.g. [elements.hexahedron]")
    options = dict(elements.get(cell_type, {}))
    if cell_type == "hexahedron":
        options.setdefault("formulation", "incompatible")
    return options


def _mesh_supports(spec: _Spec, mf: MeshFile) -> np.ndarray:
    mesh = mf.mesh
    fixed = []
    for i, tab in enumerate(_tables(spec, "supports", required=False)):
        where = f"supports[{i}]"
        _keys(spec, tab, {"nodes", "fix", "name"}, where)
        nodes = tab.get("nodes")
        if isinstance(nodes, str):
            if nodes not in mesh.node_sets:
                known = ", ".join(sorted(mesh.node_sets)) or "none"
                raise spec.error(f"{where}.nodes", f"no node set {nodes!r} in {mf.path.name} (node sets: {known})")
            idx = mesh.node_sets[nodes]
        elif isinstance(nodes, list) and nodes and all(isinstance(n, int) and not isinstance(n, bool) for n in nodes):
            try:
                idx = np.array([mf.node_from_file(n) for n in nodes])
            except ValueError as exc:
                raise spec.error(f"{where}.nodes", str(exc)) from None
        else:
            raise spec.error(f"{where}.nodes", f"must be a node set name or a list of node indices, got {nodes!r}")
        if idx.size == 0:
            raise spec.error(f"{where}.nodes", f"node set {nodes!r} has no nodes of the volume mesh")
        fixed.append(_fixed_dofs(spec, tab, where, idx, lambda n, c: DOFS_PER_NODE * n + c))
    return np.unique(np.concatenate(fixed)) if fixed else np.zeros(0, dtype=int)


def _check_rigid_body_modes(spec: _Spec, nodes: np.ndarray, fixed: np.ndarray) -> None:
    """Refuse supports that leave rigid-body motions free, naming them.

    A rigid motion ``u = t + w x (p - c)`` of the whole body is a null vector of
    the constrained stiffness exactly when it vanishes on every fixed DOF, so the
    free rigid motions are the null space of the rigid-body basis restricted to
    the fixed DOFs (6 columns: translations x, y, z, rotations about x, y, z
    through the centroid).
    """
    c = nodes.mean(axis=0)
    p = nodes - c
    n = len(nodes)
    R = np.zeros((n * 3, 6))
    for k in range(3):
        R[k::3, k] = 1.0
    scale = max(float(np.abs(p).max()), 1e-300)
    # rotation about x: (0, -z, y); about y: (z, 0, -x); about z: (-y, x, 0); scaled to unit size
    R[1::3, 3], R[2::3, 3] = -p[:, 2] / scale, p[:, 1] / scale
    R[0::3, 4], R[2::3, 4] = p[:, 2] / scale, -p[:, 0] / scale
    R[0::3, 5], R[1::3, 5] = -p[:, 1] / scale, p[:, 0] / scale
    Rc = R[fixed]
    s = np.linalg.svd(Rc, compute_uv=False) if len(fixed) else np.zeros(0)
    rank = int(np.sum(s > 1e-8 * max(1.0, s.max(initial=0.0))))
    if rank == 6:
        return
    _, _, vt = np.linalg.svd(Rc if len(fixed) else np.zeros((1, 6)))
    null = vt[rank:]
    labels = ["translation x", "translation y", "translation z", "rotation about x", "rotation about y",
              "rotation about z"]
    free = []
    for v in null:
        k = int(np.argmax(np.abs(v)))
        pure = abs(v[k]) > 0.999
        free.append(labels[k] if pure else "a combination of " + ", ".join(
            labels[j] for j in np.flatnonzero(np.abs(v) > 0.05)))
    raise spec.error("supports", f"the structure is not restrained: {6 - rank} rigid-body mode(s) are free "
                                 f"({'; '.join(free)}); fix more directions or nodes")
