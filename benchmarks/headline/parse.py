"""Reading what the headline rows' commands wrote: run summaries, markdown tables, JSON, and number formats.

The commands are the project's own (``flows.update``, ``benchmarks.*``); their outputs are read here, not
recomputed. A summary is read in the one shape of every kind of run (:mod:`tasks.io.summary`: ``parameters``
as plain numbers, ``intervals`` as ``{lower95, upper95, sd}``; an older record is upgraded on reading), so a
change of the run record's schema does not silently drop a row: an unreadable output raises, and the row is
marked failed on the page.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from tasks.io.summary import read_summary


def summary(run_folder: Path) -> dict:
    """The ``summary.json`` of a run folder, in the current shape."""
    return read_summary(Path(run_folder) / "summary.json")


def estimate(s: dict) -> np.ndarray:
    """The reported parameters, in the summary's order, shape (m,)."""
    return np.array([float(v) for v in s["parameters"].values()])


def intervals(s: dict) -> np.ndarray | None:
    """The 95 % intervals, shape (m, 2) (an unbounded side: -inf or inf), or None when the run reported none."""
    if not s.get("intervals"):
        return None
    iv = s["intervals"]
    return np.array([(-np.inf if iv[n]["lower95"] is None else iv[n]["lower95"],
                      np.inf if iv[n]["upper95"] is None else iv[n]["upper95"]) for n in s["parameters"]], float)


def fe_runs(s: dict) -> int:
    """FE runs of a run (FRF runs: FE evaluations; modal runs: eigen-solves)."""
    return int(s["fe_evaluations"])


def covered(bounds: np.ndarray | None, truth: np.ndarray) -> int | None:
    """How many true values lie inside their intervals."""
    if bounds is None:
        return None
    return int(np.sum((bounds[:, 0] <= truth) & (truth <= bounds[:, 1])))


def markdown_rows(text: str, first_header: str) -> list[dict]:
    """The rows of the markdown table whose header row starts with ``| first_header |`` (the last such table).

    A column name that repeats gets its count (the second "in FE runs" is "in FE runs 2")."""
    lines = text.splitlines()
    starts = [i for i, ln in enumerate(lines) if re.match(r"\|\s*" + re.escape(first_header) + r"\s*\|", ln)]
    if not starts:
        raise ValueError(f"no table with a '{first_header}' column in the output")
    i = starts[-1]
    header = []
    for c in (c.strip() for c in lines[i].strip().strip("|").split("|")):
        header.append(c if c not in header else f"{c} {sum(h.split(' (')[0] == c for h in header) + 1}")
    rows = []
    for ln in lines[i + 2:]:
        if not ln.startswith("|"):
            break
        cells = [c.strip() for c in ln.strip().strip("|").split("|")]
        rows.append(dict(zip(header, cells)))
    return rows


def json_tail(text: str) -> object:
    """The JSON document a command printed last (a list or an object starting on its own line)."""
    for i in range(len(text) - 1, -1, -1):
        if text[i] in "[{" and (i == 0 or text[i - 1] == "\n"):
            try:
                return json.loads(text[i:])
            except json.JSONDecodeError:
                continue
    raise ValueError("no JSON document at the end of the output")


def up(x: float, digits: int = 2) -> str:
    """``x`` >= 0 rounded *up* to ``digits`` significant digits ("within" bounds stay true): 0.000461 -> 0.00047."""
    if x == 0:
        return "0"
    if not math.isfinite(x):
        return str(x)
    exp = math.floor(math.log10(abs(x))) - digits + 1
    v = math.ceil(round(x / 10.0 ** exp, 9)) * 10.0 ** exp
    if abs(v) < 1e-4:
        return f"{v:.{digits - 1}e}"
    return f"{v:.{max(0, -exp)}f}"


def percent(x: float, digits: int = 1) -> str:
    """A fraction as a percentage with ``digits`` decimals, rounded up: 0.00871 -> '0.9 %'."""
    scale = 10 ** digits
    return f"{math.ceil(round(x * 100 * scale, 6)) / scale:.{digits}f} %"


def span(values, fmt: str = "{:g}") -> str:
    """'lo-hi' of some numbers, or the one value when they are equal."""
    values = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    if not values:
        return "-"
    lo, hi = min(values), max(values)
    return fmt.format(lo) if fmt.format(lo) == fmt.format(hi) else f"{fmt.format(lo)}-{fmt.format(hi)}"


def median(values) -> float:
    values = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    return float(np.median(values)) if values else float("nan")


def number(text: str) -> float:
    """The first number in a table cell: '0.9 %' -> 0.9, '54 (105)' -> 54."""
    m = re.search(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", text)
    if m is None:
        raise ValueError(f"no number in {text!r}")
    return float(m.group(0))
