"""``python -m benchmarks.headline``: the command line (the package's docstring says what it does)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from benchmarks.headline import (DEFAULT_LOCK, PAGE, REPO, SECTION, WORK, current, locked, read_row, run_row,
                                 stored, write_page, write_readme)
import benchmarks.headline as headline


def main(argv: list[str] | None = None) -> int:
    from benchmarks.headline.rows import ROWS

    keys = [r.key for r in ROWS]
    p = argparse.ArgumentParser(prog="python -m benchmarks.headline", description=headline.__doc__.split("\n\n")[0])
    p.add_argument("--only", nargs="+", choices=keys, metavar="ROW", help=f"rows to run, of {', '.join(keys)}")
    p.add_argument("--keep", action="store_true", help="skip rows that have a stored result (resume)")
    p.add_argument("--page-only", action="store_true", help="no run: rewrite the page (and README) from stored rows")
    p.add_argument("--reread", action="store_true", help="no run: read the stored rows' outputs again, then write")
    p.add_argument("--no-readme", action="store_true", help="leave README.md's headline table as it is")
    p.add_argument("--lock", default=str(DEFAULT_LOCK) if DEFAULT_LOCK.exists() else "none",
                   help="file to flock while a row runs ('none': no lock; default /work/locks/heavy when present)")
    p.add_argument("--lock-per-row", action="store_true",
                   help="release the lock between rows (default: hold it for the whole run, one heavy job: on a "
                        "busy machine a row that queues again for the lock can wait an hour)")
    p.add_argument("--list", action="store_true", help="print the rows and their commands, run nothing")
    args = p.parse_args(argv)
    if args.list:
        for r in ROWS:
            print(f"{r.key}: {r.what}")
            for cmd, env in r.commands:
                print("    " + " ".join([*(f"{k}={v}" for k, v in env.items()), "python -m", *cmd]))
            if r.note:
                print(f"    note: {r.note}")
        return 0
    lock = None if args.lock == "none" else Path(args.lock)
    t0 = time.perf_counter()
    ran = []
    todo = [] if (args.page_only or args.reread) else \
        [r for r in ROWS if not ((args.only and r.key not in args.only) or (args.keep and stored(r.key)))]
    if todo:
        with locked(None if args.lock_per_row else lock) as waited:
            for r in todo:
                print(f"[{r.key}] {r.what}", flush=True)
                rec = run_row(r, lock if args.lock_per_row else None, held=lock is not None and not args.lock_per_row)
                if not args.lock_per_row and r is todo[0]:
                    rec["lock_wait_s"] = round(waited, 1)
                ran.append(rec)
                print(f"[{r.key}] {rec['wall_s']:.0f} s: {rec['result'] or rec['error']}", flush=True)
    records = current([r.key for r in ROWS])
    if args.reread:
        for r in ROWS:
            rec = stored(r.key)
            if rec:
                records[r.key] = rec
                rec.update(read_row(r, WORK / r.key, rec["commands"]))
                (WORK / r.key / "row.json").write_text(json.dumps(rec, indent=1, default=str))
    total = {}
    if ran:
        elapsed = time.perf_counter() - t0
        total["text"] = (f"; this invocation ran {len(ran)} row(s) in {elapsed / 60:.1f} min including "
                         f"{sum(r['lock_wait_s'] for r in ran) / 60:.1f} min waiting for the lock")
    write_page(ROWS, records, total)
    print(f"wrote {PAGE.relative_to(REPO)}")
    failed = [k for k, v in records.items() if v and v["error"]]
    missing = [k for k, v in records.items() if not v]
    if args.no_readme:
        pass
    elif failed or missing:
        print("README.md left as it is: not every row has a result", file=sys.stderr)
    else:
        write_readme(ROWS, records)
        print(f"rewrote the table under '{SECTION}' in README.md")
    if failed or missing:
        print(f"failed: {failed or '-'}; not run: {missing or '-'}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
