"""Example: the cylindrical S8R panel of data/examples/shell_panel updated on its shell thicknesses (route B).

    python -m benchmarks.make.shell_thickness        # data/examples/shell_thickness/

The panel, its four segments, sensors, excitation and damping are those of :mod:`benchmarks.make.shell_panel`;
the parameters are relative factors on the four ``*SHELL SECTION`` thicknesses (3 mm nominal), which enter
K and M non-linearly (bending stiffness ~ t^3): ccx runs as a black box, one run per FE run.

``panel.inp`` is the model's mesh (``MODEL_MESH``, 12 x 12 cells). ``measured.csv`` is ccx's own
``*STEADY STATE DYNAMICS`` FRF (modal superposition of 40 modes, ``*MODAL DAMPING, RAYLEIGH`` = the model
file's a, b) of the panel meshed twice as finely (``FINE_MESH``, 24 x 24) with the thicknesses scaled by
``1 + THETA_TRUE``, at 5 frequencies in each half-band 0.85-1.0 and 1.0-1.15 times each of the first three
natural frequencies (as ccx places them; repeated ones dropped), 7 sensors, 1 % multiplicative noise
(seed ``SEED``). The two meshes' natural frequencies at the truth are printed and kept in ``truth.json``: the
S8R panel converges slowly under mesh refinement (the clamped edge), 0.08-0.11 % between 12 x 12 and 24 x 24.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.make import shell_panel
from fe_core.io.calculix import read_deck

OUT = Path(__file__).resolve().parents[2] / "data" / "examples" / "shell_thickness"
THETA_TRUE = [0.06, -0.05, 0.08, -0.04]
NOISE, SEED = 0.01, 11
MODEL_MESH, FINE_MESH = (12, 12), (24, 24)
N_MODES = 30

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


def thickness_cards(nx: int, ny: int, theta, folder: Path) -> tuple[str, dict]:
    """The panel's model cards with each segment's *SHELL SECTION thickness times 1 + theta_k."""
    cards, ids = shell_panel.panel(nx, ny)
    (folder / "plain.inp").write_text(cards)
    deck = read_deck(folder / "plain.inp")
    refs = [shell_panel_ref(deck, s) for s in shell_panel.SEGMENTS]
    text = deck.text(numbers={r: shell_panel.T * (1 + t) for r, t in zip(refs, theta)})
    return text, ids


def shell_panel_ref(deck, elset: str):
    from fe_core.io.calculix.deck import NumberRef

    return NumberRef(deck.section_of(elset), 0, 0)


def model_toml() -> str:
    params = "".join(f'\n[[parameters]]\nname = "t_{s.lower()}"\nkind = "shell_thickness"\nelset = "{s}"\n'
                     f'bounds = [-0.3, 0.3]\n' for s in shell_panel.SEGMENTS)
    _, ids = shell_panel.panel(*MODEL_MESH)
    sens = "".join(f'\n[[sensors]]\nname = "{d} at {shell_panel.point(u, v)}"\nnode = '
                   f'{ids[shell_panel.point(u, v)]}\ndirection = "{d}"\n' for u, v, d in shell_panel.SENSORS)
    a, b = shell_panel.DAMPING
    return MODEL_TOML.format(n_modes=N_MODES, a=a, b=b, parameters=params, sensors=sens)


def main(out: Path = OUT) -> None:
    out.mkdir(parents=True, exist_ok=True)
    coarse, _ = shell_panel.panel(*MODEL_MESH)
    (out / "panel.inp").write_text(coarse)
    (out / "model.toml").write_text(model_toml())
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        fine, fids = thickness_cards(*FINE_MESH, THETA_TRUE, tmp)
        coarse_truth, _ = thickness_cards(*MODEL_MESH, THETA_TRUE, tmp)
        f_fine = shell_panel.modes(fine, tmp)
        f_coarse = shell_panel.modes(coarse_truth, tmp)
        print("natural frequencies at the truth, fine mesh  :", np.round(f_fine, 3).tolist())
        print("                                 model mesh :", np.round(f_coarse, 3).tolist())
        print("difference (%):", np.round(100 * (f_coarse / f_fine - 1), 3).tolist())
        bands = [(float(0.85 * f), float(1.15 * f)) for f in f_fine[:3]]
        freqs, H = shell_panel.ccx_frf(fine, fids, bands, 5, tmp)
    freqs, keep = np.unique(np.round(freqs, 6), return_index=True)   # ccx prints a natural frequency twice
    H = H[keep]
    rng = np.random.default_rng(SEED)
    amp = np.abs(H) * (1 + NOISE * rng.standard_normal(H.shape))
    rows = ["sensor,frequency_hz,amplitude"]
    for k, f in enumerate(freqs):
        rows += [f"{j + 1},{float(f)!r},{float(amp[k, j])!r}" for j in range(H.shape[1])]
    (out / "measured.csv").write_text("\n".join(rows) + "\n")
    truth = {"parameters": THETA_TRUE, "names": [f"t_{s.lower()}" for s in shell_panel.SEGMENTS],
             "what": "relative factors on the *SHELL SECTION thicknesses (3 mm nominal)", "noise": NOISE,
             "seed": SEED, "fine_mesh": list(FINE_MESH), "model_mesh": list(MODEL_MESH),
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
