"""The benchmark measured as a modal test would: ``data/benchmark/hammer.uff``.

    python -m benchmarks.make.hammer            # about a minute (1,600 direct solves)

An impact hammer hits sensor s5's point along z (the model file's excitation
``hammer``, test node 5); accelerometers at the six sensors measure u_z
(test nodes 1..6). The structure is the SPEC's actual one
(``fe_core.benchmark.ALPHA_ACTUAL``), solved with the direct sparse LU per
frequency (``method="direct"``), not the Krylov path that the update fits.

The test is simulated, not just the FRF perturbed: ``N_AVERAGES`` hits, each a
half-sine force pulse of ``PULSE_S`` with a peak force varying by +-30 %; per
hit the force and the six accelerations are spectra at 1,601 lines from 0 to
400 Hz (0.25 Hz apart), each with complex Gaussian noise:

- response noise: ``NOISE`` (1 %) of the response per line, scaled by
  ``sqrt(N_AVERAGES)`` so that the averaged FRF carries 1 % relative noise,
  plus a sensor noise floor of ``FLOOR`` times the channel's largest
  response (where the accelerance is small, near 0 Hz and at the
  anti-resonances, the floor dominates and the coherence drops);
- force noise: ``FORCE_NOISE`` of the force per line.

The FRF is the H1 estimate ``sum X F* / sum |F|^2`` and the ordinary
coherence ``|sum X F*|^2 / (sum |F|^2 sum |X|^2)``, per line, as analysers
compute them. Written with pyuff as a test system exports it: a units dataset
164 (SI), then per channel a dataset 58 FRF (function type 4, load case 0 =
single point excitation, response node 1..6 +Z, reference node 5 +Z, even
abscissa 0..400 Hz, ordinate type 12 acceleration over 13 force, complex
double) and its coherence (function type 6). The 0 Hz line is in the file
(an accelerance is 0 there: what the file holds is noise with coherence near
0); the reader drops it.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "data" / "benchmark" / "hammer.uff"
MODEL = REPO / "data" / "benchmark" / "model.toml"
SEED = 16
LINES = 1601
BAND_HZ = 400.0
N_AVERAGES = 10
PULSE_S = 0.5e-3          # half-sine contact time of a small steel-tip hammer, s
PEAK_FORCE_N = 200.0
NOISE = 0.01              # relative noise of the averaged FRF per line
FLOOR = 1e-3              # sensor noise floor, relative to the channel's largest response
FORCE_NOISE = 0.002       # relative noise of the force per line
HAMMER_NODE = 5


def pulse_spectrum(f_hz: np.ndarray, peak: float, duration: float) -> np.ndarray:
    """Fourier transform of ``peak sin(pi t / duration)`` on ``0 <= t <= duration``, N s."""
    w = 2 * np.pi * np.asarray(f_hz, float)
    a = np.pi / duration
    return peak * a * (1 + np.exp(-1j * w * duration)) / (a**2 - w**2)


def simulate(accelerance: np.ndarray, f_hz: np.ndarray, rng: np.random.Generator):
    """H1 estimate and ordinary coherence of ``N_AVERAGES`` simulated hits.

    Parameters
    ----------
    accelerance : ndarray, shape (p, n), complex, (m/s^2)/N
    f_hz : ndarray, shape (p,)

    Returns
    -------
    H1 : ndarray, shape (p, n), complex
    coherence : ndarray, shape (p, n)
    """
    p, n = accelerance.shape
    mean_force = pulse_spectrum(f_hz, PEAK_FORCE_N, PULSE_S)
    floor = FLOOR * np.max(np.abs(accelerance * mean_force[:, None]), axis=0)  # (n,)
    sxf = np.zeros((p, n), complex)
    sff = np.zeros(p)
    sxx = np.zeros((p, n))
    for _ in range(N_AVERAGES):
        force = mean_force * rng.uniform(0.7, 1.3)
        response = accelerance * force[:, None]
        sigma = np.sqrt((NOISE * np.sqrt(N_AVERAGES) * np.abs(response)) ** 2 + floor**2)
        x = response + sigma * (rng.standard_normal((p, n)) + 1j * rng.standard_normal((p, n))) / np.sqrt(2)
        fm = force + FORCE_NOISE * np.abs(force) * (rng.standard_normal(p) + 1j * rng.standard_normal(p)) / np.sqrt(2)
        sxf += x * np.conj(fm)[:, None]
        sff += np.abs(fm) ** 2
        sxx += np.abs(x) ** 2
    return sxf / sff[:, None], np.abs(sxf) ** 2 / (sff[:, None] * sxx)


def write_uff(path: Path, f_hz: np.ndarray, H1: np.ndarray, coherence: np.ndarray, responses=None,
              references=None) -> None:
    """Channel j: response test node ``responses[j]`` (default j + 1), reference ``references[j]`` (default the
    hammer's node), both +Z."""
    import pyuff

    n = H1.shape[1]
    responses = list(range(1, n + 1)) if responses is None else list(responses)
    references = [HAMMER_NODE] * n if references is None else list(references)

    sets = [pyuff.prepare_164(units_code=1, units_description="SI", temp_mode=1, length=1.0, force=1.0, temp=1.0,
                              temp_offset=273.15)]
    for j in range(H1.shape[1]):
        rsp, ref = responses[j], references[j]
        record6 = dict(load_case_id=0, rsp_node=rsp, rsp_dir=3, ref_node=ref, ref_dir=3)
        sets.append(pyuff.prepare_58(
            binary=0, id1=f"H1 accelerance {rsp}:+Z/{ref}:+Z", id2=f"impact test, {N_AVERAGES} averages",
            id3="simulated by benchmarks.make.hammer", id4="NONE", id5="NONE", func_type=4, **record6,
            abscissa_spacing=1, abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz",
            ordinate_spec_data_type=12, ordinate_axis_units_lab="m/s^2", orddenom_spec_data_type=13,
            orddenom_axis_units_lab="N", data=H1[:, j].copy(), x=f_hz.copy()))
        sets.append(pyuff.prepare_58(
            binary=0, id1=f"coherence {rsp}:+Z/{ref}:+Z", id2=f"impact test, {N_AVERAGES} averages",
            id3="simulated by benchmarks.make.hammer", id4="NONE", id5="NONE", func_type=6, **record6,
            abscissa_spacing=1, abscissa_spec_data_type=18, abscissa_axis_units_lab="Hz",
            ordinate_spec_data_type=0, orddenom_spec_data_type=0, data=coherence[:, j].copy(), x=f_hz.copy()))
    tmp = path.with_name(path.name + ".tmp")
    pyuff.UFF(str(tmp)).write_sets(sets, mode="overwrite", force_double=True)
    tmp.replace(path)


def main() -> int:
    from fe_core.benchmark import ALPHA_ACTUAL
    from fe_core.io import read_model

    t0, c0 = time.perf_counter(), time.process_time()
    model = read_model(MODEL)
    hammer = model.excitation_test_dofs.index((HAMMER_NODE, 3))
    f = np.arange(LINES) * (BAND_HZ / (LINES - 1))
    receptance = np.zeros((LINES, model.n_sensors), complex)
    receptance[1:] = model.frf_channels(ALPHA_ACTUAL, f[1:], np.arange(model.n_sensors),
                                        np.full(model.n_sensors, hammer), method="direct")
    accelerance = -((2 * np.pi * f[:, None]) ** 2) * receptance  # exactly 0 at 0 Hz
    H1, coherence = simulate(accelerance, f, np.random.default_rng(SEED))
    write_uff(OUT, f, H1, coherence)
    good = (coherence[1:] >= 0.9)
    rel = np.abs(H1[1:] - accelerance[1:]) / np.abs(accelerance[1:])
    print(f"wrote {OUT.relative_to(REPO)}: {model.n_sensors} accelerances (hammer at test node {HAMMER_NODE} +Z) "
          f"with coherence, {LINES} lines 0-{BAND_HZ:g} Hz, {N_AVERAGES} averages")
    print(f"relative error of H1 vs the direct FRF: rms {np.sqrt(np.mean(rel[good] ** 2)):.4f} where coherence "
          f">= 0.9 ({good.sum()} of {good.size} values), median {np.median(rel):.4f} overall")
    print(f"coherence < 0.9: {(~good).sum()} values; lowest line with coherence >= 0.9 in every channel: "
          f"{f[1:][good.all(axis=1)][0]:g} Hz")
    print(f"time {time.perf_counter() - t0:.1f} s wall, {time.process_time() - c0:.1f} s CPU")
    return 0


if __name__ == "__main__":
    from benchmarks.make import parse_no_options

    parse_no_options("benchmarks.make.hammer", __doc__)
    sys.exit(main())
