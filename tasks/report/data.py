"""Read one run folder into plain DataFrames for the report (nothing but its Parquet and JSON).

The FE runs come from the run record every strategy writes (:mod:`tasks.record`: the paper loop's ``fe``
stages, the hybrid's ``local`` and ``global``, the polish), the measured values from ``measured.parquet``,
the sampling distributions and training times from the paper loop's stages when it has them. Only finished
stages are used (a run that is still going, or was killed, gives a report of what is finished); stage folders
this module does not know (``*.rerun-*`` folders, stages added later) are listed, not refused.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from tasks import record
from tasks.io.summary import upgrade
from tasks.runstore import CorruptFileError, RunStore

__all__ = [
    "ReportError",
    "RunData",
    "RepeatsData",
    "KNOWN_STAGES",
    "load_run",
    "load_repeats",
    "is_repeats_folder",
    "param_columns",
    "best_so_far",
    "stage_inventory",
    "find_closure",
    "residual_frame",
]

STAGE_RECORD = "_stage.json"
#: Stages this report draws (``polish``: its points, when the folder holds them).
KNOWN_STAGES = ("samples", "fe", "errors", "distribution", "train", "predict", "select", "polish", "local", "global",
                "emulator", "check", "evidence", "weigh", "intervals")
_ITER = re.compile(r"^iteration=(\d+)$")
_STAGE = re.compile(r"^stage=(.+)$")
_REPEAT = re.compile(r"^repeat=(\d+)$")


class ReportError(ValueError):
    """A run folder that cannot be reported; the message names the folder or file."""


def param_columns(df: pd.DataFrame) -> list[str]:
    """``alpha_1 .. alpha_m`` columns of a table, in numeric order, then ``gamma_j`` (updated mass factors)."""
    cols = [c for c in df.columns if re.fullmatch(r"(alpha|gamma)_\d+", str(c))]
    return sorted(cols, key=lambda c: (c.startswith("gamma"), int(c.split("_")[1])))


def _read_summary(root: Path) -> dict | None:
    """The run's ``summary.json`` in the current shape (an older record's upgraded), or None before it is written."""
    summary = _read_json(root / "summary.json")
    return None if summary is None else upgrade(summary)


def _read_json(path: Path) -> dict | None:
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ReportError(f"{path}: not readable JSON ({exc})") from exc


def _read_parquet(path: Path) -> pd.DataFrame:
    try:
        return pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises several types for damaged files
        raise ReportError(f"{path}: not a readable Parquet file ({exc})") from exc


def _iterations(root: Path) -> list[int]:
    out = []
    for p in root.iterdir():
        m = _ITER.match(p.name)
        if m and p.is_dir():
            out.append(int(m.group(1)))
    return sorted(out)


def _finished(root: Path, iteration: int, stage: str) -> bool:
    return (root / f"iteration={iteration}" / f"stage={stage}" / STAGE_RECORD).exists()


def _stage_record(root: Path, iteration: int, stage: str) -> dict:
    return _read_json(root / f"iteration={iteration}" / f"stage={stage}" / STAGE_RECORD) or {}


def stage_inventory(root: Path) -> pd.DataFrame:
    """Every stage folder of every iteration, known or not.

    Returns
    -------
    DataFrame
        ``iteration, stage, finished, known, seconds, info`` (``info`` as JSON text).
    """
    rows = []
    known = set(KNOWN_STAGES) | set((_read_json(root / "manifest.json") or {}).get("stages", []))  # the strategy's
    for k in _iterations(root):
        for p in sorted((root / f"iteration={k}").iterdir()):
            m = _STAGE.match(p.name)
            if not (m and p.is_dir()):
                continue
            name = m.group(1)
            record = _read_json(p / STAGE_RECORD) if (p / STAGE_RECORD).exists() else None
            info = (record or {}).get("info", {})
            rows.append({
                "iteration": k,
                "stage": name,
                "finished": record is not None,
                "known": name in known,
                "seconds": float(info["seconds"]) if isinstance(info.get("seconds"), (int, float)) else np.nan,
                "info": json.dumps(info, default=str),
            })
    return pd.DataFrame(rows, columns=["iteration", "stage", "finished", "known", "seconds", "info"])


@dataclass
class RunData:
    """One run's tables, as the report needs them.

    Attributes
    ----------
    root : Path
    manifest : dict
    summary : dict or None
        ``summary.json`` when the run finished.
    samples : DataFrame
        ``sample_id, iteration, alpha_*`` of every FE-evaluated batch.
    errors : DataFrame
        ``sample_id, iteration, overall_error, status, error_sensor_*``.
    measured : DataFrame
        ``frequency_hz, sensor, amplitude`` (m/N): the values the run fitted.
    distributions : DataFrame
        ``iteration, kind, parameter, mean, std``.
    training : DataFrame
        ``iteration, stage, trainer, seconds, n_train`` (``train`` and ``train.rerun-*``).
    stages : DataFrame
        :func:`stage_inventory`.
    polish : DataFrame or None
        Points of a polish stage (``alpha_*`` and, when known, ``overall_error``).
    closure : dict or None
        ``closure.json`` of a close-the-loop run, with its folder under ``"_folder"``.
    model : fe_core.model.ParametricModel or None
        The run's model, when the caller resolved it (``flows.report``: the FRF curves and mesh pictures).
    """

    root: Path
    manifest: dict
    summary: dict | None
    samples: pd.DataFrame
    errors: pd.DataFrame
    measured: pd.DataFrame
    distributions: pd.DataFrame
    training: pd.DataFrame
    stages: pd.DataFrame
    polish: pd.DataFrame | None = None
    closure: dict | None = None
    notes: list[str] = field(default_factory=list)
    model: object = None

    @property
    def config(self) -> dict:
        return self.manifest.get("config", {})

    @property
    def names(self) -> list[str]:
        return param_columns(self.samples)

    @property
    def true_parameters(self) -> np.ndarray | None:
        t = self.config.get("true_parameters")
        return None if t is None else np.asarray(t, dtype=float)

    @property
    def sensors(self) -> list[int]:
        return sorted(int(s) for s in self.measured["sensor"].unique())

    @property
    def frequencies(self) -> np.ndarray:
        return np.sort(self.measured["frequency_hz"].unique())

    def best(self) -> tuple[int, np.ndarray, float]:
        """The reported solution: ``summary.json``'s parameters, else the best FE sample so far.

        Returns
        -------
        sample_id (or -1 when it is not an FE sample of the run), alpha, overall error
        """
        names = self.names
        if self.summary and "parameters" in self.summary:
            alpha = np.array([self.summary["parameters"][n] for n in names], dtype=float)
            # The least-squares optimum (issue 19) is no FE sample of the run: no sample id then.
            sid = -1 if "lowest_error" in self.summary else int(self.summary.get("best_sample_id", -1))
            return sid, alpha, float(self.summary["overall_error"])
        ok = self.errors[self.errors["status"] == "ok"]
        if ok.empty:
            raise ReportError(f"{self.root}: no successful FE sample to report")
        row = ok.loc[ok["overall_error"].idxmin()]
        sid = int(row["sample_id"])
        alpha = self.samples.loc[self.samples["sample_id"] == sid, names].to_numpy()[0]
        return sid, alpha, float(row["overall_error"])


def is_repeats_folder(root: Path) -> bool:
    return any(_REPEAT.match(p.name) and p.is_dir() for p in Path(root).iterdir())


def load_run(root: Path | str) -> RunData:
    """Read one (single, not repeats) run folder of any strategy from its run record (:mod:`tasks.record`).

    Raises
    ------
    ReportError
        If the folder or its manifest is missing, or no FE stage has finished yet.
    """
    root = Path(root)
    if not root.is_dir():
        raise ReportError(f"{root}: no such run folder")
    manifest = _read_json(root / "manifest.json")
    if manifest is None:
        raise ReportError(f"{root}: no manifest.json; is this a run folder of flows.update?")
    summary = _read_summary(root)
    try:
        runs = record.fe_runs(RunStore(root))
    except CorruptFileError as exc:
        raise ReportError(str(exc)) from None
    if runs.empty:
        raise ReportError(f"{root}: no finished FE stage yet")
    names = record.parameter_columns(runs)
    sensor_cols = [c for c in runs.columns if c.startswith("error_sensor_")]
    loop = runs[runs["stage"] != "polish"]
    polish = runs[runs["stage"] == "polish"]
    dists, training = [], []
    for k in _iterations(root):
        base = root / f"iteration={k}"
        if _finished(root, k, "distribution"):
            d = _read_parquet(base / "stage=distribution" / "distribution.parquet")
            d.insert(0, "kind", _stage_record(root, k, "distribution").get("info", {}).get("kind", "normal"))
            d.insert(0, "iteration", k)
            dists.append(d)
        for p in sorted(base.glob("stage=train*")):
            name = p.name.split("=", 1)[1]
            if (p / STAGE_RECORD).exists() and (name == "train" or name.startswith("train.rerun")):
                info = _read_json(p / STAGE_RECORD).get("info", {})
                training.append({"iteration": k, "stage": name, "trainer": info.get("trainer", "?"),
                                 "seconds": float(info.get("seconds", np.nan)),
                                 "n_train": info.get("n_train", np.nan)})
    data = RunData(
        root=root,
        manifest=manifest,
        summary=summary,
        samples=loop[["sample_id", "iteration", *names]].reset_index(drop=True),
        errors=loop[["sample_id", "iteration", "overall_error", "status", *sensor_cols]].reset_index(drop=True),
        measured=_measured_of_run(root),
        distributions=pd.concat(dists, ignore_index=True) if dists else pd.DataFrame(
            columns=["iteration", "kind", "parameter", "mean", "std"]),
        training=pd.DataFrame(training, columns=["iteration", "stage", "trainer", "seconds", "n_train"]),
        stages=stage_inventory(root),
    )
    if len(polish):
        data.polish = polish[polish["status"] == "ok"][["sample_id", "iteration", *names, "overall_error"]].assign(
            source="stage=polish").reset_index(drop=True)
    data.closure = find_closure(root)
    unknown = sorted(set(data.stages.loc[~data.stages["known"], "stage"]))
    if unknown:
        data.notes.append("stage folders not drawn by this report: " + ", ".join(unknown))
    return data


def _measured_of_run(root: Path) -> pd.DataFrame:
    """``frequency_hz, sensor, amplitude`` of the values the run fitted (``measured.parquet``, ``used``)."""
    path = root / "measured.parquet"
    if not path.exists():
        raise ReportError(f"{path}: missing; the run's measured values are written when it starts")
    table = _read_parquet(path)
    used = table[table["used"]] if "used" in table.columns else table
    return used[["frequency_hz", "sensor", "amplitude"]].sort_values(["frequency_hz", "sensor"], ignore_index=True)


def best_so_far(data: RunData) -> pd.DataFrame:
    """After each iteration: the best FE sample of iterations 1..k.

    Returns
    -------
    DataFrame
        ``iteration, sample_id, overall_error, fe_evaluations, alpha_*, error_sensor_*``.
    """
    ok = data.errors[data.errors["status"] == "ok"].merge(
        data.samples[["sample_id"] + data.names], on="sample_id", how="left")
    sensor_cols = [c for c in ok.columns if c.startswith("error_sensor_")]
    rows = []
    for k in sorted(data.errors["iteration"].unique()):
        upto = ok[ok["iteration"] <= k]
        if upto.empty:
            continue
        best = upto.loc[upto["overall_error"].idxmin()]
        row = {"iteration": int(k), "sample_id": int(best["sample_id"]), "overall_error": float(best["overall_error"]),
               "fe_evaluations": int((data.samples["iteration"] <= k).sum())}
        row.update({c: float(best[c]) for c in data.names + sensor_cols})
        rows.append(row)
    return pd.DataFrame(rows)


# -- optional parts: close-the-loop ------------------------------------------------------------
def find_closure(root: Path) -> dict | None:
    """``closure.json`` in the run folder or one level below, with ``"_folder"`` added."""
    for path in [root / "closure.json", *sorted(root.glob("*/closure.json"))]:
        if path.exists():
            closure = _read_json(path)
            if not isinstance(closure, dict):
                raise ReportError(f"{path}: expected a JSON object")
            closure["_folder"] = str(path.parent)
            return closure
    return None


def residual_frame(obj, folder: Path, frequencies=None) -> pd.DataFrame | None:
    """A residual table ``frequency_hz, sensor, residual`` from what closure.json holds.

    Accepts a list of records with those keys, a dict of equal-length lists,
    a 2-D list (frequencies x sensors, with ``frequencies`` given), or the
    name of a Parquet/CSV file relative to ``folder``. None when ``obj`` is
    none of these.
    """
    if obj is None:
        return None
    if isinstance(obj, str):
        path = Path(obj) if Path(obj).is_absolute() else folder / obj
        if not path.exists():
            return None
        df = _read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    elif isinstance(obj, list) and obj and isinstance(obj[0], dict):
        df = pd.DataFrame(obj)
    elif isinstance(obj, dict) and {"frequency_hz", "sensor", "residual"} <= set(obj):
        df = pd.DataFrame({k: obj[k] for k in ("frequency_hz", "sensor", "residual")})
    elif isinstance(obj, list) and obj and isinstance(obj[0], list) and frequencies is not None:
        arr = np.asarray(obj, dtype=float)
        if arr.shape[0] != len(frequencies):
            return None
        f, s = np.meshgrid(np.asarray(frequencies, float), np.arange(1, arr.shape[1] + 1), indexing="ij")
        df = pd.DataFrame({"frequency_hz": f.ravel(), "sensor": s.ravel(), "residual": arr.ravel()})
    else:
        return None
    if not {"frequency_hz", "sensor", "residual"} <= set(df.columns):
        return None
    if "sample_id" in df.columns and df["sample_id"].nunique() > 1:
        return None
    return df[["frequency_hz", "sensor", "residual"]].astype({"sensor": int})


# -- repeats ----------------------------------------------------------------------------------
@dataclass
class RepeatsData:
    """A ``--repeats`` folder: its summary and each repeat's run."""

    root: Path
    summary: dict | None
    runs: dict[int, RunData]
    errors: list[str] = field(default_factory=list)

    @property
    def first(self) -> RunData:
        return self.runs[min(self.runs)]

    def best_run(self) -> RunData:
        return min(self.runs.values(), key=lambda r: r.best()[2])


def load_repeats(root: Path | str) -> RepeatsData:
    """Read a repeats folder (``repeat=<i>/`` subfolders and, when finished, ``summary.json``).

    A repeat that cannot be read yet (still running) is left out and named in ``errors``.
    """
    root = Path(root)
    runs, errors = {}, []
    for p in sorted(root.iterdir(), key=lambda p: p.name):
        m = _REPEAT.match(p.name)
        if not (m and p.is_dir()):
            continue
        try:
            runs[int(m.group(1))] = load_run(p)
        except ReportError as exc:
            errors.append(str(exc))
    if not runs:
        raise ReportError(f"{root}: no readable repeat=<i> run folder" + (f" ({errors[0]})" if errors else ""))
    return RepeatsData(root=root, summary=_read_summary(root), runs=runs, errors=errors)
