"""The solid structures of the held-out cases: geometry, meshes (the tool's and the data's), segments, supports,
sensors and excitation.

Each structure is a plain dict (:func:`structure`):

* ``model_nodes``, ``model_cells``, ``model_cell_type``: the mesh the tool reads (``tetra10`` in VTK node order,
  meshed by gmsh, or ``hexahedron``); ``data_nodes``, ``data_cells``, ``data_element``: the independent mesh
  scikit-fem assembles for the measured data (straight tet4 corners with P2 elements, or hexahedra with Q2;
  :func:`on_model_mesh`: the tool's own cells);
* ``segment_of(centroids) -> index`` (-1: in no segment), ``segments`` (names), ``support(points) -> bool``,
  ``sensors`` and ``excitation`` as ``(name, point, direction)`` (points on the surface; each mesh takes its
  nearest node), the material, the damping target, the size, the mass-layer region and the joint.

Structures (all SI):

* ``holed_plate``: steel 0.50 x 0.32 x 0.008 m, two holes, clamped along x = 0; tet10 (gmsh, 0.02 m) for the
  tool, P2 on a gmsh mesh of half that size for the data; six segments (x thirds, y halves).
* ``ribbed_panel``: aluminium 0.48 x 0.32 x 0.008 m with two 30 x 8 mm blade ribs underneath along x, bolted
  at four corner holes (the holes' faces held); six segments (the plate's quadrants, each rib).
* ``frame``: a steel table frame of solid members (four 30 x 30 mm legs, 0.5 m, feet clamped; a ring of four
  30 x 30 mm beams on top, 0.6 x 0.42 m), hexahedra of 10 mm: the tool's hex8 with incompatible modes, the
  data's scikit-fem Q2 (27-node) on the same cells; six segments (the leg pairs, the four beams).
* ``angle_plate`` (held-out only): a steel angle of 8 mm plates, 0.36 m long, a base 0.24 m deep clamped along
  its back edge and an upright 0.20 m high with a 70 mm hole; six segments (the base's halves, the upright's
  quarters).

The deck (``channel_deck``) is :mod:`benchmarks.make.cases.deck`.
"""

from __future__ import annotations

import numpy as np

STEEL = (2.1e11, 0.3, 7850.0)
ALUMINIUM = (7.0e10, 0.33, 2700.0)
#: VTK's tet10 edges after the four corners (fe_core.elements.tet10's order).
TET10_EDGES = ((0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3))


# -- gmsh ---------------------------------------------------------------------------------------------------
def gmsh_mesh(build, size: float, order: int, per_circle: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Mesh the OCC geometry ``build(occ)`` makes: nodes (n, 3) and cells (tet4, or tet10 in VTK order).

    Only nodes of volume cells are kept (renumbered in gmsh's order), so the tool reads the same numbering."""
    import gmsh

    gmsh.initialize(["-noenv"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add("solid")
        build(gmsh.model.occ)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size / 3.0)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", per_circle)
        gmsh.option.setNumber("Mesh.RandomSeed", 1)
        gmsh.model.mesh.generate(3)
        if order == 2:
            gmsh.option.setNumber("Mesh.HighOrderOptimize", 1)
            gmsh.model.mesh.setOrder(2)
        tags, xyz, _ = gmsh.model.mesh.getNodes()
        types, _, conn = gmsh.model.mesh.getElements(3)
    finally:
        gmsh.finalize()
    per = 4 if order == 1 else 10
    (k,) = [i for i, t in enumerate(types) if t == (4 if order == 1 else 11)]
    index = np.full(int(tags.max()) + 1, -1)
    index[tags.astype(np.int64)] = np.arange(tags.size)
    cells = index[conn[k].astype(np.int64)].reshape(-1, per)
    xyz = xyz.reshape(-1, 3)
    used = np.unique(cells)
    renumber = np.full(xyz.shape[0], -1)
    renumber[used] = np.arange(used.size)
    nodes, cells = xyz[used], renumber[cells]
    if order == 2:
        cells = _vtk_tet10(nodes, cells)
    return nodes, _positive(nodes, cells)


def _vtk_tet10(nodes, cells) -> np.ndarray:
    """Reorder each tet10's edge nodes to VTK's (:data:`TET10_EDGES`): the edge node nearest each edge's
    midpoint (gmsh and VTK differ in the last two; found by geometry, not assumed)."""
    corner = nodes[cells[:, :4]]
    mids = nodes[cells[:, 4:]]                                     # (c, 6, 3)
    out = cells.copy()
    for j, (a, b) in enumerate(TET10_EDGES):
        target = (corner[:, a] + corner[:, b]) / 2
        pick = np.argmin(np.linalg.norm(mids - target[:, None], axis=2), axis=1)
        out[:, 4 + j] = cells[np.arange(cells.shape[0]), 4 + pick]
    if np.any(np.sort(out[:, 4:], axis=1) != np.sort(cells[:, 4:], axis=1)):
        raise RuntimeError("tet10 edge nodes could not be matched to their edges")
    return out


def _positive(nodes, cells) -> np.ndarray:
    """Cells with positive volume (swap corners 1 and 2, and the edge nodes with them, where negative)."""
    if cells.shape[1] == 8:
        return cells
    a, b, c, d = (nodes[cells[:, m]] for m in range(4))
    neg = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    if not neg.any():
        return cells
    cells = cells.copy()
    swap = [0, 2, 1, 3] + ([6, 5, 4, 7, 9, 8] if cells.shape[1] == 10 else [])  # VTK edges under 1 <-> 2
    cells[neg] = cells[neg][:, swap]
    return cells


def corner_centroids(nodes, cells) -> np.ndarray:
    k = 4 if cells.shape[1] in (4, 10) else 8
    return nodes[cells[:, :k]].mean(axis=1)


# -- structures ---------------------------------------------------------------------------------------------
def _holed_plate(occ):
    box = occ.addBox(0, 0, 0, 0.5, 0.32, 0.008)
    holes = [occ.addCylinder(0.17, 0.15, -0.001, 0, 0, 0.01, 0.045), occ.addCylinder(0.36, 0.21, -0.001, 0, 0, 0.01, 0.03)]
    occ.cut([(3, box)], [(3, h) for h in holes])


def holed_plate() -> dict:
    def segment_of(c):
        return np.minimum((c[:, 0] / (0.5 / 3)).astype(int), 2) * 2 + (c[:, 1] > 0.16)

    top = 0.008
    sensors = [(f"z {x:g} {y:g}", (x, y, top), (0.0, 0.0, 1.0)) for x, y in
               ((0.12, 0.04), (0.12, 0.29), (0.27, 0.03), (0.26, 0.29), (0.40, 0.08), (0.43, 0.30), (0.495, 0.02),
                (0.495, 0.30))]
    return {"name": "holed_plate", "build": _holed_plate, "sizes": (0.02, 0.01), "material": STEEL,
            "segments": ["root_low", "root_high", "mid_low", "mid_high", "tip_low", "tip_high"],
            "segment_of": segment_of, "support": lambda p: np.isclose(p[:, 0], 0.0, atol=1e-7),
            "support_text": "clamped along x = 0 (every node of that face held in x, y, z)",
            "sensors": sensors, "excitation": ("hammer", (0.47, 0.12, top), (0.0, 0.0, 1.0)), "zeta": 0.015,
            "layer": (0.25, 0.42, 0.05, 0.27, -1.0, 1.0),
            "description": "steel plate 0.50 x 0.32 x 0.008 m with holes of 90 and 60 mm, clamped along x = 0"}


PANEL = (0.48, 0.32, 0.008)   # plate x, y, thickness
RIB_Y, RIB_T, RIB_H = (0.102, 0.21), 0.008, 0.03   # each rib's y range starts at RIB_Y


def _ribbed_panel(occ):
    plate = occ.addBox(0, 0, 0, *PANEL)
    ribs = [occ.addBox(0, y, -RIB_H, PANEL[0], RIB_T, RIB_H) for y in RIB_Y]
    holes = [occ.addCylinder(x, y, -0.001, 0, 0, PANEL[2] + 0.002, 0.006) for x in (0.03, PANEL[0] - 0.03)
             for y in (0.03, PANEL[1] - 0.03)]
    cut, _ = occ.cut([(3, plate)], [(3, h) for h in holes])
    occ.fragment(cut, [(3, r) for r in ribs])


def _ribbed_support(p):
    near = np.zeros(len(p), bool)
    for x in (0.03, PANEL[0] - 0.03):
        for y in (0.03, PANEL[1] - 0.03):
            r = np.hypot(p[:, 0] - x, p[:, 1] - y)
            near |= np.abs(r - 0.006) < 4e-4
    return near & (p[:, 2] > -1e-7)


def ribbed_panel() -> dict:
    def segment_of(c):
        seg = (c[:, 0] > PANEL[0] / 2) * 2 + (c[:, 1] > PANEL[1] / 2)
        seg = np.where(c[:, 2] < 0, np.where(c[:, 1] < PANEL[1] / 2, 4, 5), seg)
        return seg

    top = PANEL[2]
    sensors = [(f"z {x:g} {y:g}", (x, y, top), (0.0, 0.0, 1.0)) for x, y in
               ((0.12, 0.06), (0.11, 0.26), (0.24, 0.16), (0.25, 0.02), (0.36, 0.07), (0.37, 0.27), (0.47, 0.17))]
    sensors.append(("rib y 0.24", (0.24, RIB_Y[0], -0.028), (0.0, -1.0, 0.0)))
    joint = {"interface": (2, 0.0), "side": lambda c: c[:, 2] < 0, "region": lambda p: (
        (p[:, 0] > 0.16 - 1e-9) & (p[:, 0] < 0.36 + 1e-9) & (p[:, 1] > RIB_Y[0] - 1e-9)
        & (p[:, 1] < RIB_Y[0] + RIB_T + 1e-9)),
        "area": 0.2 * RIB_T, "description": "rib A's bond to the plate over x 0.16-0.36 m made compliant"}
    return {"name": "ribbed_panel", "build": _ribbed_panel, "sizes": (0.022, 0.011), "material": ALUMINIUM,
            "segments": ["plate_1", "plate_2", "plate_3", "plate_4", "rib_a", "rib_b"], "segment_of": segment_of,
            "support": _ribbed_support, "support_text": "bolted at four corner holes (the holes' faces held)",
            "sensors": sensors, "excitation": ("hammer", (0.34, 0.29, top), (0.0, 0.0, 1.0)), "zeta": 0.012,
            "layer": (0.14, 0.34, 0.08, 0.26, 0.0, 1.0), "joint": joint,
            "description": "aluminium plate 0.48 x 0.32 x 0.008 m with two 30 x 8 mm ribs, bolted at four corners"}


ANGLE = (0.36, 0.24, 0.20, 0.008)   # length (x), base depth (y), upright height (z), thickness


def _angle_plate(occ):
    length, depth, height, t = ANGLE
    base = occ.addBox(0, 0, 0, length, depth, t)
    upright = occ.addBox(0, 0, t, length, t, height - t)
    hole = occ.addCylinder(0.25, -0.001, 0.12, 0, t + 0.002, 0, 0.035)
    cut, _ = occ.cut([(3, upright)], [(3, hole)])
    occ.fragment([(3, base)], cut)


def angle_plate() -> dict:
    length, depth, height, t = ANGLE

    def segment_of(c):
        upright = (c[:, 2] > t) & (c[:, 1] < t)
        base = (c[:, 0] > length / 2).astype(int)
        up = 2 + 2 * (c[:, 2] > height / 2) + (c[:, 0] > length / 2)
        return np.where(upright, up, base)

    sensors = [("base z 0.08 0.12", (0.08, 0.12, t), (0.0, 0.0, 1.0)), ("base z 0.30 0.10", (0.30, 0.10, t),
                                                                         (0.0, 0.0, 1.0)),
               ("base z 0.18 0.05", (0.18, 0.05, t), (0.0, 0.0, 1.0)), ("upright y 0.06 0.10", (0.06, 0.0, 0.10),
                                                                       (0.0, -1.0, 0.0)),
               ("upright y 0.34 0.06", (0.34, 0.0, 0.06), (0.0, -1.0, 0.0)), ("top y 0.0", (0.0, 0.0, height),
                                                                           (0.0, -1.0, 0.0)),
               ("top y 0.18", (0.18, 0.0, height), (0.0, -1.0, 0.0)), ("top x 0.36", (length, 0.004, height),
                                                                     (1.0, 0.0, 0.0))]
    return {"name": "angle_plate", "build": _angle_plate, "sizes": (0.02, 0.01), "material": STEEL,
            "segments": ["base_left", "base_right", "upright_low_left", "upright_low_right", "upright_high_left",
                         "upright_high_right"], "segment_of": segment_of,
            "support": lambda p: np.isclose(p[:, 1], depth, atol=1e-7),
            "support_text": f"the base clamped along its back edge y = {depth} m", "sensors": sensors,
            "excitation": ("hammer", (0.33, 0.0, 0.19), (0.3, -0.9, 0.3)), "zeta": 0.015,
            "layer": (0.1, 0.3, -1.0, 1.0, 0.05, 0.16),
            "description": f"a steel angle of 8 mm plates, {length} m long, base {depth} m deep clamped at its back "
                           f"edge, upright {height} m with a 70 mm hole"}


# -- the hexahedral frame -------------------------------------------------------------------------------------
FRAME_H = 0.01             # cell size
FRAME_N = 3                # cells across a member (30 mm)
FRAME = (0.6, 0.42, 0.5)   # outer x, y extent and the legs' height


def _frame_active(i, j, k):
    nx, ny, nz, m = round(FRAME[0] / FRAME_H), round(FRAME[1] / FRAME_H), round(FRAME[2] / FRAME_H), FRAME_N
    leg = (i < m or i >= nx - m) and (j < m or j >= ny - m)
    ring = k >= nz and (i < m or i >= nx - m or j < m or j >= ny - m)
    return leg or ring


def hex_grid(xs, ys, zs, active) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and hexahedra (VTK order) of the active boxes of a grid."""
    shape = (len(xs), len(ys), len(zs))
    index = np.arange(np.prod(shape)).reshape(shape)
    grid = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    hexes = []
    for i in range(len(xs) - 1):
        for j in range(len(ys) - 1):
            for k in range(len(zs) - 1):
                if active(i, j, k):
                    hexes.append([index[i, j, k], index[i + 1, j, k], index[i + 1, j + 1, k], index[i, j + 1, k],
                                  index[i, j, k + 1], index[i + 1, j, k + 1], index[i + 1, j + 1, k + 1],
                                  index[i, j + 1, k + 1]])
    hexes = np.array(hexes)
    used = np.unique(hexes)
    renumber = np.full(grid.shape[0], -1)
    renumber[used] = np.arange(used.size)
    return grid[used], renumber[hexes]


def frame_mesh() -> tuple[np.ndarray, np.ndarray]:
    nx, ny, nz = round(FRAME[0] / FRAME_H), round(FRAME[1] / FRAME_H), round(FRAME[2] / FRAME_H) + FRAME_N
    return hex_grid(np.arange(nx + 1) * FRAME_H, np.arange(ny + 1) * FRAME_H, np.arange(nz + 1) * FRAME_H,
                    _frame_active)


def frame() -> dict:
    x, y, z = FRAME
    w = FRAME_N * FRAME_H
    top = z + w

    def segment_of(c):
        leg = c[:, 2] < z
        front = c[:, 1] < y / 2
        along_x = (c[:, 1] < w) | (c[:, 1] > y - w)
        beam = np.where(along_x, np.where(front, 2, 3), np.where(c[:, 0] < x / 2, 4, 5))
        return np.where(leg, np.where(front, 0, 1), beam)

    sensors = [("corner x", (x, 0.0, top), (1.0, 0.0, 0.0)), ("corner y", (x, 0.0, top - 0.01), (0.0, -1.0, 0.0)),
               ("front beam z", (0.3, 0.0, top), (0.0, 0.0, 1.0)), ("back beam z", (0.31, y, top), (0.0, 0.0, 1.0)),
               ("left beam x", (0.0, 0.21, top - 0.01), (-1.0, 0.0, 0.0)), ("right beam z", (x, 0.2, top),
                                                                             (0.0, 0.0, 1.0)),
               ("leg mid y", (0.0, 0.0, 0.25), (0.0, -1.0, 0.0)), ("back leg mid x", (x, y, 0.24), (1.0, 0.0, 0.0))]
    nz = round(z / FRAME_H)
    joint = {"interface": (2, z), "side": lambda c: c[:, 2] > z, "region": lambda p: (
        (p[:, 0] < w + 1e-9) & (p[:, 1] < w + 1e-9)), "area": w**2,
        "description": f"the front-left leg's top (z = {z} m, {nz} cells up) joined to the ring by a compliant "
                       "interface"}
    return {"name": "frame", "build": None, "mesh": frame_mesh, "material": STEEL,
            "segments": ["legs_front", "legs_back", "beam_front", "beam_back", "beam_left", "beam_right"],
            "segment_of": segment_of, "support": lambda p: np.isclose(p[:, 2], 0.0, atol=1e-9),
            "support_text": "four feet clamped (z = 0)", "sensors": sensors,
            "excitation": ("hammer", (x, y, top - 0.01), (0.6, 0.7, 0.4)), "zeta": 0.012,
            "layer": (0.2, 0.62, 0.3, 0.43, 0.0, 1.0), "joint": joint,
            "description": "steel table frame of 30 x 30 mm solid members, 0.6 x 0.4 x 0.53 m, feet clamped"}


def tiny_bar() -> dict:
    """A steel cantilever 0.3 x 0.01 x 0.01 m of 10 mm hexahedra (30 cells): the generator's test, in no set."""
    def segment_of(c):
        return (c[:, 0] > 0.15).astype(int)

    mesh = lambda: hex_grid(np.arange(31) * 0.01, np.arange(2) * 0.01, np.arange(2) * 0.01, lambda i, j, k: True)
    return {"name": "tiny_bar", "build": None, "mesh": mesh, "material": STEEL, "segments": ["root", "tip"],
            "segment_of": segment_of, "support": lambda p: np.isclose(p[:, 0], 0.0, atol=1e-9),
            "support_text": "clamped at x = 0",
            "sensors": [("tip z", (0.3, 0.0, 0.01), (0.0, 0.0, 1.0)), ("mid z", (0.15, 0.0, 0.01), (0.0, 0.0, 1.0)),
                        ("tip y", (0.3, 0.0, 0.0), (0.0, -1.0, 0.0))],
            "excitation": ("hammer", (0.29, 0.01, 0.01), (0.0, 0.6, 0.8)), "zeta": 0.02,
            "layer": (0.05, 0.25, -1.0, 1.0, -1.0, 1.0), "description": "a steel cantilever 0.3 x 0.01 x 0.01 m"}


def _tiny_block(occ):
    occ.addBox(0, 0, 0, 0.2, 0.06, 0.01)


def tiny_block() -> dict:
    """A steel block 0.2 x 0.06 x 0.01 m of tet10 (gmsh, 0.02 m), clamped at x = 0: the test of data on the tool's
    tetrahedral mesh, in no set."""
    def segment_of(c):
        return (c[:, 0] > 0.1).astype(int)

    return {"name": "tiny_block", "build": _tiny_block, "sizes": (0.02, 0.01), "material": STEEL,
            "segments": ["root", "tip"], "segment_of": segment_of,
            "support": lambda p: np.isclose(p[:, 0], 0.0, atol=1e-7), "support_text": "clamped at x = 0",
            "sensors": [("tip z", (0.2, 0.0, 0.01), (0.0, 0.0, 1.0)), ("mid z", (0.1, 0.06, 0.01), (0.0, 0.0, 1.0))],
            "excitation": ("hammer", (0.19, 0.05, 0.01), (0.0, 0.0, 1.0)), "zeta": 0.02,
            "layer": (0.05, 0.15, -1.0, 1.0, -1.0, 1.0), "description": "a steel block 0.2 x 0.06 x 0.01 m"}


SOLIDS = {"holed_plate": holed_plate, "ribbed_panel": ribbed_panel, "frame": frame, "angle_plate": angle_plate,
          "tiny_bar": tiny_bar, "tiny_block": tiny_block}


def structure(name: str) -> dict:
    """The structure ``name`` with its two meshes (gmsh runs here; the frame is a grid)."""
    s = SOLIDS[name]()
    if s["build"] is None:
        s["model_nodes"], s["model_cells"] = s["mesh"]()
        s["model_cell_type"] = "hexahedron"
        s["data_nodes"], s["data_cells"], s["data_element"] = s["model_nodes"], s["model_cells"], "Q2"
    else:
        coarse, fine = s["sizes"]
        s["model_nodes"], s["model_cells"] = gmsh_mesh(s["build"], coarse, 2)
        s["model_cell_type"] = "tetra10"
        s["data_nodes"], s["data_cells"] = gmsh_mesh(s["build"], fine, 1)
        s["data_element"] = "P2"
    s["size_m"] = float(np.ptp(s["model_nodes"], axis=0).max())
    return s


def on_model_mesh(s: dict) -> dict:
    """``s`` with its data on the tool's own mesh: scikit-fem's P2 on the tet10 cells' corners (the same
    discretisation as the tool's, assembled independently; the edges straight where gmsh bent the tool's onto a
    hole), or the frame's Q2 on its cells as before (already the tool's cells).

    The sets of finer data meshes carry the tool mesh's own error (10-30 % of the FRF at the true factors on the
    development set); data on the tool's mesh judge the noise and effect rules without it."""
    if s["model_cell_type"] != "tetra10":
        return s
    corners = np.unique(s["model_cells"][:, :4])
    renumber = np.full(s["model_nodes"].shape[0], -1)
    renumber[corners] = np.arange(corners.size)
    return {**s, "data_nodes": s["model_nodes"][corners], "data_cells": renumber[s["model_cells"][:, :4]],
            "data_element": "P2"}
