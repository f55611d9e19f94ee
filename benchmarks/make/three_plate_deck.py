"""Example: the benchmark's three-plate structure as a CalculiX deck of C3D8I (incompatible-modes) bricks.

    python -m benchmarks.make.three_plate_deck     # data/examples/three_plate_ccx/

The mesh is ``data/benchmark/three_plate.inp`` (meshio's Abaqus file: 1230 nodes, 544 bricks, the six
segment sets and the clamped node set), with the element type set to C3D8I, the node coordinates
rewritten in at most 20 characters a number (ccx's field limit), one steel material, one
``*SOLID SECTION`` per segment and ``*BOUNDARY`` on the clamped nodes. ``model.toml`` is the benchmark's
model file with the deck in place of the mesh (the same damping, sensors and excitations);
the measured data are the benchmark's own (``data/benchmark/measured.csv``), ``truth.json`` its factors.
"""

from __future__ import annotations

import json
from pathlib import Path

from fe_core.io.calculix import read_deck

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "data" / "examples" / "three_plate_ccx"
SEGMENTS = [f"segment{i}" for i in range(1, 7)]


def deck_text() -> str:
    deck = read_deck(REPO / "data" / "benchmark" / "three_plate.inp")
    nodes = next(c for c in deck.cards if c.keyword == "*NODE")
    nodes.data = [(", ".join(f"{float(v):.15g}" for v in text.split(",")), f, ln) for text, f, ln in nodes.data]
    element = next(i for i, c in enumerate(deck.cards) if c.keyword == "*ELEMENT")
    extra = ("*MATERIAL, NAME=STEEL\n*ELASTIC\n2.06e11, 0.3\n*DENSITY\n7850.\n"
             + "".join(f"*SOLID SECTION, ELSET={s}, MATERIAL=STEEL\n" for s in SEGMENTS)
             + "*BOUNDARY\nclamped, 1, 3\n")
    text = deck.text(params={element: {"TYPE": "C3D8I"}}, extra=extra, steps="")
    return "** the benchmark's three-plate structure, C3D8I (benchmarks/make/three_plate_deck.py)\n" + text


def main(out: Path = OUT) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "three_plate.inp").write_text(deck_text())
    toml = (REPO / "data" / "benchmark" / "model.toml").read_text()
    rest = toml[toml.index("[[sensors]]"):]
    head = ("# The benchmark's three-plate structure as a CalculiX deck of C3D8I bricks "
            "(python -m benchmarks.make.three_plate_deck).\n"
            'units = "SI"\nsolver = "calculix"\ndeck = "three_plate.inp"\npoint_tolerance = 1e-6\n'
            'excitation = "combined"\n\n[damping]\na = 0.01\nb = 0.0001\n\n'
            + "".join(f'[[segments]]\nset = "{s}"\n\n' for s in SEGMENTS))
    (out / "model.toml").write_text(head + rest)
    expected = json.loads((REPO / "data" / "benchmark" / "expected.json").read_text())
    actual = expected["actual"]
    actual = json.loads(actual.replace("'", '"')) if isinstance(actual, str) else actual
    (out / "truth.json").write_text(json.dumps({"parameters": actual["alpha"],
                                                "measured": "../../benchmark/measured.csv"}, indent=1) + "\n")


if __name__ == "__main__":
    import argparse

    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    main()
