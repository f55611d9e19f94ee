"""Rerun every row of the README's ``## Headline results`` table and write ``docs/results/headline.md``.

    nice -n 5 python -m benchmarks.headline                     # every row (about 1.5 h on 2 quiet cores)
    nice -n 5 python -m benchmarks.headline --only main hammer  # some rows; the others' stored results are kept
    nice -n 5 python -m benchmarks.headline --keep              # resume: rerun only rows with no stored result
    python -m benchmarks.headline --page-only                   # rewrite the page and the README table, no run
    python -m benchmarks.headline --list                        # the rows, their commands and notes

Each row (``benchmarks/headline/rows.py``) runs its commands one after another as child processes
(``python -m ...`` from the repository's root), the rows one at a time under an exclusive lock on ``--lock``
(default ``/work/locks/heavy`` when it exists: one heavy job at a time on a shared machine), held for the whole
run (``--lock-per-row`` releases it between rows); the wait is not counted.
Per command the wall time, the CPU time (user + system of the child and the processes it waited for) and
the peak resident memory (``os.wait4``) are measured; the load average before and after is recorded. Outputs
and logs go to ``runs/headline/<row>/``; ``row.json`` there holds the row's commit (``git rev-parse
--short HEAD``), whether the tree was clean, the date, the timings and the figures read from the outputs.

The page is written from the rows' records: each row's newer of its ``row.json`` here and its record in
``docs/results/headline.json`` (committed beside the page, rewritten with it), so ``--only`` on a fresh clone
reruns some rows and keeps the others as the page had them; ``--keep`` resumes a partial run. The README's
headline table is rewritten from the same figures (``--no-readme`` leaves it): the README's
result column is then exactly what the page measured. ``tests/test_docs.py`` checks that every number of
that column is on the page and that the page's commits are at most 40 commits of code or data behind HEAD.
"""

from __future__ import annotations

import datetime as dt
import fcntl
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PAGE = REPO / "docs" / "results" / "headline.md"
RECORDS = REPO / "docs" / "results" / "headline.json"     # the page's rows, committed: what --only keeps
README = REPO / "README.md"
WORK = REPO / "runs" / "headline"
DEFAULT_LOCK = Path("/work/locks/heavy")
SECTION = "## Headline results"


def git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def provenance() -> dict:
    """The commit the code ran on, whether tracked files other than the docs had changes, date and machine.

    docs/ and README.md do not count: this command writes them, and they do not change what runs."""
    status = git("status", "--porcelain", "--untracked-files=no", "--", ".", ":!docs", ":!README.md")
    return {"commit": git("rev-parse", "--short", "HEAD") or "unknown", "clean": status == "",
            "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"}


@contextmanager
def locked(path: Path | None):
    """Hold an exclusive flock on ``path`` (the machine's heavy-job lock) for the block; None: no lock."""
    if path is None:
        yield 0.0
        return
    t0 = time.perf_counter()
    with open(path, "a") as fh:
        print(f"  waiting for {path} ...", flush=True)
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield time.perf_counter() - t0
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def run_command(argv: list[str], env: dict, log) -> dict:
    """Run ``python -m argv`` from the repository's root, its output appended to ``log``; timings and exit code."""
    load = os.getloadavg()
    log.write(f"\n$ python -m {' '.join(argv)}\n")
    log.flush()
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", *argv], cwd=REPO, stdout=log, stderr=subprocess.STDOUT,
                            env={**os.environ, **env, "PYTHONPATH": str(REPO)})
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    return {"command": "python -m " + " ".join(argv), "env": env, "exit": proc.returncode, "wall_s": round(wall, 1),
            "cpu_s": round(usage.ru_utime + usage.ru_stime, 1), "peak_rss_gb": round(usage.ru_maxrss / 2 ** 20, 3),
            "load_before": [round(x, 2) for x in load], "load_after": [round(x, 2) for x in os.getloadavg()]}


def run_row(row, lock: Path | None, held: bool = False) -> dict:
    """Run one row's commands (under the lock), read its figures, store and return ``row.json``. ``held``: the
    caller holds the heavy-job lock for the whole invocation (the row is locked though ``lock`` is None)."""
    out = WORK / row.key
    if out.exists():
        shutil.rmtree(out)      # a run folder left there would be resumed by flows.update, not rerun
    out.mkdir(parents=True)
    with locked(lock) as waited, open(out / "log.txt", "w") as log:
        record = {"key": row.key, **provenance(), "lock_wait_s": round(waited, 1),   # the tree as the row starts
                  "locked": lock is not None or held}
        t0 = time.perf_counter()
        record["commands"] = []
        for argv, env in row.commands:
            argv = [a.replace("{out}", str(out.relative_to(REPO))) for a in argv]
            print(f"  python -m {' '.join(argv)}", flush=True)
            record["commands"].append(run_command(argv, {**row.env, **env}, log))
        record["wall_s"] = round(time.perf_counter() - t0, 1)
    record.update(read_row(row, out, record["commands"]))
    (out / "row.json").write_text(json.dumps(record, indent=1, default=str))
    return record


def read_row(row, out: Path, timing: list[dict]) -> dict:
    """The row's result cell and figures from its outputs, or the reason they could not be read."""
    log = (out / "log.txt").read_text(errors="replace")
    try:
        text, figures = row.summarise(out, log, timing)
        return {"result": text, "figures": figures, "error": None}
    except Exception as exc:  # noqa: BLE001 -- any unreadable output marks the row failed, the page says why
        return {"result": None, "figures": None, "error": f"{type(exc).__name__}: {exc}"}


def stored(key: str) -> dict | None:
    """The row's result stored in this tree's ``runs/headline`` (what ``--keep`` resumes from), or None."""
    path = WORK / key / "row.json"
    return json.loads(path.read_text()) if path.exists() else None


def committed() -> dict:
    """The records the committed page was written from (``docs/results/headline.json``), by row key."""
    return json.loads(RECORDS.read_text()) if RECORDS.exists() else {}


def current(keys, page: dict | None = None) -> dict:
    """Per row the newer (by date) of this tree's stored result and the committed page's, or None."""
    page = committed() if page is None else page
    out = {}
    for key in keys:
        have = [r for r in (stored(key), page.get(key)) if r]
        out[key] = max(have, key=lambda r: r["date"]) if have else None
    return out


def _page_link(details: str) -> str:
    """README-relative links (docs/...) as seen from docs/results/."""
    return details.replace("](docs/", "](../")


def write_page(rows, records: dict, total: dict) -> str:
    """docs/results/headline.md from the stored records of ``rows``."""
    done = [records[r.key] for r in rows if records.get(r.key)]
    commits = sorted({r["commit"] for r in done})
    dirty = [r["key"] for r in done if not r["clean"]]
    dates = sorted(r["date"] for r in done)
    wall = sum(r["wall_s"] for r in done)
    lines = [
        "# Headline results, rerun",
        "",
        f"Written by `python -m benchmarks.headline`. Ran on commit {', '.join(f'`{c}`' for c in commits) or '-'} "
        f"(tree {'clean' if not dirty else 'with uncommitted changes in rows ' + ', '.join(dirty)}), "
        f"{dates[0] if dates else '-'} to {dates[-1] if dates else '-'}, {done[0]['machine'] if done else '-'}; "
        + ("each row alone under the machine's heavy-job lock (waiting not counted). "
           if all(r.get("locked", True) for r in done) else
           "without the heavy-job lock: rows side by side with each other and with other sessions' jobs (the load "
           "is in the table), so wall times are several times an idle machine's. ")
        + "Total wall time of the rows: "
        f"**{wall / 60:.1f} min** ({wall:.0f} s){total.get('text', '')}.",
        "",
        "Every figure of the README's `## Headline results` table is one of this page's (the README's table is "
        "written from it; `tests/test_docs.py` checks both that and that the commits above are at most 40 "
        "commits of code or data behind HEAD). Rerun before a change of behaviour is merged: `nice -n 5 python -m "
        "benchmarks.headline` (`--only ROW ...` for some rows, `--keep` to resume).",
        "",
        "| row | what | result | wall | load (1 min) before / after | commit |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        rec = records.get(r.key)
        if rec is None:
            lines.append(f"| {r.key} | {r.what} | not run | - | - | - |")
            continue
        result = rec["result"] if rec["error"] is None else f"FAILED to read: {rec['error']}"
        loads = f"{rec['commands'][0]['load_before'][0]:.1f} / {rec['commands'][-1]['load_after'][0]:.1f}"
        lines.append(f"| {r.key} | {r.what} | {result} | {rec['wall_s']:.0f} s | {loads} | `{rec['commit']}` |")
    lines += ["", "## Rows", ""]
    for r in rows:
        rec = records.get(r.key)
        lines += [f"### {r.key}: {r.what}", "", f"Details: {_page_link(r.details)}."]
        if r.note:
            lines.append(f"Cheaper than its page: {r.note}")
        lines.append("")
        if rec is None:
            lines += ["Not run yet.", ""]
            continue
        for c in rec["commands"]:
            env = " ".join(f"{k}={v}" for k, v in c["env"].items())
            lines.append(f"- `{(env + ' ') if env else ''}{c['command']}`: exit {c['exit']}, {c['wall_s']:.1f} s wall, "
                         f"{c['cpu_s']:.1f} s CPU, peak memory {c['peak_rss_gb']:.2f} GB, load average "
                         f"{', '.join(map(str, c['load_before']))} before, {', '.join(map(str, c['load_after']))} after")
        lines += ["", f"Commit `{rec['commit']}` ({'clean' if rec['clean'] else 'uncommitted changes'}), "
                      f"{rec['date']}, row wall time {rec['wall_s']:.1f} s.", ""]
        if rec["error"]:
            lines += [f"**Failed to read the outputs**: {rec['error']}", ""]
        else:
            lines += [f"Result: {rec['result']}", "", "Figures:", "", "```json",
                      json.dumps(rec["figures"], indent=1, default=str), "```", ""]
    PAGE.write_text("\n".join(lines) + "\n")
    RECORDS.write_text(json.dumps({r.key: records[r.key] for r in rows if records.get(r.key)}, indent=1,
                                  default=str) + "\n")
    return PAGE.read_text()


def readme_table(rows, records: dict) -> list[str]:
    """The README's headline table: what | result | details, the result from the stored records."""
    lines = ["| what | result | details |", "|---|---|---|"]
    for r in rows:
        rec = records.get(r.key)
        if rec and rec["error"] is None:
            lines.append(f"| {r.what} | {rec['result']} | {r.details} |")
    return lines


def readme_intro(rows, records: dict) -> list[str]:
    """The paragraph above the README's table: how the rows are rerun, on which commit, how long it took."""
    done = [records[r.key] for r in rows if records.get(r.key)]
    commits = ", ".join(f"`{c}`" for c in sorted({r["commit"] for r in done}))
    wall = sum(r["wall_s"] for r in done)
    return [f"Rerun together by `python -m benchmarks.headline`: {len(done)} rows, "
            f"{'one at a time' if all(r.get('locked', True) for r in done) else 'some side by side, unlocked'}, "
            f"{wall / 60:.0f} min of "
            f"wall time on 2 shared cores, last on commit {commits}. [headline.md](docs/results/headline.md) names "
            "the date, the load, each row's command, its figures and wall time; this table is written from it."]


def write_readme(rows, records: dict) -> None:
    """Replace the paragraph and the table under ``## Headline results`` in README.md (the text after stays)."""
    text = README.read_text()
    head, sep, rest = text.partition(SECTION)
    if not sep:
        raise SystemExit(f"{README}: no '{SECTION}' section")
    lines = rest.split("\n")
    start = next(i for i, ln in enumerate(lines) if ln.startswith("|"))
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
    lines[1:end] = ["", *readme_intro(rows, records), "", *readme_table(rows, records)]
    README.write_text(head + sep + "\n".join(lines))
