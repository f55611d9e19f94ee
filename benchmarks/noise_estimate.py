"""The noise level estimated from a residual (``fe_core.inference.residual``): bias, spread and false structure.

    nice -n 10 python -m benchmarks.noise_estimate            # white noise on three layouts + issue 28's own cases
    nice -n 10 python -m benchmarks.noise_estimate --draws 500 --no-cases

Two estimators side by side: the one before (mean square of second differences in bands cut where a step exceeds
1.5 x the smallest step of all lines) and :func:`fe_core.inference.residual.estimate_noise` (bands cut where the
step changes, clipped at 3 standard deviations). On white noise of 0.5 % on the benchmark's 12 lines and two own
cases' layouts: the estimate's mean and spread over draws (in units of sigma), and how often pure noise is called
structure at 1 % -- against the chi-square with each estimate, and with the new test's p
(:func:`fe_core.inference.residual.estimated_noise_test`). On the own cases (``data/cases/own_structures``): our model's
residual at the truth with the effect (noise only) and without it (structure), each estimate beside the rms.
Tables for docs/guide/noise-estimate.md.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from scipy import stats

from fe_core.inference.residual import estimate_noise, estimated_noise_test
from flows.config import REPO

SIGMA = 0.005


def old_estimate(residual: np.ndarray, freqs_hz) -> float:
    """The estimate before: mean square of second differences, bands cut at 1.5 x the smallest step of all lines."""
    f = np.asarray(freqs_hz, float)
    order = np.argsort(f)
    steps = np.diff(f[order])
    cuts = np.flatnonzero(steps > 1.5 * steps[steps > 0].min()) + 1
    bands = [order[a:b] for a, b in zip(np.r_[0, cuts], np.r_[cuts, f.size])]
    d2 = [np.diff(residual[b], n=2, axis=0).ravel() for b in bands if b.size >= 3]
    return float(np.sqrt(np.mean(np.concatenate(d2) ** 2) / 6.0)) if d2 else float("nan")


def white_noise(name: str, freqs, n_sensors: int, draws: int, rng, n_fitted: int = 4) -> str:
    """One table row: mean/sd of each estimate over draws, false-structure rates at 1 %."""
    old, new, chi_old, chi_new, calibrated = [], [], 0, 0, 0
    for _ in range(draws):
        e = SIGMA * rng.standard_normal((len(freqs), n_sensors))
        J = rng.standard_normal((e.size, n_fitted))  # a linear fit of n_fitted parameters: what it leaves
        r = (e.ravel() - J @ np.linalg.lstsq(J, e.ravel(), rcond=None)[0]).reshape(e.shape)
        a, (b, _, dof, p) = old_estimate(r, freqs), estimated_noise_test(r, freqs, n_fitted)
        old.append(a / SIGMA)
        new.append(b / SIGMA)
        chi_old += stats.chi2.sf(np.sum(r**2) / a**2, dof) < 0.01
        chi_new += stats.chi2.sf(np.sum(r**2) / b**2, dof) < 0.01
        calibrated += p < 0.01
    return (f"| {name} | {len(freqs)} x {n_sensors} | {np.mean(old):.3f} / {np.std(old):.3f} | "
            f"{np.mean(new):.3f} / {np.std(new):.3f} | {chi_old / draws:.1%} | {chi_new / draws:.1%} | "
            f"{calibrated / draws:.1%} |")


def own_cases() -> list[str]:
    """Rows per own case: residual at the truth with and without the effect, rms and both estimates."""
    from fe_core.closure.effects import Applied, ElementBand, GroundedSpring, PointMass, extended_frf, patch_bands
    from fe_core.io import read_model
    from tasks.io.measured import read_measured

    truth = json.loads((REPO / "data/cases/own_structures/truth.json").read_text())
    rows, models = [], {}
    for case, t in truth["cases"].items():
        model = models.setdefault(t["model"], read_model(REPO / t["model"]))
        m = read_measured(REPO / t["measured"])
        alpha = truth["structures"][t["structure"]]["alpha"]
        if t["effect"] == "point_mass":
            effect = PointMass(model, [t["node"]])
        elif t["effect"].startswith("grounded_spring"):
            effect = GroundedSpring(model, [t["node"]], component="xyz".index(t["effect"][-1]))
        else:
            effect = ElementBand(model, patch_bands(model, [t["node"]], rings=(2,)), kind="patch")
        cells = [case]
        for applied in ([Applied(effect, t["location"], np.array([t["value"]]))], []):
            r = np.log(np.abs(extended_frf(model, alpha, m.frequencies_hz, applied, method="direct")) / m.amplitude)
            p = estimated_noise_test(r, m.frequencies_hz, 0)[3]
            cells += [f"{np.sqrt(np.mean(r**2)):.2%}", f"{old_estimate(r, m.frequencies_hz):.2%}",
                      f"{estimate_noise(r, m.frequencies_hz):.2%} (p {p:.2g})"]
        rows.append("| " + " | ".join(cells) + " |")
        print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.noise_estimate", description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=2000, help="white-noise draws per layout")
    ap.add_argument("--no-cases", action="store_true", help="white noise only (no FE solves)")
    args = ap.parse_args(argv)
    from fe_core.benchmark import MEASUREMENT_FREQUENCIES_HZ

    truth = json.loads((REPO / "data/cases/own_structures/truth.json").read_text())["cases"]
    rng = np.random.default_rng(2026)
    print(f"white noise {SIGMA:.1%}, {args.draws} draws; estimate mean / sd in sigma; pure noise called structure "
          "at 1 % (4 parameters fitted): chi-square with the old estimate, with the new one, the new test's p")
    print("| layout | lines x sensors | old: mean / sd | new: mean / sd | chi2, old | chi2, new | new test |")
    print("|---|---|---|---|---|---|---|")
    print(white_noise("benchmark (2 bands of 6)", MEASUREMENT_FREQUENCIES_HZ, 6, args.draws, rng), flush=True)
    for case, n in (("plate-mass-5%", 6), ("frame-patch-10%", 6), ("cantilever-mass-2%", 5)):
        f = np.asarray(truth[case]["frequencies_hz"])
        print(white_noise(f"{case} lines", f, n, args.draws, rng), flush=True)
    if not args.no_cases:
        print("\nown cases, our model at the truth (no fit): rms, old estimate, new estimate (the new test's p)")
        print("| case | with the effect: rms | old | new | without it: rms | old | new |")
        print("|---|---|---|---|---|---|---|")
        own_cases()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
