"""The closure's own-error rule on finished held-out runs: is the alpha-only fit's misfit within the model's own error?

    python -m benchmarks.heldout_own_error runs/heldout-heldout5/results.jsonl [more results.jsonl ...]

For each case of ``benchmarks.heldout --keep DIR``'s ``results.jsonl`` whose run folder (beside it) has a closure,
at the closure's alpha-only start (``closure.json``'s ``parameters_before``): the misfit beyond the noise, what one
mode 0.5 % off would leave (:class:`fe_core.closure.far.shifts.ModeShifts`), the per-mode shifts fitted to the
residual, and the verdict with the rule (:func:`fe_core.closure.far.shifts.unclaimed`): ``noise`` when the misfit
is within it and the run's closure added nothing or left structure (``closure.json``'s ``residual_after``), else the
run's own. The rule reads only the baseline and the selection's end, so on a run made before it this is the verdict
the closure would now give (its search is the same). Prints a markdown table; ``--json`` the records.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def rows(results: Path):
    """One record per case of ``results`` (a results.jsonl) whose run folder can be read."""
    from benchmarks.heldout_crossband import stored
    from fe_core.closure.far.shifts import own_error, unclaimed
    from fe_core.closure.fits import Fit

    for line in results.read_text().splitlines():
        r = json.loads(line)
        run = results.parent / r["case"]
        rec = {"case": r["case"], "structure": r["structure"], "effect": r["true effect"],
               "expected": r["expected"], "verdict": r["verdict"]}
        if not (run / "closure" / "closure.json").is_file():
            yield {**rec, "error": "no closure"}
            continue
        t = time.perf_counter()
        try:
            model, freqs, u, sigma, alpha = stored(run)
        except Exception as exc:  # noqa: BLE001 -- a run whose case files are gone is listed, not fatal
            yield {**rec, "error": f"{type(exc).__name__}: {str(exc)[:120]}"}
            continue
        fit = Fit(alpha=alpha, effect=None, location=None, values=[], model_amplitude=None, residual=None,
                  evaluations=0)
        ms = own_error(model, freqs, u, fit, sigma)
        closure = json.loads((run / "closure" / "closure.json").read_text())
        left = unclaimed(ms.within, len(closure["effects"]), bool(closure["residual_after"]["structured"]))
        yield {**rec, "before_pct": 100 * ms.before, "single_pct": 100 * ms.single, "ratio": ms.before / ms.single,
               "largest_shift_pct": 100 * ms.largest, "modes": int(ms.shifts.size), "within": ms.within,
               "rule_verdict": "noise" if left else r["verdict"], "seconds": time.perf_counter() - t}


def table(records) -> str:
    """The records as docs/results/held-out.md shows them (a changed verdict in bold)."""
    lines = ["| case | structure | truth | expected | run's verdict | misfit / one mode off, % (ratio) | largest shift, % "
             "| with the rule |", "|---" * 8 + "|"]
    for r in records:
        if "error" in r:
            lines.append(f"| {r['case']} | {r['structure']} | {r['effect'][:40]} | {r['expected']} | {r['verdict']} | "
                         f"not read ({r['error']}) | | |")
            continue
        verdict = f"**{r['rule_verdict']}**" if r["rule_verdict"] != r["verdict"] else r["rule_verdict"]
        lines.append(f"| {r['case']} | {r['structure']} | {r['effect'][:44]} | {r['expected']} | {r['verdict']} | "
                     f"{r['before_pct']:.2f} / {r['single_pct']:.2f} = {r['ratio']:.2f} | {r['largest_shift_pct']:.2f} "
                     f"| {verdict} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.heldout_own_error", description=__doc__.split("\n")[0])
    p.add_argument("results", nargs="+", type=Path, help="results.jsonl of benchmarks.heldout --keep DIR")
    p.add_argument("--json", action="store_true", help="print the records as JSON lines instead of a table")
    args = p.parse_args(argv)
    records = []
    for path in args.results:
        for rec in rows(path):
            records.append(rec)
            if args.json:
                print(json.dumps(rec), flush=True)
    if not args.json:
        print(table(records))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
