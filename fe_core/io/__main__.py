"""Check a model file and print what it describes: ``python -m fe_core.io path/to/model.toml``.

Exit code 2 with the file and key named when the model is refused (as ``flows.update`` would).
"""

from __future__ import annotations

import sys

import numpy as np

from . import ModelFileError, read_model


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1 or argv[0].startswith("-"):
        print("usage: python -m fe_core.io MODEL.toml", file=sys.stderr)
        return 2
    try:
        model = read_model(argv[0])
    except ModelFileError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    kind = "matrices" if model.mesh is None else f"{model.mesh.n_cells} cells, {model.mesh.n_nodes} nodes"
    print(f"{argv[0]}: {kind}, {model.n_dofs} free DOFs, total mass {model.total_mass():.6g} kg")
    for i, name in enumerate(model.segment_names):
        gamma = f", gamma_{i + 1} (its mass factor)" if i in model.mass_parameters else ""
        print(f"  alpha_{i + 1}{gamma}: segment {name!r}, {model.segment_masses[i]:.6g} kg")
    if model.remainder_mass:
        print(f"  fixed remainder: {model.remainder_mass:.6g} kg")
    for line in model.placements:
        print(f"  {line}")
    freqs = model.natural_frequencies(np.zeros(model.n_segments), n_modes=min(6, model.n_dofs - 1))
    print("  natural frequencies at alpha = 0: " + ", ".join(f"{f:.5g}" for f in freqs) + " Hz")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
