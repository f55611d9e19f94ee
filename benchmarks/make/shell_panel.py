"""Example: a cylindrical aluminium panel of S8R shells, a CalculiX deck (route A on segment moduli).

    python -m benchmarks.make.shell_panel          # data/examples/shell_panel/

A panel of radius 0.4 m over a 90 degree arc, 0.5 m long, 3 mm thick, clamped along its straight edge at
x = 0 (every node there, *BOUNDARY 1-6). Four segments (*ELSET): the root half (x < 0.25 m) and the tip
half, each split at mid-arc; one material for all. Our own FE core has no shell element: the model is the
deck, ccx assembles it.

``panel.inp`` is the model's mesh (``MODEL_MESH``: 12 x 12 cells). ``measured.csv`` is CalculiX's own FRF
(``*STEADY STATE DYNAMICS``, modal superposition of 40 modes with ``*MODAL DAMPING, RAYLEIGH`` = the model
file's a, b) of the same panel meshed twice as finely (``FINE_MESH``: 24 x 24; the natural frequencies
differ by 0.085-0.108 % in the first three modes, see the printout) with the segments' moduli scaled by
``1 + ALPHA_TRUE``, around the first three modes (ccx places 5 frequencies in each half-band 0.85-1.0 and
1.0-1.15 times each natural frequency; repeated ones dropped: 30), 7 sensors, with 1 % multiplicative
noise (seed 5). The first try, a flat panel with two blade stiffeners (S4 and S8R), was 0.3-0.7 % off its
finer mesh (the T-junctions converge slowly) and is not kept.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from fe_core.io.calculix import read_eigenfrequencies, read_steady_state, run_ccx

OUT = Path(__file__).resolve().parents[2] / "data" / "examples" / "shell_panel"
ALPHA_TRUE = [-0.10, 0.15, 0.20, -0.15]
SEGMENTS = ["ROOT_LOW", "ROOT_HIGH", "TIP_LOW", "TIP_HIGH"]
NOISE, SEED = 0.01, 5
MODEL_MESH, FINE_MESH = (12, 12), (24, 24)     # cells along the axis, around the arc
DAMPING = (2.0, 2e-6)
L, R, ARC = 0.5, 0.4, np.pi / 2
E, NU, RHO, T = 70e9, 0.33, 2700.0, 0.003
#: Sensors (x, y, z, direction) and the excitation: points on both meshes.
SENSORS = [(0.5, 0.0, "z"), (0.5, 0.25, "z"), (0.5, 0.75, "y"), (1.0, 0.0, "z"), (1.0, 0.5, "z"),
           (1.0, 1.0, "y"), (0.75, 0.5, "z")]            # (axial fraction, arc fraction, direction)
EXCITATION = (1.0, 1.0, "z")


def panel(nx: int, ny: int, factors=None) -> tuple[str, dict]:
    """(model cards of the deck, {(x, y, z) rounded: node id}): nx cells along the axis, ny around the arc."""
    nodes, ids = [], {}

    def node(u, v):
        x, th = L * u, ARC * v
        key = (round(x, 9), round(R * np.sin(th), 9), round(R * np.cos(th), 9))
        if key not in ids:
            ids[key] = len(ids) + 1
            nodes.append(f"{ids[key]}, {key[0]:.9g}, {key[1]:.9g}, {key[2]:.9g}")
        return ids[key]

    sets = {s: [] for s in SEGMENTS}
    elems = []
    for j in range(ny):
        for i in range(nx):
            u0, u1, v0, v1 = i / nx, (i + 1) / nx, j / ny, (j + 1) / ny
            um, vm = (u0 + u1) / 2, (v0 + v1) / 2
            elems.append([node(u0, v0), node(u1, v0), node(u1, v1), node(u0, v1),
                          node(um, v0), node(u1, vm), node(um, v1), node(u0, vm)])
            sets[SEGMENTS[2 * (u1 > 0.5 + 1e-9) + (v1 > 0.5 + 1e-9)]].append(len(elems))
    out = ["** a cylindrical aluminium panel of S8R shells (benchmarks/make/shell_panel.py)", "*NODE"] + nodes
    out.append("*ELEMENT, TYPE=S8R, ELSET=PANEL")
    out += [f"{e + 1}, " + ", ".join(map(str, c)) for e, c in enumerate(elems)]
    for s in SEGMENTS:
        out.append(f"*ELSET, ELSET={s}")
        ids_ = sets[s]
        out += [", ".join(map(str, ids_[k:k + 12])) for k in range(0, len(ids_), 12)]
    clamp = [i for (x, _, _), i in ids.items() if abs(x) < 1e-12]
    out.append("*NSET, NSET=CLAMP")
    out += [", ".join(map(str, clamp[k:k + 12])) for k in range(0, len(clamp), 12)]
    out += ["*NSET, NSET=TIP_CORNER", f"{node(1.0, 1.0)}"]
    if factors is None:
        out += ["*MATERIAL, NAME=ALU", "*ELASTIC", f"{E:.6g}, {NU}", "*DENSITY", f"{RHO}"]
        mats = ["ALU"] * 4
    else:
        mats = []
        for s, f in zip(SEGMENTS, factors):
            mats.append(f"ALU_{s}")
            out += [f"*MATERIAL, NAME=ALU_{s}", "*ELASTIC", f"{E * (1 + f)!r}, {NU}", "*DENSITY", f"{RHO}"]
    for s, m in zip(SEGMENTS, mats):
        out += [f"*SHELL SECTION, ELSET={s}, MATERIAL={m}", f"{T}"]
    out += ["*BOUNDARY", "CLAMP, 1, 6"]
    return "\n".join(out) + "\n", ids


def point(u: float, v: float) -> tuple[float, float, float]:
    return (round(L * u, 9), round(float(R * np.sin(ARC * v)), 9), round(float(R * np.cos(ARC * v)), 9))


def _node_at(ids, p):
    return ids[p]


def ccx_frf(model_cards: str, ids: dict, bands: list[tuple[float, float]], n_per_half: int, folder: Path):
    """ccx's modal FRF at the sensors (complex, shape (p, n)) and its frequencies."""
    sensors = [_node_at(ids, point(*s[:2])) for s in SENSORS]
    f = _node_at(ids, point(*EXCITATION[:2]))
    a, b = DAMPING
    steps = ["*NSET, NSET=SENSORS", ", ".join(map(str, sensors)),
             "*STEP", "*FREQUENCY, STORAGE=YES", "40", "*CLOAD", f"{f}, 3, 0.", "*END STEP"]
    for lo, hi in bands:
        steps += ["*STEP", "*STEADY STATE DYNAMICS", f"{lo!r}, {hi!r}, {n_per_half}, 1.",
                  "*MODAL DAMPING, RAYLEIGH", f",,{a!r},{b!r}", "*CLOAD", f"{f}, 3, 1.",
                  "*NODE PRINT, NSET=SENSORS", "U", "*END STEP"]
    (folder / "frf.inp").write_text(model_cards + "\n".join(steps) + "\n")
    run_ccx(folder, "frf", timeout=900)
    freqs, disp = read_steady_state(folder / "frf.dat")
    comp = {"x": 0, "y": 1, "z": 2}
    H_ = np.column_stack([disp[n][:, comp[s[2]]] for n, s in zip(sensors, SENSORS)])
    return freqs, H_


def modes(model_cards: str, folder: Path, n: int = 8) -> np.ndarray:
    (folder / "modes.inp").write_text(model_cards + f"*STEP\n*FREQUENCY\n{n}\n*END STEP\n")
    run_ccx(folder, "modes", timeout=900)
    return read_eigenfrequencies(folder / "modes.dat")


MODEL_TOML = """# A cylindrical aluminium panel of S8R shells as a CalculiX deck (python -m benchmarks.make.shell_panel).
# Route A: ccx exports each segment's stiffness and mass (m + 1 runs), the update runs in-process.
units = "SI"
solver = "calculix"
deck = "panel.inp"
solver_timeout = 120.0

[damping]
a = {a}
b = {b}
{segments}
{sensors}
[[excitations]]
name = "tip corner z"
nset = "TIP_CORNER"
direction = "z"
"""


def main(out: Path = OUT) -> None:
    out.mkdir(parents=True, exist_ok=True)
    coarse, cids = panel(*MODEL_MESH)
    (out / "panel.inp").write_text(coarse + "*STEP\n*FREQUENCY\n8\n*END STEP\n")
    segs = "".join(f'\n[[segments]]\nset = "{s}"\nbounds = [-0.5, 0.5]\n' for s in SEGMENTS)
    sens = "".join(f'\n[[sensors]]\nname = "{d} at {point(u, v)}"\nnode = {_node_at(cids, point(u, v))}\n'
                   f'direction = "{d}"\n' for u, v, d in SENSORS)
    (out / "model.toml").write_text(MODEL_TOML.format(a=DAMPING[0], b=DAMPING[1], segments=segs, sensors=sens))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fine, fids = panel(*FINE_MESH, factors=ALPHA_TRUE)
        coarse_truth, _ = panel(*MODEL_MESH, factors=ALPHA_TRUE)
        f_fine = modes(fine, tmp)
        f_coarse = modes(coarse_truth, tmp)
        print("natural frequencies at the truth, fine mesh  :", np.round(f_fine, 2).tolist())
        print("                                 model mesh :", np.round(f_coarse, 2).tolist())
        print("difference (%):", np.round(100 * (f_coarse / f_fine - 1), 3).tolist())
        bands = [(float(0.85 * f), float(1.15 * f)) for f in f_fine[:3]]
        freqs, H_ = ccx_frf(fine, fids, bands, 5, tmp)
    freqs, keep = np.unique(np.round(freqs, 6), return_index=True)   # ccx prints a natural frequency twice
    H_ = H_[keep]
    rng = np.random.default_rng(SEED)
    amp = np.abs(H_) * (1 + NOISE * rng.standard_normal(H_.shape))
    rows = ["sensor,frequency_hz,amplitude"]
    for k, f in enumerate(freqs):
        rows += [f"{j + 1},{float(f)!r},{float(amp[k, j])!r}" for j in range(H_.shape[1])]
    (out / "measured.csv").write_text("\n".join(rows) + "\n")
    truth = {"parameters": ALPHA_TRUE, "names": SEGMENTS, "noise": NOISE, "seed": SEED,
             "natural_frequencies_fine_hz": np.round(f_fine, 4).tolist(),
             "natural_frequencies_model_mesh_hz": np.round(f_coarse, 4).tolist(),
             "frequencies_hz": np.round(freqs, 4).tolist()}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(f"wrote {out}: {len(freqs)} frequencies x {H_.shape[1]} sensors")


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", type=Path, default=OUT, help="folder to write (default: the example's)")
    main(parser.parse_args().out)
