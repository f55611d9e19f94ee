"""Example: a cylindrical aluminium panel of S8R shells, a CalculiX deck (route A on segment moduli).

    python -m benchmarks.make.shell_panel          # data/examples/shell_panel/ (about 4 min on 2 busy cores)

A panel of radius 0.4 m over a 90 degree arc, 0.5 m long, 3 mm thick, hung free on soft springs at four points
of its straight edges (SPRING1 to ground in x, y and z, SUSPENSION_K: the suspension's rigid-body modes at 3-6 Hz, a
bungee test set-up). Four segments (*ELSET): the half x < 0.25 m and the other, each split at mid-arc; one
material for all. Our own FE core has no shell element: the model is the deck, ccx assembles it.

``panel.inp`` is the model's mesh (``MODEL_MESH``: 20 x 20 cells). ``measured.csv`` (and, without its noise,
``exact.npz``) is the FRF of ccx's stiffness and mass matrices of the same panel meshed twice as finely
(``FINE_MESH``: 40 x 40) with the segments' moduli scaled by ``1 + ALPHA_TRUE``, solved at each frequency
(no modal truncation) with the model file's Rayleigh damping (``EXAMPLE_DAMPING``: 0.9-1.2 % of critical),
at the frequencies of a 1 Hz grid within 0.9-1.1 times each of the first four flexible modes (``BAND``),
7 sensors, with 1 % multiplicative noise (seed 5). The printout and ``truth.json`` say how far the model mesh
is from the data mesh at the truth: ccx's natural frequencies, the noise-free FRF's chi-square per line in
units of the noise, and the least-squares factors of the noise-free data against their 95 % intervals.

Tried first and not kept: the panel clamped along x = 0 (12 x 12 against 24 x 24: natural frequencies 0.1 %
apart; S8R converge like 1/n there, ccx's clamped shell being a clamped 3-D face with its edge singularity,
so the 1 % noise on 210 amplitudes resolved the mesh difference and the intervals missed the truth), data
from ccx's own *STEADY STATE DYNAMICS (40 modes: up to 3x off the direct solution in small channels of the
free panel), and a flat panel with two blade stiffeners (0.3-0.7 % off its finer mesh).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from fe_core.io.calculix import read_eigenfrequencies, run_ccx

OUT = Path(__file__).resolve().parents[2] / "data" / "examples" / "shell_panel"
ALPHA_TRUE = [-0.10, 0.15, 0.20, -0.15]
SEGMENTS = ["ROOT_LOW", "ROOT_HIGH", "TIP_LOW", "TIP_HIGH"]
NOISE, SEED = 0.01, 5
MODEL_MESH, FINE_MESH = (20, 20), (40, 40)     # cells along the axis, around the arc
SUPPORT = "suspended"
SUSPENSION_K = 250.0       # N/m per corner and direction: the suspension's rigid-body modes at 3-6 Hz
#: where the springs hold the straight edges (axial fractions): no sensor or the excitation on a spring's node
#: (ccx ties a spring's shell node through a knot, and loads it otherwise than route A's equal shares)
SUSPENSION_AT = (0.25, 0.75)
N_RIGID, N_BANDS = 6, 4    # the suspension's modes, then the panel's first four, measured around
DAMPING = (2.0, 2e-6)      # Rayleigh a, b of route B's clamped panel (benchmarks/calculix_route_b.py)
#: the example's Rayleigh a, b: 0.9-1.2 % of critical in its four measured modes (0.2-0.5 % with DAMPING put
#: the half-power lines' slopes at 100-250 x a frequency difference: 0.014 % became 3 % in amplitude)
EXAMPLE_DAMPING = (4.0, 2e-5)
#: the measured frequencies: a grid of STEP_HZ within BAND times each flexible natural frequency of the data
#: mesh (evenly stepped bands: the flows estimate the noise from second differences along frequency)
BAND, STEP_HZ = (0.9, 1.1), 1.0
L, R, ARC = 0.5, 0.4, np.pi / 2
E, NU, RHO, T = 70e9, 0.33, 2700.0, 0.003
#: Sensors (x, y, z, direction) and the excitation: points on both meshes.
SENSORS = [(0.5, 0.0, "z"), (0.5, 0.25, "z"), (0.5, 0.75, "y"), (1.0, 0.0, "z"), (1.0, 0.5, "z"),
           (1.0, 1.0, "y"), (0.75, 0.5, "z")]            # (axial fraction, arc fraction, direction)
EXCITATION = (1.0, 1.0, "z")


def panel(nx: int, ny: int, factors=None, support: str = "clamped") -> tuple[str, dict]:
    """(model cards of the deck, {(x, y, z) rounded: node id}): nx cells along the axis, ny around the arc.

    ``support``: "clamped" (the straight edge at x = 0, *BOUNDARY 1-6; route B's panel) or "suspended"
    (free, on soft springs to ground at four points of its straight edges, SUSPENSION_K in x, y and z: the example's)."""
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
        corners = [node(u, v) for u in SUSPENSION_AT for v in (0.0, 1.0)]
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


def write_model(folder: Path, mesh: tuple[int, int], factors=None, segments=SEGMENTS) -> None:
    """panel.inp (the suspended panel, nominal moduli or ``factors``) and model.toml (route A on ``segments``,
    SENSORS, the excitation at TIP_CORNER) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    cards, ids = panel(*mesh, factors=factors, support=SUPPORT)
    (folder / "panel.inp").write_text(cards + "*STEP\n*FREQUENCY\n12\n*END STEP\n")
    segs = "".join(f'\n[[segments]]\nset = "{s}"\nbounds = [-0.5, 0.5]\n' for s in segments)
    sens = "".join(f'\n[[sensors]]\nname = "{d} at {point(u, v)}"\nnode = {_node_at(ids, point(u, v))}\n'
                   f'direction = "{d}"\n' for u, v, d in SENSORS)
    (folder / "model.toml").write_text(MODEL_TOML.format(a=EXAMPLE_DAMPING[0], b=EXAMPLE_DAMPING[1],
                                                       segments=segs, sensors=sens))


def measured_frequencies(natural_hz) -> np.ndarray:
    """The STEP_HZ grid's frequencies within BAND of any of the data mesh's flexible natural frequencies."""
    grid = STEP_HZ * np.arange(1, int(BAND[1] * max(natural_hz) / STEP_HZ) + 2)
    near = np.any([(grid >= BAND[0] * f) & (grid <= BAND[1] * f) for f in natural_hz], axis=0)
    return grid[near]


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
        # ccx's matrices of the data mesh with the true moduli (route A on one segment: 2 ccx runs, kept out of
        # the matrix cache), solved at each frequency (no modal truncation)
        write_model(tmp / "fine", FINE_MESH, factors=ALPHA_TRUE, segments=SEGMENTS[:1])
        cache = os.environ.get("FE_CALCULIX_CACHE")
        os.environ["FE_CALCULIX_CACHE"] = str(tmp / "cache")
        try:
            H_ = read_model(tmp / "fine" / "model.toml").frf(np.zeros(1), freqs)   # Krylov: direct to 1e-10
        finally:
            if cache is None:
                os.environ.pop("FE_CALCULIX_CACHE")
            else:
                os.environ["FE_CALCULIX_CACHE"] = cache
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
