"""What the tool's own model error looks like on issue 40's development cases, at the true factors.

    python -m benchmarks.heldout_misfit dev12 dev03 dev01        # a few lines per case, about 10 s each

The data of a case come from another mesh (or element) of the same structure, so the tool's model misses them
even at the true factors and without any effect. This asks which part of that misfit a judgement could allow for
as the model's own, and how it compares with what an effect does. Per case, on the lines where every channel is
kept, at the true factors (the effect, if any, not modelled):

1. **the FRF misfit and its frequency part**: the log residual ``ln(|Z| / u)`` as it is; after the model's
   natural frequencies are warped smoothly, ``f_r -> f_r exp(-(c0 + c1 x + c2 x^2))`` with ``x = f_r / f_top``
   (three coefficients fitted by least squares); and after every mode in the band is shifted freely (one factor
   per mode). The FRF is the model's exact one, its modes (up to twice the top) taken out and put back shifted:
   ``Z = R + sum_r P_r / (w_r^2 - w^2 + i w (a + b w_r^2))`` with ``R`` what the modes leave (Rayleigh damping,
   :meth:`fe_core.model.ParametricModel.modal_terms`, summed by :meth:`mrgp_core.modal_outputs.ModalLayout.terms`). Each is tested against the noise the data state
   (coherence and averages, :func:`fe_core.inference.residual.analyse_residual`);
2. **the modes**: identified from the measured FRFs (LSCF/LSFD, :func:`tasks.modal_identify.identify_modes`,
   band 0.5 x the model's first mode to the top line), paired with the model's by MAC at the sensors: the
   frequency differences in % and the MACs, beside the shifts the case's effect makes in the data
   (``truth.json``).

Not a tuning: nothing of the tool is set from these figures (docs/results/held-out.md).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from mrgp_core.modal_outputs import ModalLayout

REPO = Path(__file__).resolve().parents[1]
ROOT = REPO / "data" / "cases" / "held_out"


def _case(case: str) -> tuple[dict, object, object]:
    from flows.config import UpdateConfig
    from flows.problem import load_model, prepare_data
    from tasks.io.measured import read_measured

    folder = ROOT / ("dev" if case.startswith("dev") else "heldout") / case
    truth = json.loads((folder / "truth.json").read_text())
    config = UpdateConfig(model=str(REPO / truth["model"]), measured=str(folder / "measured.csv"))
    model, _ = load_model(config.model)
    return truth, model, prepare_data(config, read_measured(config.measured), model)


def frf_misfit(model, data, alpha) -> dict:
    """The analyses of the log residual as it is, after a smooth warp and after free shifts of the modes."""
    from fe_core.inference.residual import analyse_residual

    lines = data.complete_lines
    f, u = data.frequencies_hz[lines], data.amplitude[lines]
    w = 2 * np.pi * f
    Z = model.parameter_frf(alpha, f, data.channels)
    n = 12
    while True:  # every mode up to twice the top line
        omega2, P = model.modal_terms(alpha, n, data.channels)
        if np.sqrt(omega2[-1]) > 2.0 * w.max() or n > 96:
            break
        n += 12
    keep = np.sqrt(omega2) < 2.0 * w.max()
    omega2, P = omega2[keep], P[keep]
    channels = u.shape[1]  # the modes' part of Z on the (line, channel) grid, as the modal emulation sums it
    layout = ModalLayout(np.repeat(w, channels), np.tile(np.arange(channels), w.size), channels,
                         tuple(float(v) for v in model.damping), omega2.size)

    def modal_sum(o2):
        return layout.terms(o2, P).reshape(u.shape)

    rest = Z - modal_sum(omega2)
    x = np.sqrt(omega2) / w.max()
    in_band = int(np.sum(np.sqrt(omega2) <= w.max()))

    def warped(c):
        return np.log(np.abs(rest + modal_sum(omega2 * np.exp(-2 * (c[0] + c[1] * x + c[2] * x**2)))) / u).ravel()

    def shifted(s):
        o2 = omega2.copy()
        o2[:in_band] *= np.exp(-2 * s)
        return np.log(np.abs(rest + modal_sum(o2)) / u).ravel()

    noise, m = data.noise_spec(), len(alpha)
    warp = least_squares(warped, np.zeros(3), x_scale=0.01)
    shift = least_squares(shifted, np.zeros(in_band), x_scale=0.01)
    out = {}
    for name, r, k, extra in (("as it is", warped(np.zeros(3)), 0, None), ("smooth warp", warp.fun, 3, warp.x),
                              ("free shifts", shift.fun, in_band, shift.x)):
        an = analyse_residual(r.reshape(u.shape), f, m + k, noise)
        out[name] = {"rms": an.rms, "noise": an.sigma, "structured": an.structured,
                     "coefficients_percent": None if extra is None else (100 * extra).round(3).tolist()}
    return out


def modes_misfit(model, data, truth, alpha) -> dict:
    """Identified modes against the model's at ``alpha``, paired by MAC at the sensors."""
    from fe_core.correlation.mac import mac_matrix
    from fe_core.solvers.modal import eigenmodes
    from tasks.io.measured import read_measured
    from tasks.modal_data import match_modes
    from tasks.modal_identify import identify_modes

    measured = read_measured(str(REPO / truth["measured"]))
    first = float(model.natural_frequencies(alpha, 1)[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        modes, _ = identify_modes(measured, 0.5 * first, float(truth["lines"]["top_hz"]))
    outputs = match_modes(modes, model).outputs
    f, V = eigenmodes(model.stiffness(alpha), model.mass(), modes.n_modes + 4)
    mac = mac_matrix(modes.shapes, (outputs.T @ V).T)
    j = np.argmax(mac, axis=1)
    return {"test_hz": modes.frequencies_hz.round(2).tolist(),
            "difference_percent": (100 * (f[j] - modes.frequencies_hz) / modes.frequencies_hz).round(2).tolist(),
            "mac": mac[np.arange(j.size), j].round(3).tolist(), "model_mode": (j + 1).tolist(),
            "effect_shift_percent": truth.get("effect_frequency_shift_percent")}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.heldout_misfit", description=__doc__.split("\n")[0])
    p.add_argument("cases", nargs="+", help="case ids (dev01 ...; a held-out id once its files are made)")
    p.add_argument("--json", metavar="PATH", help="also write every figure here")
    args = p.parse_args(argv)
    results = {}
    for case in args.cases:
        truth, model, data = _case(case)
        alpha = np.asarray(truth["factors"], float)
        effect = (truth.get("effect") or {}).get("kind") or "none"
        r = {"structure": truth["structure"], "effect": effect, "frf": frf_misfit(model, data, alpha),
             "modes": modes_misfit(model, data, truth, alpha)}
        results[case] = r
        print(f"{case} {r['structure']} (effect: {effect})")
        for name, v in r["frf"].items():
            extra = "" if v["coefficients_percent"] is None else f"  [{', '.join(map(str, v['coefficients_percent']))}] %"
            print(f"  FRF {name:12s} rms {v['rms']:.2%} vs noise {v['noise']:.2%}: "
                  f"{'structure' if v['structured'] else 'noise'}{extra}")
        m = r["modes"]
        print(f"  modes: model - test % {m['difference_percent']}; MAC {m['mac']}")
        if m["effect_shift_percent"] and any(m["effect_shift_percent"]):
            print(f"  the effect's own shifts in the data % {m['effect_shift_percent']}")
        sys.stdout.flush()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
