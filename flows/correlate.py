"""Test/analysis correlation of measured modes with a model: ``python -m flows.correlate``.

The FE model's modes are read at the test DOFs (the model's sensors with ``test_node`` keys), compared with
the measured modes by the MAC, paired (assignment on the MAC, pairs below ``--threshold`` refused and
named), with frequency differences and the COMAC of each test DOF. Writes ``correlation.json`` and
``mac.png`` (the MAC matrix) and ``shapes.png`` (the paired
shapes on the mesh) to ``--out`` and prints the pairing table. See docs/guide/modal-data.md.

Examples::

    python -m flows.correlate --model data/examples/modal/model.toml --measured data/examples/modal/modes.uff
    python -m flows.correlate --model data/examples/modal/model.toml --measured data/examples/modal/modes_oma.csv \\
        --parameters=-0.6,-0.1,-0.3,-0.2,-0.2,-0.4 --out /tmp/corr

Bad input (a file that is not modal data, a dataset 55 that is not a mode, a test node the model lacks, a
non-finite shape, a frequency above the model's band) exits with code 2 and a message naming the file and
the dataset or line.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path

import numpy as np

from flows.config import REPO, ConfigError

__all__ = ["main", "run_correlation"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m flows.correlate", description="MAC correlation of measured modes "
                                "(UFF dataset 55 or the modal CSV) with a model file's modes at the test nodes.")
    p.add_argument("--model", required=True, metavar="NAME|PATH", help="model file (sensors with test_node keys)")
    p.add_argument("--measured", required=True, metavar="PATH", help="measured modes: .uff/.unv or .csv")
    p.add_argument("--parameters", metavar="P1,P2,...", help="the model's parameter values (default nominal, 0)")
    p.add_argument("--threshold", type=float, default=0.6, help="lowest MAC of a pair (default 0.6)")
    p.add_argument("--out", metavar="DIR", help="output folder (default runs/correlate-<time>)")
    return p


def run_correlation(model_name: str, measured: str, theta=None, threshold: float = 0.6, out=None) -> dict:
    """Correlate and write ``correlation.json`` and ``mac.png``; returns the result (``out`` key: folder)."""
    from flows.problem import load_model
    from tasks import modal

    model, _ = load_model(model_name)
    theta = np.zeros(model.n_parameters) if theta is None else np.asarray(theta, float)
    if theta.shape != (model.n_parameters,):
        raise ConfigError(f"--parameters: {model.n_parameters} values needed ({', '.join(model.parameter_names)})")
    path = Path(measured) if Path(measured).is_absolute() else REPO / measured
    data, n_model = modal.load_modal_data(path, model, upper=1.0)
    result = modal.correlate(data, model, theta, n_model, threshold)
    result.update(model=str(model_name), measured=str(measured), parameter_names=model.parameter_names)
    if out is None:
        out = REPO / "runs" / f"correlate-{dt.datetime.now(dt.timezone.utc).strftime('%Y%m%dT%H%M%SZ')}"
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    modal.write_json(out / "correlation.json", result)
    modal.mac_figure(result, out / "mac.png", f"MAC: {Path(measured).name} vs {Path(str(model_name)).name}")
    modal.shapes_figure(data, model, theta, result, out / "shapes.png")
    result["out"] = str(out)
    return result


def main(argv=None) -> int:
    from tasks.io.measured import MeasuredDataError

    args = _parser().parse_args(argv)
    try:
        theta = None if args.parameters is None else [float(v) for v in args.parameters.split(",")]
        result = run_correlation(args.model, args.measured, theta, args.threshold, args.out)
    except FileNotFoundError as exc:
        print(f"error: {exc.filename}: no such file", file=sys.stderr)
        return 2
    except (ConfigError, MeasuredDataError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for line in result["table"]:
        print(line)
    worst = sorted(result["comac"].items(), key=lambda kv: kv[1])[:3]
    print("lowest COMAC: " + ", ".join(f"{dof} {v:.3f}" for dof, v in worst))
    print(f"written to {result['out']} (correlation.json, mac.png, shapes.png)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
