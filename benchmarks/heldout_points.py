"""How much of a held-out case's model error is where the sensors and the hammer sit, not the mesh?

    python -m benchmarks.heldout_points dev03 dev04 ho20      # about a minute a case (two spectral solves)

The generator (:mod:`benchmarks.make.cases`) puts every sensor and the hammer of the data at the data mesh's vertex
nearest the structure's point, and the tool takes its own mesh's node nearest the same point: on the holed plate
the two are up to 8.7 mm apart, on a plate whose tenth mode is at 921 Hz. Per case, at its true factors and
without its effect (the structure alone), the data model's FRF (:func:`benchmarks.make.cases.fem_data.spectral`,
every mode to twice the top line and the static remainder) against the tool's FRF at the same factors, on every
line of the case, as the rms of ``ln |Z_tool / Z_data|`` over all values and per sensor:

* **as generated**: the data's outputs and load at their mesh's nearest vertices;
* **at the tool's points**: the data's outputs and load interpolated at the points of the tool's chosen nodes (the
  data basis's shape functions, ``skfem``'s ``probes``; a force at a point is the transpose of that row).

What is left in the second is the mesh (and element) alone. The solid structures only: the frame and the deck share
their nodes with the tool. Nothing of the tool is set from these figures (docs/results/held-out.md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "data" / "cases" / "held_out"


def tool_points(model) -> tuple[np.ndarray, np.ndarray]:
    """The points (m) of the tool's nodes under its sensors (n_sensors, 3) and under its excitation (3,): the
    node of each output column and of the load vector's entries (a sensor or load along a direction that combines
    DOFs sits on one node)."""
    nodes = model.mesh.nodes
    L = model.outputs.tocsc()

    def node_of(rows) -> int:
        found = sorted({int(model.free_dofs[r]) // 3 for r in rows})
        if len(found) != 1:
            raise ValueError(f"a sensor or the excitation on {len(found)} nodes: {found}")
        return found[0]
    sensors = np.array([nodes[node_of(L.indices[L.indptr[j]:L.indptr[j + 1]])] for j in range(L.shape[1])])
    return sensors, nodes[node_of(np.flatnonzero(np.asarray(model.load)))]


def compare(case: str, root: Path = ROOT) -> dict:
    """The two misfits of one case (module docstring)."""
    from benchmarks.make.cases import fem_data as fd, solids
    from benchmarks.make.cases.fem_data import point_row
    from fe_core.io import read_model

    where = "dev" if case.startswith("dev") else "heldout"
    truth = json.loads((root / where / case / "truth.json").read_text())
    name = truth["structure"]
    folder = root / "structures" / name
    model = read_model(folder / "model.toml")
    s = solids.structure(name)
    d = fd.data_model(s)
    alpha = np.asarray(truth["factors"], float)
    free = d["free"]
    Kc, Mc = fd.condensed(*fd.assembled(d, alpha), free)
    sensors, hammer = tool_points(model)
    out_at = np.array([point_row(d["basis"], p, dirn) for p, (_, _, dirn) in zip(sensors, s["sensors"])])
    load_at = point_row(d["basis"], hammer, s["excitation"][2])
    lines = truth["lines"]
    f = np.arange(1, int(round(lines["top_hz"] / lines["step_hz"])) + 1) * lines["step_hz"]
    damping = tuple(json.loads((folder / "structure.json").read_text())["damping"])
    t0 = time.perf_counter()
    Z_tool = model.frf(alpha, f)
    out = {"case": case, "structure": name, "lines": int(f.size)}
    apart = [float(np.linalg.norm(d["nodes"][v] - p)) for v, p in zip(d["sensor_vertices"], sensors)]
    out["sensors_apart_mm"] = [round(1e3 * a, 2) for a in apart]
    out["hammer_apart_mm"] = round(1e3 * float(np.linalg.norm(d["nodes"][d["load_vertex"]] - hammer)), 2)
    for key, outputs, load in (("as_generated", d["outputs"], d["load"]), ("at_tool_points", out_at, load_at)):
        Z = fd.modal_frf(fd.spectral(Kc, Mc, outputs[:, free], load[free], 2.0 * lines["top_hz"]), damping, f)
        r = np.log(np.abs(Z_tool) / np.abs(Z))
        out[key] = {"rms": float(np.sqrt(np.mean(r**2))), "mean_abs": float(np.mean(np.abs(r))),
                    "per_sensor_rms": np.round(np.sqrt(np.mean(r**2, axis=0)), 4).tolist()}
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.heldout_points", description=__doc__.split("\n\n")[0])
    p.add_argument("cases", nargs="+", help="case ids (dev01.., ho01..) whose data are generated")
    p.add_argument("--json", type=Path, help="also write the figures here")
    args = p.parse_args(argv)
    rows = []
    print("| case | structure | sensors apart, mm | hammer apart, mm | rms ln-ratio as generated | at the tool's points |")
    print("|---|---|---|---|---|---|")
    for c in args.cases:
        r = compare(c)
        rows.append(r)
        print(f"| {c} | {r['structure']} | {min(r['sensors_apart_mm']):.1f}-{max(r['sensors_apart_mm']):.1f} | "
              f"{r['hammer_apart_mm']:.1f} | {100 * r['as_generated']['rms']:.1f} % | "
              f"{100 * r['at_tool_points']['rms']:.1f} % |", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
