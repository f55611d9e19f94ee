"""Mesh the L-bracket example in second-order tetrahedra with gmsh (OpenCASCADE kernel).

An L-bracket bolted at its foot: a horizontal foot plate with two bolt holes, a
vertical web and two triangular ribs, in SI units (m). Six volume groups are the
segments; surface groups are node sets for supports and loads (README.md here).

    python data/examples/bracket/make_mesh.py            # bracket.msh, ~35,000 DOFs
    python data/examples/bracket/make_mesh.py --coarse   # bracket_coarse.msh, for tests
    python data/examples/bracket/make_mesh.py --fine     # bracket_fine.msh, for "measured" data
    python data/examples/bracket/make_mesh.py --size 0.004 --out my.msh

Written as Gmsh MSH 4.1 (binary), with only the physical groups' elements
(``tetra10`` cells per volume group, ``triangle6`` cells per surface group).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import gmsh

log = logging.getLogger("bracket")

HERE = Path(__file__).resolve().parent

# Geometry, m: x along the foot, y across, z up. The web stands at x in [0, T].
FOOT_LENGTH, WIDTH, HEIGHT, T = 0.12, 0.08, 0.12, 0.01
FOOT_SPLIT = 0.06  # foot_inner | foot_outer
WEB_SPLIT = 0.065  # web_lower | web_upper
RIB_T, RIB_LEG = 0.008, 0.05  # rib thickness and leg length along x and z
HOLE_R, HOLE_X, HOLE_Y = 0.0045, 0.095, (0.02, 0.06)

#: Mesh size (m) and elements per full circle on the bolt holes of the three variants.
SIZES = {"default": (0.0075, 12), "coarse": (0.02, 6), "fine": (0.0045, 16)}

SEGMENTS = ("foot_inner", "foot_outer", "web_lower", "web_upper", "rib_left", "rib_right")


def _segment_of(centre) -> str:
    x, y, z = centre
    if z < T - 1e-9 or (z < T + 1e-9 and x > T):
        return "foot_inner" if x < FOOT_SPLIT else "foot_outer"
    if x < T + 1e-9:
        return "web_lower" if z < WEB_SPLIT else "web_upper"
    return "rib_left" if y < WIDTH / 2 else "rib_right"


def build(size: float, out: Path, per_circle: int = 12) -> Path:
    """Build, mesh (order 2) and write the bracket; returns ``out``."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("bracket")
        occ = gmsh.model.occ
        foot_a = occ.addBox(0.0, 0.0, 0.0, FOOT_SPLIT, WIDTH, T)
        foot_b = occ.addBox(FOOT_SPLIT, 0.0, 0.0, FOOT_LENGTH - FOOT_SPLIT, WIDTH, T)
        web_a = occ.addBox(0.0, 0.0, T, T, WIDTH, WEB_SPLIT - T)
        web_b = occ.addBox(0.0, 0.0, WEB_SPLIT, T, WIDTH, HEIGHT - WEB_SPLIT)
        holes = [occ.addCylinder(HOLE_X, y, -0.001, 0.0, 0.0, T + 0.002, HOLE_R) for y in HOLE_Y]
        foot_b_cut, _ = occ.cut([(3, foot_b)], [(3, h) for h in holes])
        ribs = []
        for y0 in (0.0, WIDTH - RIB_T):
            corners = [(T, y0, T), (T + RIB_LEG, y0, T), (T, y0, T + RIB_LEG)]
            p = [occ.addPoint(*c) for c in corners]
            lines = [occ.addLine(p[i], p[(i + 1) % 3]) for i in range(3)]
            face = occ.addPlaneSurface([occ.addCurveLoop(lines)])
            extruded = occ.extrude([(2, face)], 0.0, RIB_T, 0.0)
            ribs += [tag for dim, tag in extruded if dim == 3]
        volumes = [(3, foot_a), *foot_b_cut, (3, web_a), (3, web_b), *[(3, r) for r in ribs]]
        occ.fragment(volumes, [])  # conforming interfaces between the segments
        occ.synchronize()

        groups: dict[str, list[int]] = {name: [] for name in SEGMENTS}
        for dim, tag in gmsh.model.getEntities(3):
            groups[_segment_of(occ.getCenterOfMass(dim, tag))].append(tag)
        for name in SEGMENTS:
            if len(groups[name]) == 0:
                raise RuntimeError(f"segment {name!r} has no volume")
            gmsh.model.addPhysicalGroup(3, groups[name], name=name)

        surfaces = {"foot_bottom": [], "bolt_holes": [], "web_top": []}
        for dim, tag in gmsh.model.getEntities(2):
            xmin, ymin, zmin, xmax, ymax, zmax = gmsh.model.getBoundingBox(dim, tag)
            kind = gmsh.model.getType(dim, tag)
            if zmax < 1e-6:  # OCC pads bounding boxes by about 1e-7 m
                surfaces["foot_bottom"].append(tag)
            elif kind != "Plane" and xmin > FOOT_SPLIT:
                surfaces["bolt_holes"].append(tag)
            elif zmin > HEIGHT - 1e-6:
                surfaces["web_top"].append(tag)
        for name, tags in surfaces.items():
            if len(tags) == 0:
                raise RuntimeError(f"surface group {name!r} found no faces")
            gmsh.model.addPhysicalGroup(2, tags, name=name)

        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.option.setNumber("Mesh.MeshSizeMin", min(size / 3.0, 0.004))
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", per_circle)  # on the bolt holes
        gmsh.option.setNumber("Mesh.ElementOrder", 2)
        gmsh.option.setNumber("Mesh.HighOrderOptimize", 1)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.option.setNumber("Mesh.Binary", 1)
        gmsh.model.mesh.generate(3)
        n_nodes = len(gmsh.model.mesh.getNodes()[0])
        log.info("%s: %d nodes, %d DOFs (size %.4g m)", out.name, n_nodes, 3 * n_nodes, size)
        gmsh.write(str(out))
    finally:
        gmsh.finalize()
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    variant = parser.add_mutually_exclusive_group()
    variant.add_argument("--coarse", action="store_true", help="small mesh for tests")
    variant.add_argument("--fine", action="store_true", help="finer mesh for independent 'measured' data")
    variant.add_argument("--size", type=float, help="target element size, m")
    parser.add_argument("--out", type=Path, help="output .msh path")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    name = "coarse" if args.coarse else "fine" if args.fine else "default"
    size, per_circle = SIZES[name]
    if args.size is not None:
        size = args.size
    out = args.out or HERE / ("bracket.msh" if name == "default" else f"bracket_{name}.msh")
    build(size, out, per_circle)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
