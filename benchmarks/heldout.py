"""Issue 40's held-out cases run as a user runs the tool, one case at a time, and scored against their truths.

    python -m benchmarks.heldout --set dev                        # every development case (hours)
    python -m benchmarks.heldout --set dev --only dev03 --keep runs/heldout-dev
    python -m benchmarks.heldout --set dev --table                # the table of what has run so far

Each case (``data/cases/held_out/<set>/<id>/truth.json``, made by ``python -m benchmarks.make.cases``) runs

    python -m flows.update --model <model.toml> --measured <measured.csv> --close-loop --run-id <id> --runs-dir <dir>

with the tool's defaults, in a subprocess under the heavy lock (``/work/locks/heavy``, taken here with flock(2)
as ``flock(1)`` takes it, so the wall time excludes the wait) at ``nice -n 5``. From ``summary.json`` and
``closure/closure.json`` it reads the verdict, the first effect added (kind, place, size), the FE runs of the
update and the closure's FE solves. Place error: the distance between the effect found (its node, or its patch's
cells' centroid) and the truth's, over the structure's size (its largest dimension); size error: relative, of
the mass (kg), the spring (N/m) or the patch's factor beta.

Targets (issue 40): an effect of the library is ``explained`` with the right kind, the place within 5 % and the
size within 15 % (the first effect added is scored, as one with the effects of its kind found beside it when
closure.json's ``combined`` takes them as one between nodes; effects added beside it, which the truth lacks, are counted in
each result's ``extra effects`` and in the tally); a clean case is ``noise`` with the update converged and no
effect; an effect outside the library is never ``explained``; every case within 15 min. Results go to
``<out>/results.jsonl`` (one line per case; a case already there is skipped unless ``--rerun``) and the markdown
table to ``<out>/table.md``.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "data" / "cases" / "held_out"
LOCK = Path("/work/locks/heavy")
PLACE, SIZE, MINUTES = 0.05, 0.15, 15.0


def run_case(truth: dict, runs: Path, timeout: float, lock: Path | None = LOCK) -> dict:
    """Run the tool on one case (module docstring); returns the run's facts (exit, wall, load)."""
    cmd = ["nice", "-n", "5", sys.executable, "-m", "flows.update", "--model", str(REPO / truth["model"]),
           "--measured", str(REPO / truth["measured"]), "--close-loop", "--run-id", truth["case"],
           "--runs-dir", str(runs)]
    runs.mkdir(parents=True, exist_ok=True)
    log = runs / f"{truth['case']}.log"
    handle = open(lock, "a") if lock else None
    try:
        if handle:
            fcntl.flock(handle, fcntl.LOCK_EX)
        load0, t0 = os.getloadavg(), time.perf_counter()
        with open(log, "w") as out:
            try:
                code = subprocess.run(cmd, cwd=REPO, stdout=out, stderr=subprocess.STDOUT, timeout=timeout).returncode
            except subprocess.TimeoutExpired:
                code = "timeout"
        wall = time.perf_counter() - t0
        load1 = os.getloadavg()
    finally:
        if handle:
            fcntl.flock(handle, fcntl.LOCK_UN)
            handle.close()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout
    return {"exit": code, "wall_s": round(wall, 1), "load": [round(load0[0], 1), round(load1[0], 1)],
            "log": str(log), "command": " ".join(cmd[3:]), "commit": commit.strip()}


def _deck_coordinates() -> dict:
    from benchmarks.make.cases import deck

    return deck.mesh(deck.MODEL_MESH)[2]


def _solid_mesh(model_file: Path):
    import meshio

    text = model_file.read_text()
    mesh = meshio.read(model_file.parent / re.search(r'^mesh = "(.*)"', text, re.M).group(1))
    return mesh.points, mesh.cells[0].data


def position(location: str | None, details: dict, truth: dict, cache: dict):
    """Where an effect found is, m (3,): its node's coordinates or its patch's centroid; None if it has no place."""
    from benchmarks.make.cases.effects import patch_cells, patch_centre

    hit = re.fullmatch(r"node (\d+)(?: r(\d))?", location or "")
    if hit is None:
        return None
    node = int(hit.group(1))
    if truth["structure"] == "channel_deck":
        coords = cache.setdefault("deck", _deck_coordinates())
        return np.asarray(coords[node]) if node in coords else None
    nodes, cells = cache.setdefault(truth["model"], _solid_mesh(REPO / truth["model"]))
    if hit.group(2) is None:
        return nodes[node]
    return patch_centre(nodes, cells, patch_cells(cells, node, int(hit.group(2))))


def _library_kind(effect: dict) -> str:
    return effect.get("library_kind", effect["kind"])


def score(truth: dict, summary: dict, closure: dict, run: dict, cache: dict) -> dict:
    """One row of the table: what was true, what was found, and the pass/fail per the targets."""
    e = truth["effect"]
    effects = closure.get("effects") or []
    first = effects[0] if effects else {}
    group = closure["combined"][first["combined"]] if "combined" in first else None
    if group is not None:  # found as two or more beside each other: one between nodes, scored as the tool reports it
        at, value = np.asarray(group["position_m"]), group["value"]
    else:
        at = position(first.get("location"), first.get("details") or {}, truth, cache) if first else None
        value = first.get("value")
    size = truth["structure_size_m"]
    place_err = float(np.linalg.norm(np.asarray(at) - e["xyz_m"]) / size) if at is not None and "xyz_m" in e else None
    size_err = (abs(float(value) - e["value"]) / abs(e["value"])
                if isinstance(value, (int, float)) and e.get("value") else None)
    verdict = closure.get("verdict")
    minutes = run["wall_s"] / 60.0
    why = []
    if run["exit"] != 0:
        why.append(f"exit {run['exit']}")
    if truth["expected"] == "explained":
        if verdict != "explained":
            why.append(f"verdict {verdict}")
        if first.get("type") != _library_kind(e):
            why.append(f"kind {first.get('type')}")
        if place_err is None or place_err > PLACE:
            why.append("place")
        if size_err is None or size_err > SIZE:
            why.append("size")
    elif truth["expected"] == "noise":
        if verdict != "noise":
            why.append(f"verdict {verdict}")
        if not summary.get("converged"):
            why.append("not converged")
        if effects:
            why.append(f"{len(effects)} effect(s)")
    elif verdict in ("explained", None):
        why.append(f"verdict {verdict}")
    judged = not why
    if minutes > MINUTES:
        why.append(f"{minutes:.0f} min")
    true = "none" if e["kind"] == "none" else (
        f"{_library_kind(e)} at {e.get('location', e.get('description', ''))} = {e['value']:.4g} {e.get('unit', '')}")
    found = "; ".join(f"{x.get('type')} at {x.get('location')} = {x.get('value', float('nan')):.4g}" for x in effects)
    if group is not None:
        found += f" (steps {', '.join(map(str, group['steps']))}: one of {group['value']:.4g} between their nodes)"
    return {"case": truth["case"], "structure": truth["structure"], "expected": truth["expected"], "true effect": true,
            "found": found or "-", "place error %": None if place_err is None else round(100 * place_err, 2),
            "size error %": None if size_err is None else round(100 * size_err, 1), "verdict": verdict,
            "converged": summary.get("converged"), "update FE runs (eq.)":
                f"{summary.get('fe_evaluations')} ({summary.get('fe_equivalents')})",
            "closure FE solves": closure.get("fe_solves"), "wall min": round(minutes, 1), "load": run["load"],
            "extra effects": _extra(truth["expected"], len(effects) - (len(group["steps"]) - 1 if group else 0)),
            "judged right": judged, "pass": "yes" if not why else "no: " + ", ".join(why)}


COLUMNS = ["case", "structure", "true effect", "found", "place error %", "size error %", "verdict", "converged",
           "update FE runs (eq.)", "closure FE solves", "wall min", "pass"]


def _extra(expected: str, n_effects: int) -> int:
    """Effects the truth lacks: beyond the first (the one scored) for an effect of the library, else every one."""
    return max(n_effects - 1, 0) if expected == "explained" else n_effects


def _extra_of(row: dict) -> int:
    """A row's ``extra effects`` (rows written before the field: counted from ``found``)."""
    if "extra effects" in row:
        return int(row["extra effects"])
    found = row.get("found") or "-"
    return _extra(row["expected"], 0 if found == "-" else found.count("; ") + 1)


def table(rows: list[dict]) -> str:
    """The markdown table and the tally per target."""
    out = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        out.append("| " + " | ".join("-" if r.get(c) is None else str(r[c]) for c in COLUMNS) + " |")
    tally = []
    for expected, label in (("explained", "effects of the library explained, placed within 5 %, sized within 15 %"),
                            ("noise", "clean cases noise and converged"),
                            ("not explained", "effects outside the library not explained")):
        group = [r for r in rows if r["expected"] == expected]
        if group:
            right = [r for r in group if r["judged right"]]
            extra = sum(_extra_of(r) > 0 for r in right)
            tally.append(f"- {label}: {len(right)} of {len(group)}"
                         + (f" ({extra} of them with an effect the truth lacks beside it)" if extra else ""))
    timed = [r for r in rows if r["wall min"] is not None]
    if timed:
        tally.append(f"- within {MINUTES:g} min: {sum(r['wall min'] <= MINUTES for r in timed)} of {len(timed)} "
                     f"(median {np.median([r['wall min'] for r in timed]):.1f} min, longest "
                     f"{max(r['wall min'] for r in timed):.1f} min)")
    tally.append(f"- every target: {sum(r['pass'] == 'yes' for r in rows)} of {len(rows)}")
    return "\n".join(out) + "\n\n" + "\n".join(tally) + "\n"


def main(argv=None) -> int:
    from benchmarks.make.cases import sets

    p = argparse.ArgumentParser(prog="python -m benchmarks.heldout", description=__doc__.split("\n\n")[0])
    p.add_argument("--set", choices=tuple(sets.SETS), required=True)
    p.add_argument("--only", nargs="+", metavar="ID")
    p.add_argument("--keep", type=Path, help="the run folders and results go here (default runs/heldout-<set>)")
    p.add_argument("--root", type=Path, default=ROOT, help="the cases' root (default data/cases/held_out)")
    p.add_argument("--rerun", action="store_true", help="run cases already in results.jsonl again")
    p.add_argument("--table", action="store_true", help="only print the table of the results so far")
    p.add_argument("--timeout", type=float, default=3600.0, help="stop a case after this many seconds (default 3600)")
    p.add_argument("--no-lock", action="store_true", help="do not take /work/locks/heavy")
    args = p.parse_args(argv)
    out = args.keep or REPO / "runs" / f"heldout-{args.set}"
    out.mkdir(parents=True, exist_ok=True)
    results = out / "results.jsonl"
    done = {}
    if results.exists():
        for line in results.read_text().splitlines():
            row = json.loads(line)
            done[row["case"]] = row
    folder = args.root / args.set
    if not folder.is_dir():
        p.error(f"no cases of {args.set} under {args.root} (make them: python -m benchmarks.make.cases --set {args.set}"
                f"{' --out ' + str(args.root) if args.root != ROOT else ''}; or give their root: --root)")
    ids = sorted(p_.name for p_ in folder.iterdir() if (p_ / "truth.json").exists())
    if args.only:
        missing = sorted(set(args.only) - set(ids))
        if missing:
            p.error(f"no case {', '.join(missing)} under {folder} (make it: python -m benchmarks.make.cases "
                    f"--set {args.set} --only {' '.join(missing)})")
        ids = [i for i in ids if i in args.only]
    cache: dict = {}
    for case in ids:
        if args.table or (case in done and not args.rerun):
            continue
        truth = json.loads((folder / case / "truth.json").read_text())
        print(f"{case}: running ({truth['structure']}, {truth['expected']})", flush=True)
        run = run_case(truth, out, args.timeout, None if args.no_lock else LOCK)
        run_dir = out / case
        summary = _json(run_dir / "summary.json")
        closure = _json(run_dir / "closure" / "closure.json")
        row = {**score(truth, summary, closure, run, cache), "run": run}
        done[case] = row
        with open(results, "a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps({k: row[k] for k in COLUMNS}), flush=True)
    rows = [done[c] for c in ids if c in done]
    text = table(rows)
    (out / "table.md").write_text(text)
    print(text)
    return 0


def _json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


if __name__ == "__main__":
    raise SystemExit(main())
