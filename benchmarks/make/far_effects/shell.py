"""The CalculiX deck of the far-effect cases: a clamped steel box arm of S8R shells with a B32 rib and a spring mount.

A rectangular tube along x (``BoxSpec``: length, width along y, height along z, wall thickness), clamped at x = 0
(``*BOUNDARY ROOT, 1, 6``), meshed with 8-node shells (``S8R``) on a structured grid of ``nx`` cells along x and
``per_side`` cells along each side of the section. A ``B32`` beam rib runs along the top wall's centre line from
``rib_from`` to the tip (a rectangular section, sharing the shell's nodes). A ``SPRING1`` mount along z holds the
bottom wall's centre node at ``mount_x`` of the length. Five segments (*ELSET, each with its own material copy):
the top + bottom walls and the side walls, each split at mid-length, and the rib.

The model deck is the coarse grid; the data come from ccx's stiffness and mass matrices (route A, as the tool reads
a deck) of the same arm meshed twice as finely, the factors written into the materials' moduli and an undeclared
``*MASS`` element (or another spring) added at a node both grids share.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

E, NU, RHO = 2.1e11, 0.3, 7850.0


@dataclass(frozen=True)
class BoxSpec:
    name: str = "box_arm"
    length: float = 0.8
    width: float = 0.12
    height: float = 0.08
    wall: float = 0.003
    nx: int = 40
    per_side: tuple = (6, 4)            # cells along the width and along the height
    rib: tuple = (0.01, 0.02)           # B32 rib: width (y), height (z) of its rectangular section
    rib_from: float = 0.25              # fraction of the length where the rib starts
    mount_x: float = 0.6                # fraction of the length of the mount
    mount_k: float = 2e5                # N/m, along z

    @property
    def segments(self) -> tuple:
        return ("FLANGES_ROOT", "WEBS_ROOT", "FLANGES_TIP", "WEBS_TIP", "RIB")


def _section_points(s: BoxSpec, refine: int):
    """Points around the section (y, z, side) at the shell's node spacing (corners and mid-side nodes): 2 per cell
    edge; side 0 bottom, 1 right web, 2 top, 3 left web (counter-clockwise from (-w/2, -h/2))."""
    ny, nz = s.per_side[0] * refine, s.per_side[1] * refine
    w, h = s.width / 2, s.height / 2
    pts = []
    for k in range(2 * ny):
        pts.append((-w + s.width * k / (2 * ny), -h, 0))
    for k in range(2 * nz):
        pts.append((w, -h + s.height * k / (2 * nz), 1))
    for k in range(2 * ny):
        pts.append((w - s.width * k / (2 * ny), h, 2))
    for k in range(2 * nz):
        pts.append((-w, h - s.height * k / (2 * nz), 3))
    return pts


def deck(s: BoxSpec, refine: int = 1, factors=None, extra: dict | None = None) -> tuple[str, dict]:
    """(the deck's model cards, {rounded (x, y, z): node id}). ``refine``: cells per model cell along each edge;
    ``factors``: the segments' modulus factors (none: the nominal deck); ``extra``: an undeclared effect at a node
    ({"kind": "point_mass" | "grounded_spring_<x|y|z>", "point": (x, y, z), "value"})."""
    nx = s.nx * refine
    sec = _section_points(s, refine)
    n_around = len(sec)
    ids: dict = {}
    lines_nodes = []

    def nid(i, j):  # i: 0..2 nx along x (half-cell steps), j: 0..n_around-1 around
        x = s.length * i / (2 * nx)
        y, z, _ = sec[j % n_around]
        key = (round(x, 9), round(y, 9), round(z, 9))
        if key not in ids:
            ids[key] = len(ids) + 1
            lines_nodes.append(f"{ids[key]}, {key[0]:.9g}, {key[1]:.9g}, {key[2]:.9g}")
        return ids[key]

    sets = {name: [] for name in s.segments}
    shells = []
    for i in range(nx):
        for j in range(0, n_around, 2):
            i0, i1, j0, j1 = 2 * i, 2 * i + 2, j, j + 2
            # S8R: corners counter-clockwise seen from outside, then mid-side nodes
            c = [nid(i0, j0), nid(i1, j0), nid(i1, j1), nid(i0, j1), nid(i0 + 1, j0), nid(i1, j0 + 1),
                 nid(i0 + 1, j1), nid(i0, j0 + 1)]
            shells.append(c)
            side = sec[j][2]
            tip = (i + 0.5) / nx > 0.5
            kind = "FLANGES" if side in (0, 2) else "WEBS"
            sets[f"{kind}_{'TIP' if tip else 'ROOT'}"].append(len(shells))
    # the rib: B32 along the top wall's centre line (y = 0, z = h/2), from rib_from to the tip
    top_mid = next(j for j, (y, z, side) in enumerate(sec) if side == 2 and abs(y) < 1e-12)
    beams = []
    i_start = int(round(s.rib_from * nx))
    for i in range(i_start, nx):
        beams.append([nid(2 * i, top_mid), nid(2 * i + 1, top_mid), nid(2 * i + 2, top_mid)])
    out = [f"** {s.name}: S8R box arm with a B32 rib and a spring mount (benchmarks/make/far_effects/shell.py)",
           "*NODE"] + lines_nodes
    out.append("*ELEMENT, TYPE=S8R, ELSET=SHELLS")
    out += [f"{e + 1}, " + ", ".join(map(str, c)) for e, c in enumerate(shells)]
    first_beam = len(shells) + 1
    out.append("*ELEMENT, TYPE=B32, ELSET=RIB")
    out += [f"{first_beam + e}, " + ", ".join(map(str, c)) for e, c in enumerate(beams)]
    for name in s.segments[:-1]:
        out.append(f"*ELSET, ELSET={name}")
        el = sets[name]
        out += [", ".join(map(str, el[k:k + 12])) for k in range(0, len(el), 12)]
    root = [i for (x, _, _), i in ids.items() if abs(x) < 1e-12]
    out.append("*NSET, NSET=ROOT")
    out += [", ".join(map(str, root[k:k + 12])) for k in range(0, len(root), 12)]
    bottom_mid = next(j for j, (y, z, side) in enumerate(sec) if side == 0 and abs(y) < 1e-12)
    mount = nid(int(round(2 * nx * s.mount_x)), bottom_mid)
    next_el = first_beam + len(beams)
    out += ["*NSET, NSET=MOUNT", f"{mount}", "*ELEMENT, TYPE=SPRING1, ELSET=MOUNT", f"{next_el}, {mount}",
            "*SPRING, ELSET=MOUNT", "3", f"{s.mount_k!r}"]
    next_el += 1
    if extra is not None:
        node = ids[tuple(round(v, 9) for v in extra["point"])]
        if extra["kind"] == "point_mass":
            out += ["*ELEMENT, TYPE=MASS, ELSET=EXTRA", f"{next_el}, {node}", "*MASS, ELSET=EXTRA",
                    f"{float(extra['value'])!r}"]
        elif extra["kind"].startswith("grounded_spring"):
            out += ["*ELEMENT, TYPE=SPRING1, ELSET=EXTRA", f"{next_el}, {node}", "*SPRING, ELSET=EXTRA",
                    f"{'xyz'.index(extra['kind'][-1]) + 1}", f"{float(extra['value'])!r}"]
        else:
            raise ValueError(extra["kind"])
    f = np.zeros(len(s.segments)) if factors is None else np.asarray(factors, float)
    for name, a in zip(s.segments, f):
        out += [f"*MATERIAL, NAME=STEEL_{name}", "*ELASTIC", f"{float(E * (1 + a))!r}, {NU}", "*DENSITY", f"{RHO}"]
    for name in s.segments[:-1]:
        out += [f"*SHELL SECTION, ELSET={name}, MATERIAL=STEEL_{name}", f"{s.wall}"]
    b, h = s.rib
    out += ["*BEAM SECTION, ELSET=RIB, MATERIAL=STEEL_RIB, SECTION=RECT", f"{b}, {h}", "0.d0, 1.d0, 0.d0"]
    out += ["*BOUNDARY", "ROOT, 1, 6"]
    return "\n".join(out) + "\n", ids


def node_points(s: BoxSpec) -> dict:
    """Named points of the arm (on both grids' nodes): the sensors' and the excitation's."""
    L, w, h = s.length, s.width / 2, s.height / 2
    return {"tip top corner": (L, w, h), "tip bottom": (L, 0.0, -h), "tip web": (L, w, 0.0),
            "3/4 top": (0.75 * L, -w / 2, h), "mid web": (0.5 * L, -w, 0.0), "mid bottom": (0.5 * L, w / 2, -h),
            "1/4 top": (0.25 * L, w / 2, h), "3/4 web": (0.75 * L, w, h / 2), "5/8 bottom": (0.625 * L, -w / 2, -h)}
