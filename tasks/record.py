"""The run record: every FE run of a run, whatever the strategy, in two tables per FE stage.

Every stage that runs the FE model (:class:`tasks.fe_runs.FEStage`, the stages the driver makes of a
strategy's batches: the paper loop's ``fe``, the polish, the hybrid's ``local`` and ``global``) writes

* ``runs.parquet``, one row per FE run in request order: ``sample_id``, ``round`` (within the stage),
  ``jacobian``, ``cost`` (FE-run equivalents), ``seconds`` (the run's own time), ``pid`` (of the process that
  made it), ``status``, ``message``,
  ``overall_error`` (Eq. 6b of the run's residual, NaN for a failed run), the parameters and
  ``error_sensor_<j>`` (per channel, Eq. 15); ``reduced`` when a large model's reduced basis served some of the
  stage's rounds (:mod:`fe_core.solvers.reduced_basis`: those results are approximate);
* ``responses.parquet``, the long complex table: ``sample_id``, ``sensor`` (channel, 1-based),
  ``frequency_hz``, ``real``, ``imag`` (and the modal columns when the paper loop emulates modes);

and its stage record (``_stage.json``) counts ``evaluations``, ``jacobians``, ``rounds`` and ``cost``. The
readers here give the whole run's FE runs in sample order (:func:`fe_runs`), their responses, what was spent
(:func:`spent`) and the best run, for the summary, the report, reruns and the correlation tool.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tasks.runstore import RunStore

__all__ = ["RUN_COLUMNS", "RESPONSE_COLUMNS", "FE_STAGE_ORDER", "fe_stages", "fe_runs", "responses", "spent",
           "next_sample_id", "grid", "parameter_columns", "best_run", "history"]

RUN_COLUMNS = ("sample_id", "round", "jacobian", "cost", "seconds", "pid", "status", "message", "overall_error")
RESPONSE_COLUMNS = ("sample_id", "sensor", "frequency_hz", "real", "imag")
#: FE stages in the order they run within an iteration (a cycle of the hybrid); a strategy's other FE stages (any
#: finished stage whose record lists ``runs`` and ``responses``) follow in the order of their names. Folders of
#: reruns (``<stage>.rerun-...``) are not part of the run.
FE_STAGE_ORDER = ("fe", "local", "global", "polish")


def parameter_columns(table: pd.DataFrame) -> list[str]:
    """``alpha_1 .. alpha_m`` then ``gamma_j`` columns of a table, in numeric order."""
    import re

    cols = [c for c in table.columns if re.fullmatch(r"(alpha|gamma)_\d+", str(c))]
    return sorted(cols, key=lambda c: (c.startswith("gamma"), int(c.split("_")[1])))


def _iterations(store: RunStore) -> list[int]:
    out = []
    for p in store.root.glob("iteration=*"):
        try:
            out.append(int(p.name.split("=", 1)[1]))
        except ValueError:
            continue
    return sorted(out)


def fe_stages(store: RunStore, upto: int | None = None) -> list[tuple[int, str]]:
    """The finished FE stages (iteration, stage) of iterations 1..``upto`` (all when None), in run order."""
    out = []
    for k in _iterations(store):
        if upto is not None and k > upto:
            break
        names = {p.name.split("=", 1)[1] for p in (store.root / f"iteration={k}").glob("stage=*")}
        names = [n for n in names if "." not in n]
        for stage in sorted(names, key=lambda n: (FE_STAGE_ORDER.index(n) if n in FE_STAGE_ORDER
                                                 else len(FE_STAGE_ORDER), n)):
            if {"runs", "responses"} <= set(store.stage_files(k, stage)) and store.is_finished(k, stage):
                out.append((k, stage))
    return out


def fe_runs(store: RunStore, upto: int | None = None) -> pd.DataFrame:
    """Every FE run of the finished FE stages, in sample order, with ``iteration`` and ``stage`` columns."""
    parts = []
    for k, stage in fe_stages(store, upto):
        r = store.read_table(k, stage, "runs")
        r.insert(0, "stage", stage)
        r.insert(0, "iteration", np.int64(k))
        parts.append(r)
    if not parts:
        return pd.DataFrame(columns=["iteration", "stage", *RUN_COLUMNS])
    return pd.concat(parts, ignore_index=True).sort_values("sample_id", kind="stable").reset_index(drop=True)


def responses(store: RunStore, upto: int | None = None, sample_ids=None) -> pd.DataFrame:
    """The long complex table of the finished FE stages (only ``sample_ids`` when given)."""
    wanted = None if sample_ids is None else {int(s) for s in sample_ids}
    parts = []
    for k, stage in fe_stages(store, upto):
        r = store.read_table(k, stage, "responses")
        parts.append(r if wanted is None else r[r["sample_id"].isin(wanted)])
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=list(RESPONSE_COLUMNS))


def spent(store: RunStore, upto: int | None = None) -> dict:
    """FE runs, Jacobians, rounds and FE-run equivalents (``cost``) of the finished FE stages."""
    total = {"evaluations": 0, "jacobians": 0, "rounds": 0, "cost": 0.0}
    for k, stage in fe_stages(store, upto):
        info = store.stage_info(k, stage)
        for key in total:
            total[key] += info[key]
    return total


def next_sample_id(store: RunStore, upto: int | None = None) -> int:
    """One more than the largest sample id of the finished FE stages (0 for none)."""
    runs = fe_runs(store, upto)
    return int(runs["sample_id"].max()) + 1 if len(runs) else 0


def grid(df: pd.DataFrame, p: int, n: int, m: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(Z (p, n), dZ (p, n, m) or None) of one stored FE result (rows frequency-major, channels fastest)."""
    df = df.sort_values(["frequency_hz", "sensor"], kind="stable")
    Z = (df["real"].to_numpy() + 1j * df["imag"].to_numpy()).reshape(p, n)
    if f"dreal_{m}" not in df.columns:
        return Z, None
    dZ = np.stack([(df[f"dreal_{i + 1}"].to_numpy() + 1j * df[f"dimag_{i + 1}"].to_numpy()).reshape(p, n)
                   for i in range(m)], axis=-1)
    return Z, dZ


def best_run(runs: pd.DataFrame) -> pd.Series:
    """The successful FE run with the lowest overall error (the first of equals in sample order). Runs a large
    model's reduced basis served (``reduced``: approximate, to about 1e-5) count only when no full-order run
    succeeded: a served round's error can undercut the full-order run that confirmed it by its approximation."""
    ok = runs[runs["status"] == "ok"]
    if ok.empty:
        raise ValueError("no successful FE run")
    if "reduced" in ok:
        exact = ok[~ok["reduced"].eq(True)]  # NaN: a stage without served rounds
        ok = exact if len(exact) else ok
    return ok.loc[ok["overall_error"].idxmin()]


def history(store, upto: int | None = None) -> list[dict]:
    """Every FE run of a run in evaluation order: ``round`` (counted over the whole run), ``x``, ``error``
    (overall error, inf for a failed run), ``jacobian``, ``cost`` (FE-run equivalents). ``store``: a
    :class:`RunStore` or the run folder; any strategy's run (the paper loop's iterations are one round each)."""
    store = store if isinstance(store, RunStore) else RunStore(store)
    runs = fe_runs(store, upto)
    names = parameter_columns(runs)
    out, offset = [], 0
    first = runs.groupby(["iteration", "stage"])["sample_id"].transform("min")  # the stages of an iteration in turn
    for (k, _, stage), g in runs.assign(rank=first).groupby(["iteration", "rank", "stage"], sort=True):
        for row in g.sort_values("sample_id").itertuples(index=False):
            d = row._asdict()
            out.append({"round": offset + int(d["round"]), "x": np.array([d[n] for n in names], float),
                        "error": float(d["overall_error"]) if d["status"] == "ok" else float("inf"),
                        "jacobian": bool(d["jacobian"]), "cost": float(d["cost"])})
        offset += int(store.stage_info(int(k), stage)["rounds"])
    return out
