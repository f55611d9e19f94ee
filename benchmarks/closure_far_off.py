"""Far-off models (issue 28): the plain command with ``--close-loop`` on data carrying a sizeable undeclared effect.

    python -m benchmarks.closure_far_off --make      # (re)write data/cases/far_off_masses/*.csv and truth.json
    nice -n 10 python -m benchmarks.closure_far_off  # the table (docs/guide/closure-far-off.md)

Cases (truths in ``data/cases/far_off_masses/truth.json``; measured data from a model other than the one fitted):

* ``cantilever-1.9%``: ``data/examples/cantilever_matrices/measured_point_mass.csv``, scikit-fem's own FRF of the
  beam carrying a 0.6 kg point mass at node 208 (1.9 % of its 31.4 kg), 0.5 % noise;
* ``cantilever-5%``, ``cantilever-10%``: the exported matrices with a point mass of 5 % / 10 % of the beam's mass at
  node 208 added (direct solve), the truth's alpha, 0.5 % noise (``--make``);
* ``benchmark-2%``: ``data/cases/three_plate_effects/point_mass.csv`` (three-plate benchmark, 0.12 kg, 2.1 %, 0.5 % noise);
* ``benchmark-5%``: the benchmark at the SPEC's alpha with 0.29 kg (5 %) at node 337 (direct solve), 0.5 % noise;
* ``cantilever-spring``: the exported matrices with a 3e5 N/m spring to ground along y at node 208 (a stiff mount;
  direct solve), 0.5 % noise.

Per case: the update's evidence decision, its FE runs and FE-run equivalents, the closure's verdict, whether it
named the right kind at the right node, the size's error, wall time.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "data" / "cases" / "far_off_masses"
CANTILEVER = "data/examples/cantilever_matrices/model.toml"
NOISE = 0.005


def _cases() -> list[dict]:
    truth = json.loads((OUT / "truth.json").read_text())
    skfem = json.loads((REPO / "data/examples/cantilever_matrices/truth.json").read_text())["point_mass"]
    effects = json.loads((REPO / "data/cases/three_plate_effects/truth.json").read_text())["data"]["point_mass.csv"]
    cases = [{"case": "cantilever-1.9%", "model": CANTILEVER,
              "measured": "data/examples/cantilever_matrices/measured_point_mass.csv",
              "node": skfem["node"], "mass_kg": skfem["mass_kg"]},
             {"case": "benchmark-2%", "model": "three_plate", "measured": "data/cases/three_plate_effects/point_mass.csv",
              "node": effects["node"], "mass_kg": effects["value"]}]
    cases += [{"case": name, "model": t["model"], "measured": f"data/cases/far_off_masses/{t['file']}", "node": t["node"],
               "mass_kg": t.get("mass_kg", t.get("k_N_per_m")), "effect": t["effect"]} for name, t in truth.items()]
    return cases


def make() -> None:
    """Write the generated cases' data and truths (data/cases/far_off_masses/)."""
    from fe_core.benchmark import ALPHA_ACTUAL, three_plate
    from fe_core.closure.effects import Applied, GroundedSpring, PointMass, extended_frf
    from flows.problem import load_model
    from tasks.io.measured import MeasuredFRF, read_measured, write_measured

    OUT.mkdir(parents=True, exist_ok=True)
    beam = load_model(CANTILEVER)[0]
    skfem = json.loads((REPO / "data/examples/cantilever_matrices/truth.json").read_text())
    bench_lines = read_measured(REPO / "data/cases/three_plate_effects/point_mass.csv").frequencies_hz
    beam_lines = np.asarray(skfem["point_mass"]["frequencies_hz"], float)
    specs = [("cantilever-5%", beam, CANTILEVER, np.asarray(skfem["alpha"]), 208, 0.05, beam_lines, 21),
             ("cantilever-10%", beam, CANTILEVER, np.asarray(skfem["alpha"]), 208, 0.10, beam_lines, 22),
             ("benchmark-5%", three_plate(), "three_plate", ALPHA_ACTUAL, 337, 0.05, bench_lines, 23)]
    truth = {}
    for name, model, ref, alpha, node, share, freqs, seed in specs:
        mass = share * float(model.total_mass())
        Z = extended_frf(model, alpha, freqs, [Applied(PointMass(model), f"node {node}", np.array([mass]))],
                         method="direct")
        u = np.abs(Z) * (1.0 + NOISE * np.random.default_rng(seed).standard_normal(Z.shape))
        file = f"{name.replace('%', 'pc')}.csv"
        write_measured(OUT / file, MeasuredFRF(frequencies_hz=freqs, sensors=list(range(1, u.shape[1] + 1)),
                                               amplitude=u, source=f"{ref} + {mass:.4g} kg at node {node}, direct"))
        truth[name] = {"file": file, "model": ref, "alpha": [float(a) for a in alpha], "effect": "point_mass",
                       "node": node, "mass_kg": mass, "share_of_mass": share, "noise": NOISE, "seed": seed}
    # A stiff mount: a spring to ground along y (the bending direction the sensors see) at node 208, 3e5 N/m.
    k, seed = 3e5, 24
    spring = GroundedSpring(beam, component=1)
    spring.kind = "grounded_spring_y"
    Z = extended_frf(beam, skfem["alpha"], beam_lines, [Applied(spring, "node 208", np.array([k]))], method="direct")
    u = np.abs(Z) * (1.0 + NOISE * np.random.default_rng(seed).standard_normal(Z.shape))
    write_measured(OUT / "cantilever-spring.csv", MeasuredFRF(
        frequencies_hz=beam_lines, sensors=list(range(1, u.shape[1] + 1)), amplitude=u,
        source=f"{CANTILEVER} + spring to ground along y, {k:.3g} N/m at node 208, direct"))
    truth["cantilever-spring"] = {"file": "cantilever-spring.csv", "model": CANTILEVER, "alpha": skfem["alpha"],
                                  "effect": "grounded_spring_y", "node": 208, "k_N_per_m": k, "noise": NOISE,
                                  "seed": seed}
    (OUT / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")


def run_case(case: dict, work: Path) -> dict:
    from flows import update

    t0 = time.perf_counter()
    runs = work / case["case"]
    code = update.main(["--model", case["model"], "--measured", case["measured"], "--run-id", "run", "--runs-dir",
                        str(runs), "--no-intervals", "--n-jobs", "1", "--close-loop", *case.get("args", ())])
    wall = time.perf_counter() - t0
    summary = json.loads((runs / "run" / "summary.json").read_text())
    closure_file = runs / "run" / "closure" / "closure.json"
    closure = json.loads(closure_file.read_text()) if closure_file.exists() else {}
    effects = closure.get("effects", [])
    first = effects[0] if effects else {}
    value = first.get("value", np.nan) if first else np.nan
    ev = summary.get("evidence") or {}
    return {"case": case["case"], "exit": code, "evidence": ev.get("choice"),
            "update FE runs": summary["fe_evaluations"], "update FE-run equivalents": summary["fe_equivalents"],
            "verdict": closure.get("verdict"),
            "effect": f"{first.get('type')} at {first.get('location')} ({first.get('value', np.nan):.4g})" if first else "-",
            "kind right": bool(first) and first.get("type") == case.get("effect", "point_mass"),
            "node right": bool(first) and first.get("location") == f"node {case['node']}",
            "size error": abs(float(value) - case["mass_kg"]) / case["mass_kg"] if first else np.nan,
            "wall s": round(wall, 1)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.closure_far_off", description=__doc__.split("\n\n")[0])
    p.add_argument("--make", action="store_true", help="write data/cases/far_off_masses/ and stop")
    p.add_argument("--only", nargs="+", help="case names")
    args = p.parse_args(argv)
    if args.make:
        make()
        return 0
    import pandas as pd

    rows = []
    with tempfile.TemporaryDirectory(prefix="far-off-") as work:
        for case in _cases():
            if args.only and case["case"] not in args.only:
                continue
            rows.append(run_case(case, Path(work)))
            print(rows[-1], flush=True)
    table = pd.DataFrame(rows)
    print("| " + " | ".join(table.columns) + " |\n|" + "---|" * len(table.columns))
    for row in table.itertuples(index=False):
        print("| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in row) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
