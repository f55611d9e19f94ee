"""``summary.json``, the one result file of every run: its schema's version, its intervals, and reading it.

Every kind of run writes one shape (``tasks/io/summary.schema.json``, JSON Schema draft 2020-12; the fields
are described in docs/guide/runs.md, "The summary"): an FRF run (the benchmark, a model file, a CalculiX
deck), a modal run, and the top of a ``--repeats`` run, told apart by ``kind``. Whatever the kind,
``parameters`` maps each parameter's name to its value (a number) and ``intervals``, when computed, maps it to
``{"lower95", "upper95", "sd"}``.

:func:`read_summary` reads a run folder's summary; one written before the schema had a version (no
``schema_version``: an FRF run's intervals as ``[low, high]`` pairs, a modal run's parameters as
``{value, sd, lower95, upper95}``) is returned in the current shape (:func:`upgrade`), so the report, the
closure and the benchmarks read old run folders as new ones.
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["SCHEMA_VERSION", "SCHEMA_PATH", "KINDS", "interval_entries", "entries_from_pairs", "upgrade",
           "read_summary"]

#: The version of the summary's shape this code writes (``summary["schema_version"]``); raised when a field is
#: renamed, removed or changes its meaning (a new optional field keeps it).
SCHEMA_VERSION = 1
#: The JSON Schema every ``summary.json`` of this version satisfies (the tests validate real runs against it).
SCHEMA_PATH = Path(__file__).with_name("summary.schema.json")
#: ``summary["kind"]``: one FRF run (benchmark, model file or CalculiX deck), one modal run, a run with repeats.
KINDS = ("frf", "modal", "repeats")


def interval_entries(names, lower, upper, sd) -> dict:
    """``intervals``: ``{name: {"lower95", "upper95", "sd"}}`` from sequences in the order of ``names``; a bound
    or standard deviation that is None or not finite (a parameter the data do not pin down) is ``None``."""
    def num(x):
        if x is None:
            return None
        x = float(x)
        return x if x == x and abs(x) != float("inf") else None

    return {n: {"lower95": num(lo), "upper95": num(hi), "sd": num(s)}
            for n, lo, hi, s in zip(names, lower, upper, sd)}


def entries_from_pairs(pairs: dict, std: dict | None) -> dict:
    """``intervals`` from the intervals stage's ``{name: [low, high]}`` and its ``{name: sd}``
    (:func:`interval_entries`)."""
    names, std = list(pairs), std or {}
    return interval_entries(names, (pairs[n][0] for n in names), (pairs[n][1] for n in names),
                            (std.get(n) for n in names))


def upgrade(summary: dict) -> dict:
    """A summary in the current shape; one of the current version is returned as it is.

    A summary without ``schema_version`` (written before the schema) is mapped field by field: a modal run's
    ``{value, sd, lower95, upper95}`` parameters to ``parameters`` and ``intervals``, ``folder`` to
    ``run_folder``, ``fe_runs`` to ``fe_evaluations``, ``inside95`` to ``intervals_contain_truth``; an FRF run's
    ``[low, high]`` intervals to entries with the ``sd`` of ``interval_details["std"]``; a repeats run's
    ``runs`` each. Fields the old record did not have stay absent (an old summary is read, not validated)."""
    if "schema_version" in summary:
        return summary
    s = dict(summary)
    params = s.get("parameters") or {}
    if s.get("kind") == "modal update" or any(isinstance(v, dict) for v in params.values()):
        names = list(params)
        s["parameters"] = {n: float(params[n]["value"]) for n in names}
        s["intervals"] = interval_entries(names, (params[n].get("lower95") for n in names),
                                          (params[n].get("upper95") for n in names),
                                          (params[n].get("sd") for n in names))
        s["kind"] = "modal"
        for old, new in (("folder", "run_folder"), ("fe_runs", "fe_evaluations"),
                         ("inside95", "intervals_contain_truth")):
            if old in s:
                s[new] = s.pop(old)
    elif "runs" in s and "repeats" in s:
        s["kind"] = "repeats"
        s["runs"] = [upgrade(r) for r in s["runs"]]
    else:
        s["kind"] = "frf"
        if s.get("intervals"):
            s["intervals"] = entries_from_pairs(s["intervals"], (s.get("interval_details") or {}).get("std"))
    s["schema_version"] = 0  # upgraded in memory; the record on disk has the old shape
    return s


def read_summary(path) -> dict:
    """The summary in ``path`` (a ``summary.json`` or its run folder), in the current shape (:func:`upgrade`)."""
    path = Path(path)
    if path.is_dir():
        path = path / "summary.json"
    return upgrade(json.loads(path.read_text()))
