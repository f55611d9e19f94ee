"""Example (a): the tet10 L-bracket, measured on an independent finer mesh.

    python -m benchmarks.make.bracket_example     # data/examples/bracket/{model,model_coarse}.toml,
                                                  # measured.csv, truth.json

The bracket (``data/examples/bracket/README.md``: foot with two bolt holes, web, two
ribs; steel) has six segments, one per volume group. It is bolted: the bolt holes'
cylindrical faces are fixed in x, y and z (the bolts' shanks fill the holes and their
heads clamp the foot around them). Fixing the whole underside instead
(``foot_bottom``) would glue the foot to a rigid base, so the foot segments would
hardly deform in the first modes and could not be updated; a base that only touches
the foot is contact, which a linear model leaves out.

Six sensors (``SENSORS``, placed by ``python -m benchmarks.bracket_sensors``) look at the web
in x, y and z and at both ribs along their hypotenuse's normal and the right one in y (the
first modes rock the bracket about the bolt line in x, sway it in y and twist it); one hammer
hit at the web's free vertical edge, along (1, 1, 0)/sqrt(2), drives the symmetric (x) and antisymmetric (y, twist) mode families at once.

``measured.csv`` is the FRF of the **fine** mesh (``make_mesh.py --fine``, 105,114 DOFs,
regenerated here when missing; an independent discretisation: other element size,
other nodes, sensors at their own nearest nodes) at the true factors ``ALPHA_TRUE``,
with ``NOISE`` multiplicative Gaussian noise (seed ``SEED``), at 0.95, 1.0 and 1.05
times the fine mesh's first five natural frequencies at the truth. ``truth.json``
records the truth and the discretisation error the update has to absorb: the default
mesh's natural frequencies and FRF at the truth against the fine mesh's.
The whole script takes about 5 minutes on 2 busy cores and 3.2 GB (the fine mesh's modes and FRF).
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[2] / "data" / "examples" / "bracket"
E, NU, RHO = 2.06e11, 0.3, 7850.0
#: Rayleigh a [1/s], b [s]: damping ratios 1.4-1.6 % at the first five modes (300-3200 Hz).
DAMPING = (50.0, 1.5e-6)
SEGMENTS = ("foot_inner", "foot_outer", "web_lower", "web_upper", "rib_left", "rib_right")
ALPHA_TRUE = np.array([-0.10, 0.15, 0.10, -0.15, 0.20, -0.10])
#: The search box of every alpha, in the model file (the engineer's prior: +-50 %).
BOUNDS = (-0.5, 0.5)
NOISE = 0.01
SEED = 3
N_MODES = 5
#: Measured frequencies per mode, relative to its natural frequency (the peak and both flanks).
WINDOW = (0.95, 1.0, 1.05)
#: (name, point [m], direction): the sensors, in the measured data's order. Chosen by
#: ``python -m benchmarks.bracket_sensors`` (docs/results/bracket-sensors.md): of 24 candidates, the six that leave the
#: smallest predicted parameter error from the discretisation residual and the noise, with both ribs' normals.
#: (The first layout, u_x/u_y at the web's top corners, u_x mid-web, u_y on the left rib, the right rib's normal
#: and u_z on the foot, left web_lower and the ribs on a weak combination: predicted bias -0.10/+0.09/+0.07.)
SENSORS = (
    ("web top z", [0.005, 0.04, 0.12], '"z"'),
    ("web lower x", [0.0, 0.04, 0.04], '"x"'),
    ("web lower y", [0.005, 0.0, 0.04], '"y"'),
    ("rib left normal", [0.035, 0.004, 0.035], "[1.0, 0.0, 1.0]"),
    ("rib right normal", [0.035, 0.076, 0.035], "[1.0, 0.0, 1.0]"),
    ("rib right y", [0.03, 0.08, 0.03], '"y"'),
)
HAMMER = ("hammer", [0.0, 0.0, 0.11], "[1.0, 1.0, 0.0]")
#: Nearest-node tolerance, m, per mesh: about half the element size near the points.
TOLERANCE = {"bracket.msh": 0.004, "bracket_coarse.msh": 0.008, "bracket_fine.msh": 0.003}


def model_text(mesh: str, tolerance: float, title: str) -> str:
    """The model file of the bracket on ``mesh`` (a path relative to the model file or absolute)."""
    lines = [
        f"# {title}",
        "# Written by python -m benchmarks.make.bracket_example (README.md here).",
        'units = "SI"',
        f'mesh = "{mesh}"',
        f"point_tolerance = {tolerance!r}   # m; each point's distance to its node is printed",
        "",
        "[damping]                 # Rayleigh: 1.4-1.6 % of critical at 300-3200 Hz",
        f"a = {DAMPING[0]!r}",
        f"b = {DAMPING[1]!r}",
        "",
        "[[materials]]             # steel, every cell",
        f"E = {E!r}",
        f"nu = {NU!r}",
        f"rho = {RHO!r}",
        "",
    ]
    for name in SEGMENTS:
        lines += ["[[segments]]", f'set = "{name}"', f"bounds = {list(BOUNDS)}", ""]
    lines += [
        "# Bolted: the bolt holes' faces are held in x, y, z. (foot_bottom would glue the whole",
        "# foot to a rigid base: the foot segments would then not deform and not be identifiable.)",
        "[[supports]]",
        'nodes = "bolt_holes"',
        'fix = ["x", "y", "z"]',
        "",
    ]
    for name, point, direction in SENSORS:
        lines += ["[[sensors]]", f'name = "{name}"', f"point = {point}", f"direction = {direction}", ""]
    name, point, direction = HAMMER
    lines += ["[[excitations]]           # a hammer hit on the web's free vertical edge, at 45 degrees",
              f'name = "{name}"', f"point = {point}", f"direction = {direction}", ""]
    return "\n".join(lines)


def write_model_files(out: Path = OUT) -> None:
    """``model.toml`` (default mesh, the one updated) and ``model_coarse.toml`` (tests)."""
    (out / "model.toml").write_text(model_text("bracket.msh", TOLERANCE["bracket.msh"],
                                               "Example (a): the tet10 L-bracket, 33,681 free DOFs."))
    (out / "model_coarse.toml").write_text(model_text("bracket_coarse.msh", TOLERANCE["bracket_coarse.msh"],
                                                      "The L-bracket on the coarse mesh (8,388 free DOFs), for tests."))


def fine_model(out: Path = OUT, text=None, title: str = "The fine mesh (measured data)."):
    """The bracket on the fine mesh (regenerated with make_mesh.py --fine when missing); ``text`` writes its model
    file (default :func:`model_text`; the modal example's has its own test points)."""
    from fe_core.io import read_model

    mesh = out / "bracket_fine.msh"
    if not mesh.exists():
        subprocess.run([sys.executable, str(out / "make_mesh.py"), "--fine"], check=True)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model_fine.toml"
        path.write_text((text or model_text)(str(mesh), TOLERANCE["bracket_fine.msh"], title))
        return read_model(path)


def measurement_frequencies(natural_hz: np.ndarray) -> np.ndarray:
    """``WINDOW`` times each natural frequency, Hz, rounded to 0.1 Hz, shape (len(WINDOW) * N_MODES,)."""
    return np.round(np.concatenate([f * np.asarray(WINDOW) for f in natural_hz[:N_MODES]]), 1)


def main() -> int:
    from fe_core.io import read_model
    from fe_core.inference.residual import overall_error, relative_residual
    from tasks.io.measured import MeasuredFRF, write_measured

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    write_model_files(OUT)
    t0 = time.perf_counter()
    fine = fine_model(OUT)
    print(f"fine model: {fine.n_dofs} free DOFs, read in {time.perf_counter() - t0:.0f} s", flush=True)
    fine_hz = fine.natural_frequencies(ALPHA_TRUE, n_modes=N_MODES + 1)
    freqs = measurement_frequencies(fine_hz)
    Z = np.abs(fine.frf(ALPHA_TRUE, freqs))
    fine_dofs = fine.n_dofs
    del fine
    rng = np.random.default_rng(SEED)
    amp = Z * (1 + NOISE * rng.standard_normal(Z.shape))
    write_measured(OUT / "measured.csv", MeasuredFRF(
        freqs, list(range(1, Z.shape[1] + 1)), amp, None,
        f"fine-mesh (bracket_fine.msh) FRF at alpha {ALPHA_TRUE.tolist()}, {NOISE:.0%} noise, seed {SEED}"))

    # The discretisation error at the truth: what the update of the default mesh must absorb.
    default = read_model(OUT / "model.toml")
    default_hz = default.natural_frequencies(ALPHA_TRUE, n_modes=N_MODES + 1)
    Zd = np.abs(default.frf(ALPHA_TRUE, freqs))
    truth = {
        "alpha": ALPHA_TRUE.tolist(), "segments": list(SEGMENTS), "noise": NOISE, "seed": SEED,
        "frequencies_hz": freqs.tolist(),
        "fine_mesh": {"file": "bracket_fine.msh (make_mesh.py --fine)", "free_dofs": fine_dofs},
        "discretisation_at_truth": {
            "natural_hz_fine": np.round(fine_hz, 2).tolist(),
            "natural_hz_default": np.round(default_hz, 2).tolist(),
            "natural_relative_difference": np.round(default_hz / fine_hz - 1, 5).tolist(),
            "overall_error_default_vs_noise_free_fine": round(overall_error(relative_residual(Zd, Z)), 5),
            "overall_error_default_vs_measured": round(overall_error(relative_residual(Zd, amp)), 5),
            "overall_error_fine_vs_measured": round(overall_error(relative_residual(Z, amp)), 5),
        },
    }
    (OUT / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(json.dumps(truth["discretisation_at_truth"], indent=1))
    print(f"wrote {OUT}: measured.csv ({freqs.size} frequencies x {Z.shape[1]} sensors), truth.json, model files")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.bracket_example", __doc__)
    sys.exit(main())
