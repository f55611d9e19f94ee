"""The modal example: the benchmark measured as 6 modes at 18 test nodes (data/examples/modal/).

Writes ``model.toml`` (the benchmark mesh with 18 z-sensors, ``test_node`` 101..118: in each segment at a
quarter of its length at y = +-20 mm and at three quarters on the centre line) and the measured modes:
the 6 lowest modes at the SPEC's actual alpha (:func:`reference_modes`: the SPEC's independent frequencies,
or a twice finer mesh), read at the test nodes, with 0.2 % frequency noise and 2 % shape noise (each
value's standard deviation 2 % of the shape's RMS), seeded:

- ``modes.uff``: EMA-like, datasets 151, 164, 15 and one 55 per mode (mass-normalised shapes), "spec";
- ``modes_oma.csv``: OMA-like, the same modes with shapes scaled arbitrarily per mode and the 5th missing;
- ``modes_finer_mesh.uff``: as ``modes.uff`` from the twice finer mesh (discretisation error included).

    python -m benchmarks.make.modal_example
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fe_core.benchmark import ALPHA_ACTUAL, PLATES, THICKNESS, segment_bounds, three_plate
from tasks.io.measured.modes import MeasuredModes, write_csv, write_uff55

OUT = Path(__file__).resolve().parents[2] / "data" / "examples" / "modal"
FREQUENCY_NOISE = 0.002
SHAPE_NOISE = 0.02
N_MODES = 6
REFINE = (2, 2, 2)


def test_points() -> np.ndarray:
    """The 18 test points (m), in test-node order 101..118."""
    points = []
    for x0, x1 in segment_bounds():
        q, t = x0 + 0.25 * (x1 - x0), x0 + 0.75 * (x1 - x0)
        points += [(q, 0.02, THICKNESS), (q, -0.02, THICKNESS), (t, 0.0, THICKNESS)]
    return np.array(points)


def model_toml() -> str:
    head = Path(__file__).resolve().parents[2] / "data" / "benchmark" / "model.toml"
    text = head.read_text().split("[[sensors]]")[0]
    text = text.replace('mesh = "three_plate.inp"', 'mesh = "../../benchmark/three_plate.inp"')
    text = text.replace("# The three-plate benchmark (shared/benchmark/SPEC.md) as a model file.",
                        "# The three-plate benchmark with 18 test nodes for modal data (docs/guide/modal-data.md).")
    text = text.replace("# Written by python -m benchmarks.make.benchmark_model; the name three_plate is a shortcut to it.",
                        "# Written by python -m benchmarks.make.modal_example.")
    text = "\n".join(line for line in text.splitlines() if not line.startswith("excitation ="))+ "\n"
    out = [text]
    for k, p in enumerate(test_points()):
        out.append(f'[[sensors]]\nname = "t{101 + k}"\npoint = [{float(p[0])!r}, {float(p[1])!r}, {float(p[2])!r}]\ndirection = "z"\n'
                   f"test_node = {101 + k}\n\n")
    out.append('[[excitations]]\nname = "hammer"  # modal data need no excitation; a model file names one\n'
               f"point = [{float(test_points()[0][0])!r}, 0.02, 0.01]\ndirection = \"z\"\n")
    return "".join(out).rstrip() + "\n"


def reference_modes(source="spec", alpha=ALPHA_ACTUAL, n_modes=N_MODES):
    """(freqs Hz, shapes at the test points' u_z (n_modes, 18)) of the reference.

    ``"spec"``: the frequencies of the SPEC's independent implementation (``data/benchmark/expected.json``,
    actual alpha), the shapes of the SPEC mesh built by :func:`fe_core.benchmark.three_plate` (the update
    reads the model file instead); ``"finer"``: frequencies and shapes of the plates meshed twice as finely
    in x, y and z (20,331 DOFs), which carries the benchmark mesh's discretisation error (0.2-1.1 % in
    frequency) on top of the noise.
    """
    import json

    if source == "spec":
        model = three_plate()
        expected = json.loads((OUT.parents[1] / "benchmark" / "expected.json").read_text())["actual"]
        assert np.allclose(expected["alpha"], alpha), "the SPEC's frequencies are those of its actual alpha"
        freqs, shapes, _ = model.modes(np.asarray(alpha, float), n_modes)
        reference = np.asarray(expected["frequencies_Hz"][:n_modes])
        assert np.allclose(freqs, reference, rtol=1e-7), (freqs, reference)
        freqs = reference
    else:
        model = three_plate(refine=REFINE)
        freqs, shapes, _ = model.modes(np.asarray(alpha, float), n_modes)
    nodes = [model.mesh.nearest_node(p) for p in test_points()]
    assert np.allclose(model.mesh.nodes[nodes], test_points(), atol=1e-9)
    return freqs, shapes[:, nodes, 2]


def noisy(freqs, shapes, seed, frequency_noise=FREQUENCY_NOISE, shape_noise=SHAPE_NOISE):
    rng = np.random.default_rng(seed)
    f = freqs * (1 + frequency_noise * rng.standard_normal(freqs.size))
    rms = np.sqrt(np.mean(shapes ** 2, axis=1, keepdims=True))
    return f, shapes + shape_noise * rms * rng.standard_normal(shapes.shape)


def as_modes(f, shapes, keep=None, scales=None, source="") -> MeasuredModes:
    keep = list(range(f.size)) if keep is None else list(keep)
    s = shapes[keep] * (1.0 if scales is None else np.asarray(scales)[:, None])
    return MeasuredModes(f[keep], np.full(len(keep), 0.005), s, [f"{101 + k}:+z" for k in range(s.shape[1])],
                         [f"mode {k + 1}" for k in keep], ["" for _ in keep], source,
                         nodes={101 + k: tuple(p) for k, p in enumerate(test_points())})


def main() -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "model.toml").write_text(model_toml())
    freqs, shapes = reference_modes("finer")
    f, s = noisy(freqs, shapes, seed=1)
    write_uff55(OUT / "modes_finer_mesh.uff", as_modes(f, s))
    freqs, shapes = reference_modes("spec")
    f, s = noisy(freqs, shapes, seed=1)
    write_uff55(OUT / "modes.uff", as_modes(f, s))
    rng = np.random.default_rng(2)
    keep = [0, 1, 2, 3, 5]
    scales = rng.choice([-1, 1], len(keep)) * rng.uniform(0.1, 10, len(keep))
    write_csv(OUT / "modes_oma.csv", as_modes(f, s, keep, scales))
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.modal_example", __doc__)
    raise SystemExit(main())
