"""The bracket's modes: the tet10 L-bracket measured as 6 modes at its six sensor points, on single axes.

    python -m benchmarks.make.bracket_modes    # data/examples/bracket/{model_modes,model_modes_coarse}.toml,
                                               # modes.uff, modes_truth.json

The FRF example's sensors (``bracket_example.SENSORS``) include the ribs' normals, (1, 0, 1)/sqrt(2): a
combination of two DOFs that a UFF dataset 55 test DOF (x, y or z at a node) cannot name. A modal test puts a
triaxial accelerometer at each point instead: here each of the six sensor points is a test node (1..6) measured
in x, y and z, 18 test DOFs, every one a single axis, in ``model_modes.toml`` (the default mesh, 33,681 free
DOFs, the model updated) and ``model_modes_coarse.toml`` (the coarse mesh, 8,388 free DOFs).

``modes.uff`` is independent of both: the six lowest modes of the **fine** mesh (``bracket_fine.msh``,
``make_mesh.py --fine``, 105,114 DOFs, regenerated when missing; its own nodes nearest to the points) at the
true factors ``bracket_example.ALPHA_TRUE``, with 0.2 % frequency noise and 2 % shape noise (each value's
standard deviation 2 % of the shape's RMS), seed ``SEED``, as an EMA export (151, 164, 15, one 55 per
mode). ``modes_truth.json``: the truth, the noise, and the discretisation error at the truth (the default and
coarse meshes' frequencies and MAC against the fine mesh's), which the update must absorb through the factors.
About 1-3 minutes on 2 busy cores (the fine mesh's eigen-solve).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.make import bracket_example
from benchmarks.make.bracket_example import ALPHA_TRUE, OUT, SENSORS, SEGMENTS, TOLERANCE, model_text
from tasks.io.measured.modes import MeasuredModes, write_uff55

FREQUENCY_NOISE = 0.002
SHAPE_NOISE = 0.02
N_MODES = 6
SEED = 1
AXES = ("x", "y", "z")


def test_points() -> list[tuple[int, str, list[float]]]:
    """(test node, name, point [m]) of each sensor point of the FRF example, test nodes 1..6."""
    return [(k + 1, name, point) for k, (name, point, _) in enumerate(SENSORS)]


def modal_model_text(mesh: str, tolerance: float, title: str) -> str:
    """The bracket's model file with triaxial test points: ``test_node`` k, directions x, y, z."""
    text = model_text(mesh, tolerance, title).replace("benchmarks.make.bracket_example",
                                                      "benchmarks.make.bracket_modes")
    head, tail = text.split("[[sensors]]", 1)
    excitation = "[[excitations]]" + tail.split("[[excitations]]", 1)[1]
    lines = [head.rstrip() + "\n", "# Modal test points: each FRF sensor's point, measured on x, y and z (test nodes 1..6)."]
    for node, name, point in test_points():
        for axis in AXES:
            lines += [f"[[sensors]]               # the point of the FRF sensor '{name}'", f'name = "p{node} {axis}"', f"point = {point}", f'direction = "{axis}"',
                      f"test_node = {node}", ""]
    return "\n".join(lines) + "\n" + excitation


def write_model_files(out: Path = OUT) -> None:
    (out / "model_modes.toml").write_text(modal_model_text(
        "bracket.msh", TOLERANCE["bracket.msh"], "The tet10 L-bracket (33,681 free DOFs) with 6 triaxial test points."))
    (out / "model_modes_coarse.toml").write_text(modal_model_text(
        "bracket_coarse.msh", TOLERANCE["bracket_coarse.msh"],
        "The L-bracket on the coarse mesh (8,388 free DOFs) with 6 triaxial test points."))


def modes_of(model, n_modes: int = N_MODES):
    """(frequencies Hz, shapes at the model's sensors (n_modes, n_sensors), sensor points [m]) at the truth."""
    from fe_core.solvers.modal import eigenmodes

    alpha, gamma = model.factors(ALPHA_TRUE)
    f, v = eigenmodes(model.stiffness(alpha), model.mass(gamma), n_modes)
    return f, (model.outputs.T @ v).T


def fine_model(out: Path = OUT):
    """The fine mesh with the triaxial test points (regenerated with make_mesh.py --fine when missing)."""
    return bracket_example.fine_model(out, modal_model_text, "The fine mesh (measured modes).")


def main() -> int:
    from fe_core.correlation import mac_matrix
    from fe_core.io import read_model

    write_model_files(OUT)
    t0 = time.perf_counter()
    fine = fine_model(OUT)
    f, shapes = modes_of(fine)
    print(f"fine mesh: {fine.n_dofs} free DOFs, modes {np.round(f, 1).tolist()} Hz, {time.perf_counter() - t0:.0f} s",
          flush=True)
    fine_dofs = fine.n_dofs
    del fine
    rng = np.random.default_rng(SEED)
    fn = f * (1 + FREQUENCY_NOISE * rng.standard_normal(f.size))
    rms = np.sqrt(np.mean(shapes ** 2, axis=1, keepdims=True))
    sn = shapes + SHAPE_NOISE * rms * rng.standard_normal(shapes.shape)
    dofs = [f"{node}:+{axis}" for node, _, _ in test_points() for axis in AXES]
    nodes = {node: tuple(float(c) for c in point) for node, _, point in test_points()}
    write_uff55(OUT / "modes.uff", MeasuredModes(
        fn, np.full(f.size, 0.015), sn, dofs, [f"mode {k + 1}" for k in range(f.size)], ["" for _ in f],
        f"fine-mesh (bracket_fine.msh) modes at alpha {ALPHA_TRUE.tolist()}, {FREQUENCY_NOISE:.1%} frequency and "
        f"{SHAPE_NOISE:.0%} shape noise, seed {SEED}", nodes=nodes))
    discretisation = {}
    for name in ("model_modes.toml", "model_modes_coarse.toml"):
        model = read_model(OUT / name)
        fm, psi = modes_of(model)
        mac = np.diag(mac_matrix(shapes, psi))
        discretisation[name] = {"free_dofs": int(model.n_dofs), "natural_hz": np.round(fm, 2).tolist(),
                                "relative_difference": np.round(fm / f - 1, 5).tolist(),
                                "mac_with_fine": np.round(mac, 4).tolist()}
    truth = {"alpha": ALPHA_TRUE.tolist(), "segments": list(SEGMENTS), "frequency_noise": FREQUENCY_NOISE,
             "shape_noise": SHAPE_NOISE, "seed": SEED, "test_dofs": dofs,
             "fine_mesh": {"file": "bracket_fine.msh (make_mesh.py --fine)", "free_dofs": int(fine_dofs),
                           "natural_hz": np.round(f, 2).tolist()},
             "discretisation_at_truth": discretisation}
    (OUT / "modes_truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    print(json.dumps(discretisation, indent=1))
    print(f"wrote {OUT}: modes.uff ({f.size} modes x {len(dofs)} test DOFs), modes_truth.json, model_modes*.toml "
          f"({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.bracket_modes", __doc__)
    sys.exit(main())
