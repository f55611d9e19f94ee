"""The large example's structure: a steel ribbed panel meshed in tet10 by gmsh (OpenCASCADE kernel).

A plate ``LX x LY x T`` on ``z = 0..T`` with two long ribs (along x, at ``y = RIB_Y``) and one cross rib
(along y, at ``x = RIB_X``) standing on its top face, four bolt holes at the corners (the support) and two
lightening holes. Nine volume groups are the segments: the plate in 3 x 2 zones and the three ribs (the cross
rib owns the two blocks where it crosses the long ribs). Surface group ``bolt_holes``: the four holes'
faces. Units: m.

Every sensor and excitation point of the model file is a geometry point fragmented into the faces it lies on,
so it is a mesh node at every size (the model file finds it at distance 0). Second-order nodes sit at the
straight edges' midpoints (``Mesh.SecondOrderLinear``): the cells are straight-sided, so the element
integrals of ``fe_core`` and of scikit-fem are both exact and the two assemblies agree to round-off.
The mesh is deterministic: one thread, fixed algorithm and seed.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

LX, LY, T = 0.6, 0.4, 0.012  # plate, m
RIB_T, RIB_H = 0.010, 0.045  # rib thickness and height above the plate, m
RIB_Y = (0.13, 0.27)  # long ribs' centre lines (y), m
RIB_X = 0.30  # cross rib's centre line (x), m
ZONES_X, ZONE_Y = (0.2, 0.4), 0.2  # the plate's zone boundaries, m
BOLT_R = 0.0065
BOLTS = ((0.03, 0.03), (LX - 0.03, 0.03), (0.03, LY - 0.03), (LX - 0.03, LY - 0.03))
LIGHTENING_R = 0.035
LIGHTENING = ((0.12, 0.2), (0.48, 0.2))
#: Elements per full circle on the holes (gmsh's MeshSizeFromCurvature).
PER_CIRCLE = 10

SEGMENTS = ("plate_left_front", "plate_left_back", "plate_mid_front", "plate_mid_back",
            "plate_right_front", "plate_right_back", "rib_front", "rib_back", "rib_cross")
#: Volume of the CAD model, m^3 (plate minus holes, ribs, crossings counted once).
VOLUME = (LX * LY * T - np.pi * T * (len(BOLTS) * BOLT_R**2 + len(LIGHTENING) * LIGHTENING_R**2)
          + RIB_T * RIB_H * (2 * LX + LY - 2 * RIB_T))

#: (mesh size h [m], 3 x nodes) of this geometry's meshes (PER_CIRCLE = 10), measured once: the free DOFs are
#: these less the bolt holes' fixed nodes' (under 0.5 %). :func:`size_for_dofs` interpolates them.
CALIBRATION = ((0.02, 58_062), (0.012, 126_393), (0.011, 151_611), (0.008, 256_182), (0.0062, 507_810),
               (0.005, 771_651), (0.0044, 1_112_550))

def segment_of(centre) -> str:
    """The segment of a volume piece from its centre of mass (m)."""
    x, y, z = centre
    if z > T:
        if abs(x - RIB_X) < RIB_T / 2 + 1e-9:
            return "rib_cross"
        return "rib_front" if y < LY / 2 else "rib_back"
    column = "left" if x < ZONES_X[0] else "mid" if x < ZONES_X[1] else "right"
    return f"plate_{column}_{'front' if y < ZONE_Y else 'back'}"


def size_for_dofs(dofs: float) -> float:
    """The mesh size h (m) at which the panel has about ``dofs`` free DOFs.

    Linear in ``log h`` against ``log DOFs`` between the points of :data:`CALIBRATION`, extended with the end
    segments' slopes beyond them.
    """
    h, n = (np.log(np.array(v, float)) for v in zip(*CALIBRATION))
    x = np.log(float(dofs))
    k = int(np.clip(np.searchsorted(n, x) - 1, 0, n.size - 2))
    return float(np.exp(h[k] + (x - n[k]) * (h[k + 1] - h[k]) / (n[k + 1] - n[k])))

def build(out: Path, size: float, points: np.ndarray, per_circle: int = PER_CIRCLE) -> dict:
    """Build, mesh (tet10) and write the panel.

    Parameters
    ----------
    out : Path
        The ``.msh`` file written (MSH 4.1 binary, only the physical groups' elements).
    size : float
        Target element size, m.
    points : ndarray, shape (n, 3), m
        Sensor and excitation points: each becomes a mesh node.
    per_circle : int
        Elements per full circle on the holes.

    Returns
    -------
    dict
        ``nodes`` (in volume cells), ``cells`` (tet10), ``size``.
    """
    import gmsh

    gmsh.initialize(["-noenv"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)  # deterministic
        gmsh.model.add("panel")
        occ = gmsh.model.occ
        xs = (0.0, *ZONES_X, LX)
        plate = []
        for i in range(3):
            for y0, y1 in ((0.0, ZONE_Y), (ZONE_Y, LY)):
                plate.append((3, occ.addBox(xs[i], y0, 0.0, xs[i + 1] - xs[i], y1 - y0, T)))
        holes = [(3, occ.addCylinder(x, y, -0.001, 0.0, 0.0, T + 0.002, r))
                 for r, centres in ((BOLT_R, BOLTS), (LIGHTENING_R, LIGHTENING)) for x, y in centres]
        plate, _ = occ.cut(plate, holes)
        ribs = [(3, occ.addBox(0.0, y - RIB_T / 2, T, LX, RIB_T, RIB_H)) for y in RIB_Y]
        ribs.append((3, occ.addBox(RIB_X - RIB_T / 2, 0.0, T, RIB_T, LY, RIB_H)))
        marks = [(0, occ.addPoint(*p)) for p in np.asarray(points, float)]
        occ.fragment(plate + ribs, marks)  # conforming interfaces; the points become vertices
        occ.synchronize()

        groups: dict[str, list[int]] = {name: [] for name in SEGMENTS}
        for dim, tag in gmsh.model.getEntities(3):
            groups[segment_of(occ.getCenterOfMass(dim, tag))].append(tag)
        for name in SEGMENTS:
            if not groups[name]:
                raise RuntimeError(f"segment {name!r} has no volume")
            gmsh.model.addPhysicalGroup(3, groups[name], name=name)
        bolt = [tag for dim, tag in gmsh.model.getEntities(2) if gmsh.model.getType(dim, tag) == "Cylinder"
                and _near_bolt(gmsh.model.getBoundingBox(dim, tag))]
        if len(bolt) < len(BOLTS):
            raise RuntimeError(f"found {len(bolt)} bolt-hole faces, expected at least {len(BOLTS)}")
        gmsh.model.addPhysicalGroup(2, bolt, name="bolt_holes")

        for key, value in (("Mesh.MeshSizeMax", size), ("Mesh.MeshSizeMin", 0.0),
                           ("Mesh.MeshSizeFromCurvature", per_circle), ("Mesh.MeshSizeExtendFromBoundary", 1),
                           ("Mesh.Algorithm", 6), ("Mesh.Algorithm3D", 1), ("Mesh.RandomSeed", 1),
                           ("Mesh.MaxNumThreads1D", 1), ("Mesh.MaxNumThreads2D", 1), ("Mesh.MaxNumThreads3D", 1),
                           ("Mesh.Optimize", 1), ("Mesh.ElementOrder", 2), ("Mesh.SecondOrderLinear", 1),
                           ("Mesh.HighOrderOptimize", 0), ("Mesh.MshFileVersion", 4.1), ("Mesh.Binary", 1),
                           ("Mesh.SaveAll", 0)):
            gmsh.option.setNumber(key, value)
        gmsh.model.mesh.generate(3)
        n_nodes = len(gmsh.model.mesh.getNodes()[0])
        types, tags, _ = gmsh.model.mesh.getElements(3)
        n_cells = int(sum(len(t) for t in tags))
        log.info("%s: %d tet10 cells, %d nodes (size %.4g m)", out.name, n_cells, n_nodes, size)
        out.parent.mkdir(parents=True, exist_ok=True)
        gmsh.write(str(out))
    finally:
        gmsh.finalize()
    return {"nodes": n_nodes, "cells": n_cells, "size": size}


def _near_bolt(box) -> bool:
    xmin, ymin, _, xmax, ymax, _ = box
    cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
    return any(np.hypot(cx - x, cy - y) < BOLT_R for x, y in BOLTS)
