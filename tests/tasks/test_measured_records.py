"""Raw hammer records (tasks/io/measured/time_records.py, records.py): UFF58 time records and tables of samples
read into H1 FRFs with coherence and averages, checked against the analytic FRF of the system the records were
simulated from (a two-mode oscillator stepped exactly in time, benchmarks.make.hammer_records); bad records
refused naming the file and the dataset, hit or column."""

from __future__ import annotations

import numpy as np
import pyuff
import pytest

from benchmarks.make.hammer_records import modal_frf, simulate
from tasks.io.measured import MeasuredDataError, RecordOptions, read_measured, write_measured
from tasks.io.measured.time_records import write_table, write_uff
from tasks.io.measured.units import G

FS = 1024.0
OMEGA = 2 * np.pi * np.array([60.0, 170.0])
OUTPUTS = np.array([[1.0, 0.5], [0.3, -0.8]])  # mode shapes at the two accelerometers
HAMMER = np.array([0.7, 0.4])
LABELS = ["1:+z", "2:+z"]


def _records(zeta=(0.02, 0.03), hits=2, noise=False, seed=0):
    zeta = np.asarray(zeta)
    force, acc = simulate(OMEGA, zeta, OUTPUTS, HAMMER, np.array([0.2, 0.1]), np.random.default_rng(seed),
                          hits=hits, noise=noise)
    return zeta, force, acc


def _accelerance(measured):
    """The measured FRF back in accelerance, (p, c)."""
    w = 2 * np.pi * measured.frequencies_hz[:, None]
    return -(w**2) * measured.complex_frf


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    zeta, force, acc = _records()
    path = tmp_path_factory.mktemp("records") / "hits.uff"
    write_uff(path, FS, force, acc / G, LABELS, "3:+z", response_unit="g")
    return zeta, force, acc, path


def test_uff_time_records_give_the_analytic_frf(clean):
    zeta, _, _, path = clean
    m = read_measured(path)
    f = m.frequencies_hz
    assert f[0] == 1.0 and f[-1] == 400.0 and f.size == 400  # 1 s records: 1 Hz lines up to fs / 2.56
    assert m.responses == tuple(LABELS) and m.references == ("3:+z", "3:+z")
    assert m.kinds == ("accelerance", "accelerance") and m.units == ("g/N", "g/N")
    assert np.all(m.averages == 2)
    exact = modal_frf(OMEGA, zeta, OUTPUTS, HAMMER, f)
    rel = np.abs(_accelerance(m) - exact) / np.abs(exact)
    # What is left is the response not yet died out at the record's end (exp(-zeta omega T) = 5e-4 of the first
    # mode's peak), an absolute error that is large only where the accelerance is small (below 20 Hz, ~ f^2),
    # and the 6 digits of the file.
    assert np.median(rel) < 1e-3
    assert rel[f >= 20].max() < 1e-2
    # No noise: coherence 1, except where the leakage (which differs from hit to hit with the pulse) is felt
    assert np.all(m.coherence[f >= 20] > 1 - 1e-4) and m.coherence[0].min() < 0.999
    assert any("force window: rectangular" in n for n in m.notes)


def test_tables_of_samples_read_as_the_uff(clean, tmp_path):
    zeta, force, acc, path = clean
    uff = read_measured(path)
    for name in ("hits.csv", "hits.parquet"):
        table = tmp_path / name
        write_table(table, FS, force, acc / G, LABELS, reference="3:+z", response_unit="g")
        m = read_measured(table)
        assert m.responses == uff.responses and m.references == uff.references
        np.testing.assert_allclose(m.frequencies_hz, uff.frequencies_hz, rtol=1e-12)
        # UFF keeps 6 digits, Parquet float32 7: the FRFs agree to that, except below 20 Hz where the accelerance is
        # 1e-5 of its peak and that rounding (white, like an ADC's) is felt
        above = m.frequencies_hz >= 20
        np.testing.assert_allclose(m.complex_frf[above], uff.complex_frf[above], rtol=1e-4)


def test_exponential_window_gives_the_frf_at_s_shifted_by_the_decay(tmp_path):
    """Lightly damped (0.2 %), the response is still ringing at the record's end: without a window the FRF
    leaks (and a note says so); with an exponential window to 1 % on both channels the estimate is the
    structure's accelerance at s = 1/tau + j omega, exactly."""
    zeta, force, acc = _records(zeta=(0.002, 0.002))
    path = tmp_path / "light.uff"
    write_uff(path, FS, force, acc, LABELS, "3:+z")
    plain = read_measured(path)
    assert any("has not died out" in n for n in plain.notes)
    m = read_measured(path, records=RecordOptions(exponential_end=0.01))
    note = next(n for n in m.notes if n.startswith("exponential window"))
    t0 = 0.02  # the pulse's start (PRETRIGGER_S, within one sample)
    sigma = -np.log(0.01) / ((FS - 1) / FS - t0)
    assert f"decay rate {sigma:.4g} 1/s" in note or abs(float(note.split("decay rate ")[1].split()[0]) - sigma) < 0.05
    decay = float(note.split("decay rate ")[1].split()[0])
    f = m.frequencies_hz
    s = decay + 2j * np.pi * f
    shifted = (s[:, None] ** 2) * (OUTPUTS[None] * (HAMMER / (OMEGA**2 + s[:, None] ** 2
                                                             + 2 * np.asarray(zeta) * OMEGA * s[:, None]))[:, None, :]).sum(axis=2)
    # Errors relative to each channel's peak: the windowed tail at the record's end is still exp(-zeta omega T)
    # x 1 % = 0.5 % of the peak (the leakage left), against 47 % without the window.
    peak = np.abs(shifted).max(axis=0)
    error = np.abs(_accelerance(m) - shifted) / peak
    plain_error = np.abs(_accelerance(plain) - modal_frf(OMEGA, zeta, OUTPUTS, HAMMER, f)) / peak
    assert error.max() < 5e-3
    assert plain_error.max() > 10 * error.max()


def test_noisy_hits_have_coherence_below_1_and_the_line_choices(tmp_path):
    zeta, force, acc = _records(hits=4, noise=True, seed=3)
    path = tmp_path / "noisy.uff"
    write_uff(path, FS, force, acc, LABELS, "3:+z")
    m = read_measured(path, records=RecordOptions(band_hz=(50.0, 300.0), line_spacing_hz=0.5))
    assert m.frequencies_hz[0] == 50.0 and m.frequencies_hz[-1] == 300.0 and np.allclose(np.diff(m.frequencies_hz), 0.5)
    assert np.all(m.averages == 4) and m.coherence.min() < 0.999 and np.median(m.coherence) > 0.9
    assert any("zero-padded to 2048 samples" in n for n in m.notes)
    half = read_measured(path, records=RecordOptions(record_s=0.5))
    assert np.allclose(np.diff(half.frequencies_hz), 2.0)


def test_averages_from_the_file_or_the_user(tmp_path):
    hammer = read_measured("data/benchmark/hammer.uff")
    assert np.all(hammer.averages == 10)  # "impact test, 10 averages" in ID line 2
    out = tmp_path / "back.uff"
    write_measured(out, hammer)
    assert np.all(read_measured(out).averages == 10)
    csv = tmp_path / "back.csv"
    write_measured(csv, hammer)
    assert np.all(read_measured(csv).averages == 10)
    bench = read_measured("data/benchmark/measured.csv")
    assert bench.averages is None
    given = read_measured("data/benchmark/measured.csv", averages=8)
    assert np.all(given.averages == 8) and any("8 as given" in n for n in given.notes)
    kept = read_measured("data/benchmark/hammer.uff", averages=3)
    assert np.all(kept.averages == 10) and any("the 3 given are not used" in n for n in kept.notes)
    declared = tmp_path / "declared.csv"
    declared.write_text("# averages = 7\n" + "\n".join(open("data/benchmark/measured.csv").read().splitlines()) + "\n")
    assert np.all(read_measured(declared).averages == 7)


def _expect(path, *needles, records=None):
    with pytest.raises(MeasuredDataError) as info:
        read_measured(path, records=records)
    for needle in needles:
        assert needle in str(info.value), str(info.value)
    assert str(info.value).startswith(str(path))


def test_bad_records_are_refused_naming_the_place(clean, tmp_path):
    _, force, acc, path = clean
    # no force record in the UFF
    sets = [s for s in pyuff.UFF(str(path)).read_sets() if s["ordinate_spec_data_type"] != 13]
    nof = tmp_path / "noforce.uff"
    pyuff.UFF(str(nof)).write_sets(sets, mode="overwrite")
    _expect(nof, "no force record", "load case 1, sequence number 1")
    # mismatched sample rates: one record at 2048 Hz
    sets = pyuff.UFF(str(path)).read_sets()
    sets[4]["x"] = np.arange(sets[4]["data"].size) / 2048.0
    rate = tmp_path / "rate.uff"
    pyuff.UFF(str(rate)).write_sets(sets, mode="overwrite")
    _expect(rate, "dataset 5: sample rate 2048 Hz", "dataset 1 has 1024 Hz", "mismatched sample rates")
    # a record of another length within a hit
    sets = pyuff.UFF(str(path)).read_sets()
    sets[1]["data"], sets[1]["x"] = sets[1]["data"][:900], sets[1]["x"][:900]
    short = tmp_path / "short.uff"
    pyuff.UFF(str(short)).write_sets(sets, mode="overwrite")
    _expect(short, "dataset 2: 900 samples", "different lengths within a hit")
    # a hit without a pulse, a double hit (tables)
    quiet = force.copy()
    quiet[1] = np.random.default_rng(1).normal(0, 0.1, quiet.shape[1])
    table = tmp_path / "quiet.csv"
    write_table(table, FS, quiet, acc, LABELS)
    _expect(table, "hit 2 (line", "no pulse")
    double = force.copy()
    double[0, 500:520] += force[0].max() * np.sin(np.linspace(0, np.pi, 20))
    table = tmp_path / "double.csv"
    write_table(table, FS, double, acc, LABELS)
    _expect(table, "hit 1", "a second pulse at t = 0.489", "double hit")
    # a table without a force column, a bad cell, unevenly spaced time
    text = (tmp_path / "double.csv").read_text().replace("hit,time,force,", "hit,time,hammer,")
    (tmp_path / "noforce.csv").write_text(text)
    _expect(tmp_path / "noforce.csv", "no 'force' column", "without a force channel")
    lines = (tmp_path / "quiet.csv").read_text().splitlines()
    cells = lines[10].split(",")
    lines[10] = ",".join(cells[:2] + ["abc"] + cells[3:])
    (tmp_path / "cell.csv").write_text("\n".join(lines) + "\n")
    _expect(tmp_path / "cell.csv", "line 11: force 'abc' is not a finite number")
    # choices that do not fit
    _expect(path, "line_spacing_hz 2", "coarser than 1 / record length", records=RecordOptions(line_spacing_hz=2.0))
    _expect(path, "exponential_end", records=RecordOptions(exponential_end=1.5))


def test_uff_coherence_outside_0_1_is_refused(tmp_path):
    hammer = read_measured("data/benchmark/hammer.uff")
    sets = pyuff.UFF("data/benchmark/hammer.uff").read_sets()
    coherence = [k for k, s in enumerate(sets) if s.get("func_type") == 6]
    sets[coherence[2]]["data"] = sets[coherence[2]]["data"].copy()
    sets[coherence[2]]["data"][100] = 1.2
    bad = tmp_path / "coh.uff"
    pyuff.UFF(str(bad)).write_sets(sets, mode="overwrite")
    _expect(bad, f"dataset {coherence[2] + 1} (coherence of response 3:+z, reference 5:+z) point 101: coherence 1.2 "
            "is outside [0, 1]")
    assert hammer.coherence.max() <= 1


def test_the_example_reads_as_the_benchmark_hammer_test():
    """data/examples/hammer_records (python -m benchmarks.make.hammer_records): 5 hits of the six accelerometers
    under the hammer at test node 5, in g, read into 400 lines with coherence and 5 averages."""
    m = read_measured("data/examples/hammer_records/hammer_records.uff")
    assert m.responses == tuple(f"{k}:+z" for k in range(1, 7)) and set(m.references) == {"5:+z"}
    assert m.frequencies_hz.size == 400 and np.all(m.averages == 5) and m.units == ("g/N",) * 6
    assert (m.coherence >= 0.9).mean() > 0.8
