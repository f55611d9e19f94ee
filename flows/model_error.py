"""The model's own error of a finished run: ``python -m flows.model_error --run-id ID``.

The run's model on its once-refined mesh (ten-node tetrahedra; :mod:`fe_core.io.refined`) stands in for the
structure: the model fitted to it, noise-free, shows the factors' bias from the mesh and the misfit the mesh leaves
(its floor); what the data leave beyond that floor is tested against the measured noise
(:mod:`fe_core.model_error`). Writes ``<run folder>/model_error/``: the refined model (``model.toml``,
``refined.vtu``), ``model_error.json`` and ``residuals.parquet`` (frequency_hz, sensor, data and floor residuals).
Exit 2 with the reason for a run or model it cannot take (a model without a tet10 mesh).
"""

from __future__ import annotations

from flows import environment  # noqa: F401  (first: the environment Prefect starts in)

import argparse  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from prefect import flow  # noqa: E402

from fe_core.closure.fits import ALPHA_BOUNDS  # noqa: E402
from fe_core.io.refined import RefinementError  # noqa: E402
from flows.diagnose import (MASS_FACTORS_REFUSED, DiagnoseError, closure_data, run_folder,  # noqa: E402
                            run_problem)
from tasks.io.measured import MeasuredDataError  # noqa: E402
from tasks.model_error import own_error_task, refine_task  # noqa: E402
from tasks.runstore import atomic_write_bytes, atomic_write_json  # noqa: E402

log = logging.getLogger("flows.model_error")


@flow(name="model-error", flow_run_name="model-error-{run_id}", log_prints=True)
def model_error_flow(run_id: str, out_dir: str, problem, alpha, alpha_bounds, significance: float = 0.01) -> dict:
    """Refine the run's mesh, size the model's own error at the data's estimate; returns ``model_error.json``."""
    t0 = time.perf_counter()
    model = problem.model
    data = closure_data(problem.data, model)
    freqs, u = data.complete()
    fine_file = refine_task(model.source, out_dir)
    result = own_error_task(model, fine_file, freqs, u, alpha, data.noise_spec(None), significance,
                            tuple(alpha_bounds), log=log.info)
    record = {"run_id": run_id, "model": model.source, "refined_model": fine_file, "model_dofs": int(model.n_dofs),
              **result.to_dict(), "segments": list(model.segment_names), "significance": significance,
              "wall_seconds": round(time.perf_counter() - t0, 1)}
    sensors = np.asarray(data.sensors)
    p, n = result.data_residual.shape
    table = pd.DataFrame({"frequency_hz": np.repeat(freqs, n), "sensor": np.tile(sensors, p),
                          "data_residual": result.data_residual.ravel(),
                          "floor_residual": result.floor_residual.ravel()})
    atomic_write_bytes(Path(out_dir) / "residuals.parquet", table.to_parquet(index=False))
    atomic_write_json(Path(out_dir) / "model_error.json", record)
    return record


def describe(record: dict) -> str:
    """What the record says, in a few lines."""
    names = record["segments"]
    rows = [f"model error of run {record['run_id']}: the model ({record['model_dofs']:,} DOFs) against its refined "
            f"mesh ({record['fine_dofs']:,} DOFs)",
            f"  data residual rms {100 * record['rms_data']:.2f} %; the mesh's own floor {100 * record['rms_floor']:.2f} %"
            f" ({100 * record['floor_share_of_data']:.0f} % of the data's sum of squares); beyond it "
            f"{100 * record['rms_beyond']:.2f} %",
            "  factors: " + ", ".join(f"{k} {a:+.4f} (mesh bias {b:+.4f}: structure {c:+.4f})" for k, a, b, c in
                                       zip(names, record["alpha_data"], record["bias"], record["alpha_corrected"])),
            f"  beyond the mesh: {record['beyond']}",
            "  verdict: " + ("what the data leave beyond the mesh's own error is structure: something the mesh does "
                             "not explain" if record["beyond_structured"] else
                             "what the data leave is noise and the mesh's own error: nothing more to explain")]
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m flows.model_error",
                                description="Size a finished run's model error from the model's own refined mesh "
                                            "(ten-node tetrahedra) and test what the data leave beyond it.")
    p.add_argument("--run-id", required=True, metavar="ID")
    p.add_argument("--runs-dir", default="runs", metavar="PATH")
    p.add_argument("--significance", type=float, default=0.01, help="chi-square level for 'structure' (0.01)")
    args = p.parse_args(argv)
    try:
        root, summary, manifest = run_folder(args.run_id, args.runs_dir)
        cfg = manifest.get("config", {})
        problem = run_problem(cfg)
        gammas = [k for k in summary["parameters"] if k.startswith("gamma_")]
        if gammas:  # the model's fits here refit alpha only, as the closure's do
            raise DiagnoseError(f"{root / 'summary.json'}: {MASS_FACTORS_REFUSED.format(names=', '.join(gammas))}")
        names = [f"alpha_{i + 1}" for i in range(problem.model.n_segments)]
        missing = [n for n in names if n not in summary["parameters"]]
        if missing:
            raise DiagnoseError(f"{root / 'summary.json'}: parameters lack {', '.join(missing)}")
        alpha = [float(summary["parameters"][n]) for n in names]
        bounds = [max(float(cfg.get("lower", -1.0)), ALPHA_BOUNDS[0]), float(cfg.get("upper", ALPHA_BOUNDS[1]))]
        record = model_error_flow(args.run_id, str(root / "model_error"), problem, alpha, bounds, args.significance)
    except (DiagnoseError, RefinementError, MeasuredDataError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(describe(record))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
