"""Write one far-effect case: ``model.toml`` (and the mesh or deck it names), ``measured.csv`` and ``truth.json``."""

from __future__ import annotations

import json
import logging
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from ..own_structures import row_stiffness
from . import plate as pl
from . import shell as sh
from .cases import LINES, STRUCTURES, Case
from .noise import FLOOR, noisy, write_table

log = logging.getLogger(__name__)
ROOT = Path(__file__).resolve().parents[3] / "runs" / "far_effects"
#: Rayleigh damping of every case: about 1 % of critical between 100 and 700 Hz.
DAMPING = (8.0, 4e-6)


# -- the plate ------------------------------------------------------------------------------------------------
def plate_mesh(name: str, root: Path = ROOT) -> Path:
    s = STRUCTURES[name]
    path = root / "meshes" / f"{name}.msh"
    if not path.exists():
        pl.mesh(s, path)
    return path


def plate_toml(s: pl.PlateSpec, g: dict, mesh_rel: str) -> str:
    lines = [f"# {s.name}: a clamped steel plate with a hole and a rib, tet10 (benchmarks/make/far_effects).",
             'units = "SI"', f'mesh = "{mesh_rel}"', "", "[damping]", f"a = {DAMPING[0]!r}", f"b = {DAMPING[1]!r}",
             "", "[[materials]]", f"E = {pl.E!r}", f"nu = {pl.NU!r}", f"rho = {pl.RHO!r}", ""]
    for name in s.segments:
        lines += ["[[segments]]", f'set = "{name}"', "bounds = [-0.5, 0.5]", ""]
    lines += ["[[supports]]", 'nodes = "clamp"', 'fix = ["x", "y", "z"]', ""]
    for name, point, direction in s.sensors:
        lines += ["[[sensors]]", f'name = "{name}"', f"node = {pl.vertex_at(g, point)}",
                  f"direction = {[float(v) for v in direction]}", ""]
    name, point, direction = s.excitation
    lines += ["[[excitations]]", f'name = "{name}"', f"node = {pl.vertex_at(g, point)}",
              f"direction = {[float(v) for v in direction]}", ""]
    return "\n".join(lines)


def plate_case(case: Case, out: Path) -> dict:
    s = STRUCTURES[case.structure]
    path = plate_mesh(case.structure, out.parent)
    g = pl.read(path)
    fem = pl.skfem_model(g, s)
    alpha = np.array(case.alpha, float)
    K, M = pl.matrices(fem, alpha)
    total_mass = float(np.ones(fem["N"]) @ M @ np.ones(fem["N"])) / 3.0
    effect, truth_effect = None, None
    if case.effect is not None:
        e = dict(case.effect)
        node = pl.vertex_at(g, e["point"])
        if e["kind"] == "point_mass":
            value = e["share"] * total_mass
            effect = {"kind": "point_mass", "node": node, "value": value}
        elif e["kind"].startswith("grounded_spring"):
            row = fem["dofs"](node)["xyz".index(e["kind"][-1])]
            value = e["share"] * row_stiffness(K, fem["fixed"], row)
            effect = {"kind": e["kind"], "node": node, "value": value}
        elif e["kind"] == "layer":
            effect = None
            value = e["share"] * total_mass
        truth_effect = {"kind": e["kind"], "node": node, "value": float(value),
                        "position": [float(v) for v in g["nodes"][node]], "share": e["share"]}
    if case.effect is not None and case.effect["kind"] == "layer":
        K, M = pl.matrices(fem, alpha)
        centres = g["nodes"][g["cells"][:, :4]].mean(axis=1)
        cells = np.flatnonzero(np.linalg.norm(centres - np.asarray(case.effect["point"]), axis=1)
                               < case.effect["radius"])
        Mc = fem["assemble"](cells)[1]
        ones = np.ones(fem["N"])
        layer_mass = float(ones @ Mc @ ones) / 3.0
        M = M + (truth_effect["value"] / layer_mass) * Mc
        truth_effect["cells"] = int(cells.size)
    else:
        K, M = pl.matrices(fem, alpha, effect, g)
    exc_name, exc_point, exc_dir = s.excitation
    load = pl.vector_at(fem, pl.vertex_at(g, exc_point), exc_dir)
    outputs = np.array([pl.vector_at(fem, pl.vertex_at(g, p), d) for _, p, d in s.sensors])
    t = time.perf_counter()
    H, natural = pl.modal_frf(fem, K, M, DAMPING, load, outputs, LINES)
    check_lines = LINES[[40, 333, 702]]
    Hd = pl.direct_frf(fem, K, M, DAMPING, load, outputs, check_lines)
    err = float(np.max(np.abs(H[[40, 333, 702]] - Hd) / np.abs(Hd)))
    log.info("%s: modal FRF %.1f s, max relative difference to direct solves %.2e", case.name,
             time.perf_counter() - t, err)
    out.mkdir(parents=True, exist_ok=True)
    (out / "model.toml").write_text(plate_toml(s, g, os.path.relpath(path, out)))
    size = float(np.linalg.norm(g["nodes"].max(axis=0) - g["nodes"].min(axis=0)))
    return {"H": H, "natural_hz": natural[natural < LINES[-1] * 1.2], "total_mass": total_mass,
            "effect": truth_effect, "size_m": size, "modal_check": err, "dofs": int(3 * len(g["nodes"]))}


# -- the box arm ----------------------------------------------------------------------------------------------
BOX_TOML = """# {name}: a clamped steel box arm of S8R shells, a B32 rib, a spring mount (benchmarks/make/far_effects).
units = "SI"
solver = "calculix"
deck = "{deck}"
solver_timeout = 900.0

[damping]
a = {a}
b = {b}
{segments}
{sensors}
[[excitations]]
name = "tip top corner"
point = {exc}
direction = [0.0, 0.5, 1.0]
"""
BOX_SENSORS = (("tip bottom", "z"), ("tip web", "y"), ("3/4 top", "z"), ("mid web", "y"), ("mid bottom", "z"),
               ("1/4 top", "z"), ("3/4 web", "y"), ("5/8 bottom", "z"))


def box_toml(s: sh.BoxSpec, deck_rel: str, segments=None) -> str:
    pts = sh.node_points(s)
    segs = "".join(f'\n[[segments]]\nset = "{n}"\nbounds = [-0.5, 0.5]\n' for n in (segments or s.segments))
    sens = "".join(f'\n[[sensors]]\nname = "{n} {d}"\npoint = {list(pts[n])}\ndirection = "{d}"\n'
                   for n, d in BOX_SENSORS)
    return BOX_TOML.format(name=s.name, deck=deck_rel, a=DAMPING[0], b=DAMPING[1], segments=segs, sensors=sens,
                           exc=list(pts["tip top corner"]))


def box_case(case: Case, out: Path) -> dict:
    from fe_core.io import read_model
    from fe_core.io.calculix import read_eigenfrequencies, run_ccx

    s = STRUCTURES[case.structure]
    decks = out.parent / "meshes"
    decks.mkdir(parents=True, exist_ok=True)
    cards, _ = sh.deck(s, 1)
    model_deck = decks / f"{s.name}.inp"
    if not model_deck.exists():
        model_deck.write_text(cards + "*STEP\n*FREQUENCY\n12\n*END STEP\n")
    out.mkdir(parents=True, exist_ok=True)
    (out / "model.toml").write_text(box_toml(s, os.path.relpath(model_deck, out)))
    model = read_model(out / "model.toml")
    total_mass = float(model.total_mass())
    extra, truth_effect = None, None
    if case.effect is not None:
        e = dict(case.effect)
        if e["kind"] != "point_mass":
            raise ValueError(f"{case.name}: the box arm's cases carry point masses")
        value = e["share"] * total_mass
        extra = {"kind": "point_mass", "point": e["point"], "value": value}
        _, ids = sh.deck(s, 1)
        node = ids[tuple(round(v, 9) for v in e["point"])]
        truth_effect = {"kind": "point_mass", "node": node, "value": float(value),
                        "position": [float(v) for v in e["point"]], "share": e["share"]}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fine_cards, _ = sh.deck(s, 2, factors=case.alpha, extra=extra)
        (tmp / "modes.inp").write_text(fine_cards + "*STEP\n*FREQUENCY\n14\n*END STEP\n")
        run_ccx(tmp, "modes", timeout=1800)
        natural = read_eigenfrequencies(tmp / "modes.dat")
        (tmp / "fine.inp").write_text(fine_cards + "*STEP\n*FREQUENCY\n12\n*END STEP\n")
        # route A on one segment (2 ccx runs): the fine deck's K and M with the factors already in its moduli
        (tmp / "fine.toml").write_text(box_toml(s, "fine.inp", segments=s.segments[:1]))
        saved = os.environ.get("FE_CALCULIX_CACHE")
        os.environ["FE_CALCULIX_CACHE"] = str(tmp / "cache")
        try:
            fine = read_model(tmp / "fine.toml")
            H = fine.frf(np.zeros(1), LINES)
        finally:
            if saved is None:
                os.environ.pop("FE_CALCULIX_CACHE")
            else:
                os.environ["FE_CALCULIX_CACHE"] = saved
    return {"H": H, "natural_hz": natural[natural < LINES[-1] * 1.2], "total_mass": total_mass,
            "effect": truth_effect, "size_m": float(np.linalg.norm([s.length, s.width, s.height])),
            "dofs": int(model.n_dofs)}


# -- a case ---------------------------------------------------------------------------------------------------
def write_case(case: Case, root: Path = ROOT) -> Path:
    """Generate ``case`` into ``root / case.name``; returns the folder."""
    out = root / case.name
    t = time.perf_counter()
    made = box_case(case, out) if case.structure == "box_arm" else plate_case(case, out)
    rng = np.random.default_rng(case.seed)
    H = made.pop("H")
    write_table(out / "measured.csv", LINES, *noisy(H, rng, LINES))
    np.savez_compressed(out / "exact.npz", frequencies_hz=LINES, frf=H)
    truth = {"case": case.name, "structure": case.structure, "alpha": list(case.alpha), "expected": case.expected,
             "seed": case.seed, "noise": {"relative": 0.01, "floor_of_peak_acceleration": FLOOR, "force": 0.002},
             "natural_hz": np.round(made.pop("natural_hz"), 3).tolist(), **made,
             "seconds": round(time.perf_counter() - t, 1)}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    log.info("%s: written to %s (%.0f s)", case.name, out, truth["seconds"])
    return out


def renoise(case: Case, root: Path = ROOT) -> None:
    """The measured file again from the case's stored noise-free FRF (``exact.npz``) and its seed."""
    out = root / case.name
    with np.load(out / "exact.npz") as z:
        freqs, H = z["frequencies_hz"], z["frf"]
    write_table(out / "measured.csv", freqs, *noisy(H, np.random.default_rng(case.seed), freqs))
