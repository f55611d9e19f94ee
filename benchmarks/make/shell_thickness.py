"""Example: the cylindrical S8R panel of data/examples/shell_panel updated on its shell thicknesses (route B).

    python -m benchmarks.make.shell_thickness        # data/examples/shell_thickness/

The panel, its four segments, sensors, excitation and damping are those of :mod:`benchmarks.make.shell_panel`;
the parameters are relative factors on the four ``*SHELL SECTION`` thicknesses (3 mm nominal), which enter
K and M non-linearly (bending stiffness ~ t^3): ccx runs as a black box, one run per FE run.

``panel.inp`` is the model's mesh (``MODEL_MESH``, 12 x 12 cells). ``measured.csv`` is ccx's own
``*STEADY STATE DYNAMICS`` FRF (modal superposition of ``N_MODES`` modes, ``*MODAL DAMPING, RAYLEIGH`` = the
model file's a, b; the same route-B deck writer as the update's FE runs) of the panel meshed twice as finely
(``FINE_MESH``, 24 x 24) with the thicknesses scaled by ``1 + THETA_TRUE``, 7 sensors, 1 % multiplicative noise
(seed ``SEED``), at ``RATIOS`` times each of the fine mesh's first three natural frequencies (10 lines per mode)
except those within 3 % of any of its natural frequencies (0.85 f_2 is at f_1, 1.15 f_1 2.2 % below f_2,
1.15 f_3 0.9 % below f_4): 27 lines. The S8R panel converges slowly under mesh refinement: at the
truth the 12 x 12 mesh's first three natural frequencies are 0.21-0.23 % above the 24 x 24 mesh's (printed,
and kept in ``truth.json``). The damping is light (0.27 % of critical at the first mode), so a line within the
half-power band would see that difference as tens of per cent of amplitude; 3 % away it is ~7 % of the
frequency error per line, and the part common to the modes looks like a thickness change (f ~ t for a shell
in bending) which the update takes up.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.make import shell_panel
from fe_core.io import read_model

OUT = Path(__file__).resolve().parents[2] / "data" / "examples" / "shell_thickness"
THETA_TRUE = [0.06, -0.05, 0.08, -0.04]
NOISE, SEED = 0.01, 11
MODEL_MESH, FINE_MESH = (12, 12), (24, 24)
N_MODES = 30
#: Lines per mode, as fractions of its natural frequency (on the fine mesh at the truth).
RATIOS = (0.85, 0.88, 0.91, 0.94, 0.97, 1.03, 1.06, 1.09, 1.12, 1.15)

MODEL_TOML = """# The cylindrical S8R panel of data/examples/shell_panel, updated on its shell thicknesses: route B
# (python -m benchmarks.make.shell_thickness). Each FE run is one ccx run of the deck with the thicknesses
# scaled by 1 + factor, in its own folder under the run folder; derivatives by forward differences.
units = "SI"
solver = "calculix"
deck = "panel.inp"
solver_timeout = 120.0
n_modes = {n_modes}

[damping]
a = {a}
b = {b}
{parameters}{sensors}
[[excitations]]
name = "tip corner z"
nset = "TIP_CORNER"
direction = "z"
"""


def _sensor_tables(mesh) -> str:
    _, ids = shell_panel.panel(*mesh)
    return "".join(f'\n[[sensors]]\nname = "{d} at {shell_panel.point(u, v)}"\nnode = '
                   f'{ids[shell_panel.point(u, v)]}\ndirection = "{d}"\n' for u, v, d in shell_panel.SENSORS)


def model_toml(mesh=MODEL_MESH) -> str:
    params = "".join(f'\n[[parameters]]\nname = "t_{s.lower()}"\nkind = "shell_thickness"\nelset = "{s}"\n'
                     f'bounds = [-0.3, 0.3]\n' for s in shell_panel.SEGMENTS)
    a, b = shell_panel.DAMPING
    return MODEL_TOML.format(n_modes=N_MODES, a=a, b=b, parameters=params, sensors=_sensor_tables(mesh))


def main(out: Path = OUT) -> None:
    out.mkdir(parents=True, exist_ok=True)
    coarse, _ = shell_panel.panel(*MODEL_MESH)
    (out / "panel.inp").write_text(coarse)
    (out / "model.toml").write_text(model_toml())
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fine_cards, _ = shell_panel.panel(*FINE_MESH)
        (tmp / "panel.inp").write_text(fine_cards)
        (tmp / "model.toml").write_text(model_toml(FINE_MESH))
        fine = read_model(tmp / "model.toml").with_workdir(tmp / "fe")
        coarse = read_model(out / "model.toml").with_workdir(tmp / "fe")
        f_fine = fine.natural_frequencies(THETA_TRUE, 8)
        f_coarse = coarse.natural_frequencies(THETA_TRUE, 8)
        print("natural frequencies at the truth, fine mesh  :", np.round(f_fine, 3).tolist())
        print("                                 model mesh :", np.round(f_coarse, 3).tolist())
        print("difference (%):", np.round(100 * (f_coarse / f_fine - 1), 3).tolist())
        freqs = np.sort(np.concatenate([f * np.array(RATIOS) for f in f_fine[:3]]))
        freqs = freqs[np.min(np.abs(freqs[:, None] / f_fine[None, :] - 1), axis=1) >= 0.03]  # near mode 4: out
        H = fine.parameter_frf(THETA_TRUE, freqs)
    rng = np.random.default_rng(SEED)
    amp = np.abs(H) * (1 + NOISE * rng.standard_normal(H.shape))
    rows = ["sensor,frequency_hz,amplitude"]
    for k, f in enumerate(freqs):
        rows += [f"{j + 1},{float(f)!r},{float(amp[k, j])!r}" for j in range(H.shape[1])]
    (out / "measured.csv").write_text("\n".join(rows) + "\n")
    truth = {"parameters": THETA_TRUE, "names": [f"t_{s.lower()}" for s in shell_panel.SEGMENTS],
             "what": "relative factors on the *SHELL SECTION thicknesses (3 mm nominal)", "noise": NOISE,
             "seed": SEED, "ratios": list(RATIOS), "fine_mesh": list(FINE_MESH), "model_mesh": list(MODEL_MESH),
             "natural_frequencies_fine_hz": np.round(f_fine, 4).tolist(),
             "natural_frequencies_model_mesh_hz": np.round(f_coarse, 4).tolist(),
             "frequencies_hz": np.round(freqs, 4).tolist()}
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(f"wrote {out}: {len(freqs)} frequencies x {H.shape[1]} sensors")


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", type=Path, default=OUT, help="folder to write (default: the example's)")
    main(parser.parse_args().out)
