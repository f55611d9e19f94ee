"""Far-effect cases (issue 40, item 2) as users run them: ``python -m flows.update --model M --measured D
--close-loop`` per case, the verdict, the effect found against the truth, FE runs and wall time.

    python -m benchmarks.make.far_effects                     # the cases (runs/far_effects/<case>/)
    flock /work/locks/heavy nice -n 5 python -m benchmarks.far_effects --set dev --out runs/far_effects/table-dev
    python -m benchmarks.far_effects --set check ...          # the check cases, looked at once, at the end
    python -m benchmarks.far_effects --only plate-mass-4 --extra="--n-jobs 2"

Place error: the distance between the effect found and the truth's node over the structure's size (the diagonal
of its nodes' bounding box); size error: relative. A case meets the criteria of issue 40 when an effect case is
``explained`` with the place within 5 % and the size within 15 %, a clean case is ``noise`` (converged), and an
effect outside the library is not ``explained``. Each case's run folder is kept under ``--out`` (its
``summary.json``, ``closure/closure.json`` and the command's log); the table is printed and written as
``table.md`` and ``rows.json`` there.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
CASES = REPO / "runs" / "far_effects"


def _position(model, location: str):
    if not location or not location.startswith("node "):
        return None
    return model.node_position(int(location.split()[1].split()[0]))


def evaluate(case_dir: Path, run_dir: Path) -> dict:
    """The row of one finished case: truth against summary.json and closure.json."""
    from fe_core.io import read_model

    truth = json.loads((case_dir / "truth.json").read_text())
    summary = json.loads((run_dir / "summary.json").read_text()) if (run_dir / "summary.json").exists() else {}
    cfile = run_dir / "closure" / "closure.json"
    closure = json.loads(cfile.read_text()) if cfile.exists() else {}
    effects = closure.get("effects", [])
    added = [e for e in effects if e.get("status", "added") == "added"] or effects
    te = truth.get("effect")
    row = {"case": truth["case"], "expected": truth["expected"], "verdict": closure.get("verdict", "-"),
           "converged": summary.get("converged"), "found": "; ".join(
               f"{e['type']} at {e['location']} = {e['value']:.4g}" for e in added) or "-",
           "place error": None, "size error": None,
           "update FE runs": summary.get("fe_evaluations"), "update FE-run eq.": summary.get("fe_equivalents"),
           "closure FE solves": closure.get("fe_solves"), "closure s": closure.get("wall_seconds"),
           "misfit left": closure.get("smooth_misfit")}
    if te is not None and te["kind"] != "layer":
        row["truth"] = f"{te['kind']} at node {te['node']} = {te['value']:.4g}"
    else:
        row["truth"] = "-" if te is None else f"{te['kind']} ({te['share']:.0%} of the mass, outside the library)"
    if te is not None and te["kind"] != "layer" and added:
        model = read_model(case_dir / "model.toml")
        first = min(added, key=lambda e: np.linalg.norm((_position(model, e["location"]) if _position(
            model, e["location"]) is not None else np.full(3, np.inf)) - np.asarray(te["position"])))
        p = _position(model, first["location"])
        if p is not None:
            row["place error"] = float(np.linalg.norm(p - np.asarray(te["position"])) / truth["size_m"])
        if first["type"].startswith(te["kind"][:15]):
            row["size error"] = abs(float(first["value"]) - te["value"]) / te["value"]
    row["meets"] = meets(row)
    return row


def meets(row: dict) -> bool:
    if row["expected"] == "explained":
        return (row["verdict"] == "explained" and row["place error"] is not None and row["place error"] <= 0.05
                and row["size error"] is not None and row["size error"] <= 0.15)
    if row["expected"] == "noise":
        return row["verdict"] in ("noise", "-") and bool(row["converged"])
    return row["verdict"] != "explained"


def run_case(case_dir: Path, out: Path, extra: list[str], repo: Path = REPO, timeout: float | None = None) -> dict:
    run_dir = out / case_dir.name
    log = out / f"{case_dir.name}.log"
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "flows.update", "--model", str(case_dir / "model.toml"), "--measured",
           str(case_dir / "measured.csv"), "--close-loop", "--run-id", case_dir.name, "--runs-dir", str(out), *extra]
    t0 = time.perf_counter()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    with open(log, "w") as f:
        proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, cwd=repo, start_new_session=True,
                                env={**os.environ, "PYTHONPATH": str(repo)})
        try:
            code = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:  # the command, its workers and its Prefect server: its own group
            os.killpg(proc.pid, signal.SIGTERM)
            time.sleep(10)
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            code = "timeout"
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    row = evaluate(case_dir, run_dir)
    row.update({"exit": code, "wall s": round(wall, 1),
                "cpu s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 1),
                "peak GB": round(after.ru_maxrss / 1e6, 2), "load": os.getloadavg()[0]})
    return row


COLUMNS = ("case", "truth", "verdict", "found", "place error", "size error", "misfit left", "update FE runs",
           "update FE-run eq.", "closure FE solves", "wall s", "meets")


def table(rows: list[dict]) -> str:
    def fmt(v):
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.3g}" if abs(v) >= 1e-3 or v == 0 else f"{v:.2e}"
        return str(v)
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in COLUMNS) + " |" for r in rows]
    return "\n".join(lines)


def main(argv=None) -> int:
    from benchmarks.make.far_effects.cases import CHECK, DEV

    p = argparse.ArgumentParser(prog="python -m benchmarks.far_effects", description=__doc__.split("\n\n")[0])
    p.add_argument("--set", choices=("dev", "check"), default="dev")
    p.add_argument("--only", nargs="+", help="case names (default: the set's)")
    p.add_argument("--cases", type=Path, default=CASES, help="where the generated cases are")
    p.add_argument("--out", type=Path, default=CASES / "table", help="run folders, logs and the table")
    p.add_argument("--extra", default="", help="more options of flows.update, one string")
    p.add_argument("--evaluate", action="store_true", help="only tabulate the run folders already in --out")
    p.add_argument("--repo", type=Path, default=REPO, help="the code to run (another worktree: the code before)")
    p.add_argument("--timeout", type=float, help="seconds per case before it is stopped")
    args = p.parse_args(argv)
    names = args.only or [c.name for c in (DEV if args.set == "dev" else CHECK)]
    rows = []
    for name in names:
        case_dir = args.cases / name
        if args.evaluate:
            row = evaluate(case_dir, args.out / name)
        else:
            row = run_case(case_dir, args.out, shlex.split(args.extra), args.repo, args.timeout)
        rows.append(row)
        print(json.dumps(row), flush=True)
    text = table(rows)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "table.md").write_text(text + "\n")
    (args.out / "rows.json").write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
