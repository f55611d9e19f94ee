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
MODEL_MESH, FINE_MESH = (20, 20), (40, 40)     # cells along the axis, around the arc
SUPPORT = "suspended"
SUSPENSION_K = 250.0       # N/m per corner and direction: the suspension's rigid-body modes at 3-6 Hz
N_RIGID, N_BANDS = 6, 4    # the suspension's modes, then the panel's first four, measured around
DAMPING = (2.0, 2e-6)
#: the measured frequencies, relative to each flexible natural frequency of the data mesh
BAND = (0.85, 0.9, 0.95, 0.98, 1.0, 1.02, 1.05, 1.1, 1.15)
L, R, ARC = 0.5, 0.4, np.pi / 2
E, NU, RHO, T = 70e9, 0.33, 2700.0, 0.003
#: Sensors (x, y, z, direction) and the excitation: points on both meshes.
SENSORS = [(0.5, 0.0, "z"), (0.5, 0.25, "z"), (0.5, 0.75, "y"), (1.0, 0.0, "z"), (1.0, 0.5, "z"),
           (1.0, 1.0, "y"), (0.75, 0.5, "z")]            # (axial fraction, arc fraction, direction)
EXCITATION = (1.0, 1.0, "z")


def panel(nx: int, ny: int, factors=None, support: str = "clamped") -> tuple[str, dict]:
    """(model cards of the deck, {(x, y, z) rounded: node id}): nx cells along the axis, ny around the arc.

    ``support``: "clamped" (the straight edge at x = 0, *BOUNDARY 1-6; route B's panel) or "suspended"
    (free, on soft springs to ground at its four corners, SUSPENSION_K in x, y and z: the example's)."""
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
    if support == "clamped":
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
    if support == "clamped":
        out += ["*BOUNDARY", "CLAMP, 1, 6"]
    else:
        corners = [node(u, v) for u in (0.0, 1.0) for v in (0.0, 1.0)]
        out += ["*NSET, NSET=SUSPENSION", ", ".join(map(str, corners))]
        for d in (1, 2, 3):                       # one grounded spring per corner and direction
            out.append(f"*ELEMENT, TYPE=SPRING1, ELSET=SUSPENSION_{'XYZ'[d - 1]}")
            out += [f"{len(elems) + 4 * (d - 1) + k + 1}, {c}" for k, c in enumerate(corners)]
            out += [f"*SPRING, ELSET=SUSPENSION_{'XYZ'[d - 1]}", f"{d}", f"{SUSPENSION_K!r}"]
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


def check_model_mesh(out: Path, freqs, exact) -> dict:
    """The model mesh against the data mesh at the truth: the noise-free data's residual per line in units
    of the noise (chi-square per line), and the least-squares factors of the noise-free data against their
    95 % intervals at 1 % noise (the bias the discretisation difference alone leaves)."""
    from fe_core.inference.intervals import parameter_intervals
    from fe_core.io import read_model

    model = read_model(out / "model.toml")                     # route A: m + 1 ccx runs on the model mesh
    ours = np.abs(model.frf(np.array(ALPHA_TRUE), freqs))
    r = ours / np.abs(exact) - 1
    fit = parameter_intervals(model, freqs, np.abs(exact), np.array(ALPHA_TRUE), -0.5, 0.5, noise=NOISE,
                              max_jacobians=4).intervals
    half = (fit.high - fit.low) / 2
    bias = fit.estimate - np.array(ALPHA_TRUE)
    return {"chi2_per_line_at_truth": float(np.mean((r / NOISE) ** 2)), "max_abs_relative_difference": float(
        np.abs(r).max()), "noise_free_fit": fit.estimate.round(5).tolist(), "bias": bias.round(5).tolist(),
            "interval_half_width_95": half.round(5).tolist(), "bias_over_half_width": (bias / half).round(3).tolist()}


def write_model(folder: Path, mesh: tuple[int, int]) -> None:
    """panel.inp (the suspended panel, nominal moduli) and model.toml (route A, SEGMENTS, SENSORS, the
    excitation at TIP_CORNER) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    cards, ids = panel(*mesh, support=SUPPORT)
    (folder / "panel.inp").write_text(cards + "*STEP\n*FREQUENCY\n12\n*END STEP\n")
    segs = "".join(f'\n[[segments]]\nset = "{s}"\nbounds = [-0.5, 0.5]\n' for s in SEGMENTS)
    sens = "".join(f'\n[[sensors]]\nname = "{d} at {point(u, v)}"\nnode = {_node_at(ids, point(u, v))}\n'
                   f'direction = "{d}"\n' for u, v, d in SENSORS)
    (folder / "model.toml").write_text(MODEL_TOML.format(a=DAMPING[0], b=DAMPING[1], segments=segs, sensors=sens))


def measured_frequencies(natural_hz) -> np.ndarray:
    """LINES_PER_MODE frequencies around each of the data mesh's flexible natural frequencies."""
    return np.unique(np.round(np.concatenate([f * np.array(BAND) for f in natural_hz]), 4))


def main(out: Path = OUT) -> None:
    from fe_core.io import read_model

    write_model(out, MODEL_MESH)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        f_fine = modes(panel(*FINE_MESH, factors=ALPHA_TRUE, support=SUPPORT)[0], tmp, N_RIGID + N_BANDS + 2)
        f_coarse = modes(panel(*MODEL_MESH, factors=ALPHA_TRUE, support=SUPPORT)[0], tmp, N_RIGID + N_BANDS + 2)
        print("ccx's natural frequencies at the truth, data mesh:", np.round(f_fine, 3).tolist())
        print("                                       model mesh:", np.round(f_coarse, 3).tolist())
        print("difference (%):", np.round(100 * (f_coarse / f_fine - 1), 4).tolist())
        freqs = measured_frequencies(f_fine[N_RIGID:N_RIGID + N_BANDS])
        write_model(tmp / "fine", FINE_MESH)            # ccx's matrices of the data mesh (route A, m + 1 runs)
        H_ = read_model(tmp / "fine" / "model.toml").frf(np.array(ALPHA_TRUE), freqs, method="direct")
    check = check_model_mesh(out, freqs, H_)
    print(f"model mesh {MODEL_MESH} vs data mesh {FINE_MESH} at the truth, noise-free: chi-square per line "
          f"{check['chi2_per_line_at_truth']:.4f} (the noise alone: 1), max |difference| "
          f"{100 * check['max_abs_relative_difference']:.2f} %")
    print("noise-free least-squares factors", check["noise_free_fit"], "bias", check["bias"],
          "95 % half-widths", check["interval_half_width_95"], "bias / half-width", check["bias_over_half_width"])
    rng = np.random.default_rng(SEED)
    amp = np.abs(H_) * (1 + NOISE * rng.standard_normal(H_.shape))
    rows = ["sensor,frequency_hz,amplitude"]
    for k, f in enumerate(freqs):
        rows += [f"{j + 1},{float(f)!r},{float(amp[k, j])!r}" for j in range(H_.shape[1])]
    (out / "measured.csv").write_text("\n".join(rows) + "\n")
    np.savez_compressed(out / "exact.npz", frequencies_hz=freqs, frf=H_)
    truth = {"parameters": ALPHA_TRUE, "names": SEGMENTS, "noise": NOISE, "seed": SEED,
             "model_mesh": list(MODEL_MESH), "data_mesh": list(FINE_MESH),
             "natural_frequencies_data_mesh_hz": np.round(f_fine, 4).tolist(),
             "natural_frequencies_model_mesh_hz": np.round(f_coarse, 4).tolist(),
             "frequencies_hz": np.round(freqs, 4).tolist(), "model_mesh_check": check}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(f"wrote {out}: {len(freqs)} frequencies x {H_.shape[1]} sensors")


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", type=Path, default=OUT, help="folder to write (default: the example's)")
    main(parser.parse_args().out)
