"""Bad input to ``python -m flows.update``: exit code 2, a message naming the file, row or key, nothing written.

Every case of ``BAD_INPUTS`` is given twice: for a new run id (the run
folder must not be created) and for an existing run folder (its files and
their contents must not change). The cases run ``flows.update.main``
in-process (no Prefect run starts, because every check comes first);
``test_the_real_command_exits_2`` checks one case through the real command.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyuff
import pytest

from fe_core.benchmark import ALPHA_ACTUAL
from flows import update
from flows.run import write_manifest
from flows.config import REPO, load_config
from tasks.io.measured import read_measured, write_measured
from tasks.runstore import RunStore

BENCHMARK = REPO / "data" / "benchmark" / "measured.csv"
LINES = BENCHMARK.read_text().splitlines()  # header + 72 rows, frequency-major (6 sensors per frequency)


def _csv(lines: list[str]) -> str:
    return "\n".join(lines) + "\n"


def _replace(line_no: int, field: int, value: str) -> str:
    """The benchmark CSV with one field of one line (1-based, header = line 1) replaced."""
    lines = list(LINES)
    cells = lines[line_no - 1].split(",")
    cells[field] = value
    lines[line_no - 1] = ",".join(cells)
    return _csv(lines)


def _amplitude_only(line_no: int, value: str) -> str:
    lines = [",".join(line.split(",")[:3]) for line in LINES]
    cells = lines[line_no - 1].split(",")
    cells[2] = value
    lines[line_no - 1] = ",".join(cells)
    return _csv(lines)


def _uff_out_of_order(path: Path) -> None:
    """The benchmark as UFF58, with two frequencies of sensor 3 swapped (and their values)."""
    m = read_measured(BENCHMARK)
    sets = []
    for j, sensor in enumerate(m.sensors):
        x, data = m.frequencies_hz.copy(), m.complex_frf[:, j].copy()
        if sensor == 3:
            x[[4, 5]], data[[4, 5]] = x[[5, 4]], data[[5, 4]]
        sets.append(pyuff.prepare_58(
            binary=0, func_type=4, rsp_node=int(sensor), rsp_dir=3, ref_node=0, ref_dir=3, abscissa_spacing=0,
            abscissa_spec_data_type=18, ordinate_spec_data_type=8, orddenom_spec_data_type=13, data=data, x=x))
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite")


def _scaled_frequencies(path: Path, factor: float) -> None:
    m = read_measured(BENCHMARK)
    write_measured(path, type(m)(m.frequencies_hz * factor, m.sensors, m.amplitude, m.complex_frf, ""))


def _drop_sensor(sensor: int) -> str:
    return _csv([LINES[0]] + [line for line in LINES[1:] if line.split(",")[0] != str(sensor)])


def _renumber_sensor(old: int, new: int) -> str:
    out = [LINES[0]]
    for line in LINES[1:]:
        cells = line.split(",")
        if cells[0] == str(old):
            cells[0] = str(new)
        out.append(",".join(cells))
    return _csv(out)


def _channels(response=None, reference=None, frequencies=(100.0, 110.0), comments=None, extra_rows=(),
              coherence=None) -> str:
    """A hammer test as a channel table: s1..s6 under 'hammer' (lines 2-7 at 100 Hz, 8-13 at 110 Hz).

    ``response`` / ``reference``: {sensor number: label} replacing a channel's labels on all its rows;
    ``comments``: {line before which to insert: text}; ``coherence``: {line: value}.
    """
    lines = ["response,reference,frequency_hz,real,imag,coherence"]
    for f in frequencies:
        for j in range(1, 7):
            resp = (response or {}).get(j, f"s{j}")
            ref = (reference or {}).get(j, "hammer")
            lines.append(f"{resp},{ref},{f!r},{1e-6 * j!r},{-2e-7 * j!r},0.99")
    for line, value in (coherence or {}).items():
        cells = lines[line - 1].split(",")
        cells[5] = value
        lines[line - 1] = ",".join(cells)
    lines += list(extra_rows)
    for before, text in sorted((comments or {}).items(), reverse=True):
        lines.insert(before - 1, text)
    return _csv(lines)


def _hits(fs=256.0, n=256, hits=2):
    """Two hits of a short synthetic hammer test: a half-sine force and a decaying response at 1:+z."""
    t = np.arange(n) / fs
    force = np.where((t > 0.02) & (t < 0.03), 100 * np.sin(np.pi * (t - 0.02) / 0.01), 0.0)
    response = np.where(t > 0.02, np.exp(-20 * (t - 0.02)) * np.sin(2 * np.pi * 40 * (t - 0.02)), 0.0)
    return np.tile(force, (hits, 1)), np.tile(response, (hits, 1, 1))


def _records_uff(path: Path, rate_of_dataset_3=None) -> None:
    from tasks.io.measured.time_records import write_uff

    force, response = _hits()
    write_uff(path, 256.0, force, response, ["1:+z"], "5:+z")
    if rate_of_dataset_3:
        sets = pyuff.UFF(str(path)).read_sets()
        sets[2]["x"] = np.arange(sets[2]["data"].size) / rate_of_dataset_3
        pyuff.UFF(str(path)).write_sets(sets, mode="overwrite")


def _records_csv(path: Path, quiet_hit=None, force_column="force") -> None:
    from tasks.io.measured.time_records import write_table

    force, response = _hits()
    if quiet_hit:
        force[quiet_hit - 1] = 0.0
    write_table(path, 256.0, force, response, ["1:+z"], reference="5:+z")
    path.write_text(path.read_text().replace("hit,time,force,", f"hit,time,{force_column},"))


def _uff_coherence_above_1(path: Path) -> None:
    sets = pyuff.UFF(str(BENCHMARK.with_name("hammer.uff"))).read_sets()
    sets[4]["data"] = sets[4]["data"].copy()  # the coherence of channel 2 (dataset 5; its FRF is dataset 4)
    sets[4]["data"][40] = 1.2
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite")


# (id, measured file name, its content (str, bytes or a writer), config lines, extra CLI args, message parts).
# "{measured}" and "{config}" in message parts are replaced by the paths.
BAD_INPUTS = [
    ("nan amplitude", "m.csv", _replace(5, 2, "nan"), "", [], ["{measured}", "line 5", "amplitude"]),
    ("negative amplitude", "m.csv", _amplitude_only(9, "-1e-6"), "", [], ["{measured}", "line 9", "> 0"]),
    ("zero amplitude", "m.csv", _amplitude_only(2, "0"), "", [], ["{measured}", "line 2", "amplitude 0.0"]),
    ("missing sensor", "m.csv", _drop_sensor(6), "", [], ["{measured}", "missing [6]"]),
    ("unknown sensor", "m.csv", _renumber_sensor(6, 7), "", [], ["{measured}", "missing [6]", "unknown [7]"]),
    ("duplicated row", "m.csv", _csv(LINES + [LINES[3]]), "", [], ["{measured}", "line 4 and line 74"]),
    ("unknown column", "m.csv", _csv([LINES[0] + ",phase"] + [x + ",0.1" for x in LINES[1:]]), "", [],
     ["{measured}", "'phase'"]),
    ("frequencies out of order", "m.uff", _uff_out_of_order, "", [],
     ["{measured}", "sensor 3) point 6", "out of order"]),
    ("frequency above the model's range", "m.csv", lambda p: _scaled_frequencies(p, 100.0), "", [],
     ["{measured}", "frequency_hz 28500.0", "above 13"]),
    ("empty file", "m.csv", "", "", [], ["{measured}", "empty file"]),
    ("unknown response", "m.csv", _channels(response={3: "s9"}), "", [],
     ["{measured}", "line 4", "unknown response 's9'", "'s1', 's2'"]),
    ("unknown reference", "m.csv", _channels(reference={1: "shaker"}), "", [],
     ["{measured}", "line 2", "unknown reference 'shaker'", "'combined', 'hammer'"]),
    ("a direction the model cannot measure", "m.csv", _channels(response={3: "3:+x"}), "", [],
     ["{measured}", "line 4", "response '3:+x': a direction the model cannot measure", "3:+z ('s3')"]),
    ("mixed FRF kinds without a kind column", "m.csv",
     _channels(comments={1: "# kind = accelerance", 8: "# kind = mobility"}), "", [],
     ["{measured}", "line 9 declares mobility", "line 1 declared accelerance", "mixed FRF kinds"]),
    ("line above the model's band", "m.csv", _channels(frequencies=(100.0, 20000.0)), "", [],
     ["{measured}", "line 8: frequency_hz 20000.0 is above 13"]),
    ("coherence above 1", "m.csv", _channels(coherence={5: "1.5"}), "", [],
     ["{measured}", "line 5: coherence 1.5 is outside [0, 1]"]),
    ("coherence below 0", "m.csv", _channels(coherence={12: "-0.2"}), "", [],
     ["{measured}", "line 12: coherence -0.2 is outside [0, 1]"]),
    ("UFF58 coherence above 1", "m.uff", _uff_coherence_above_1, "", [],
     ["{measured}", "dataset 5 (coherence of response 2:+z, reference 5:+z) point 41: coherence 1.2 is outside [0, 1]"]),
    ("time records without a force channel", "m.csv", lambda p: _records_csv(p, force_column="hammer"), "", [],
     ["{measured}", "no 'force' column: a time record without a force channel"]),
    ("time records with mismatched sample rates", "m.uff", lambda p: _records_uff(p, rate_of_dataset_3=512.0), "",
     [], ["{measured}", "dataset 3: sample rate 512 Hz, but dataset 1 has 256 Hz: mismatched sample rates"]),
    ("a hit without a pulse", "m.csv", lambda p: _records_csv(p, quiet_hit=2), "", [],
     ["{measured}", "hit 2 (line", "no pulse"]),
    ("command line averages of zero", None, None, "", ["--averages", "0"], ["command line", "key 'averages'"]),
    ("duplicated response, reference, frequency", "m.csv",
     _channels(extra_rows=["s2,hammer,100.0,3e-6,1e-7,0.9"]), "", [],
     ["{measured}", "line 3 and line 14 both give response 's2', reference 'hammer' at frequency_hz 100.0"]),
    ("config windows without windows", None, None, 'lines = "windows"', [],
     ["{config}", "key 'line_windows'", "is required with lines = 'windows'"]),
    ("config complex residuals on amplitudes", "m.csv", _amplitude_only(3, "1e-6"), 'residuals = "complex"', [],
     ["key 'residuals'", "amplitudes only", "{measured}"]),
    ("config bad window", None, None, "line_windows = [[120.0, 100.0]]", [],
     ["{config}", "key 'line_windows'", "window 1"]),
    ("command line coherence above 1", None, None, "", ["--min-coherence", "1.5"],
     ["command line", "key 'min_coherence'"]),
    ("command line bad windows", None, None, "", ["--lines", "windows", "--line-windows", "100:120"],
     ["command line", "key 'line_windows'", "'100:120'"]),
    ("binary file", "m.csv", bytes(range(256)) * 4, "", [], ["{measured}", "not a CSV"]),
    ("binary parquet", "m.parquet", b"PAR1" + os.urandom(64), "", [], ["{measured}", "not a Parquet"]),
    ("missing file", None, None, "", ["--measured", "nowhere/m.csv"], ["nowhere/m.csv", "no such file"]),
    ("config not TOML", None, None, "q = = 3", [], ["{config}", "not valid TOML"]),
    ("config unknown key", None, None, 'trainr = "sao"', [], ["{config}", "unknown key 'trainr'"]),
    ("config wrong type", None, None, 'q = "eight"', [], ["{config}", "key 'q' must be int"]),
    ("config float for int", None, None, "s = 4.5", [], ["{config}", "key 's' must be int"]),
    ("config lower >= upper", None, None, "lower = 0.5\nupper = 0.5", [], ["{config}", "key 'lower'"]),
    ("config q of zero", None, None, "q = 0", [], ["{config}", "key 'q'", "at least 1"]),
    ("config s of zero", None, None, "s = 0", [], ["{config}", "key 's'", "at least 1"]),
    ("config unknown trainer", None, None, 'trainer = "newton"', [], ["{config}", "'newton'", "sao, pso, gradient"]),
    ("config bound below -1", None, None, "lower = -1.5", [], ["{config}", "key 'lower'", ">= -1"]),
    ("config true parameter at -1", None, None, "true_parameters = [-0.6, -1.0, -0.3, -0.2, -0.2, -0.4]", [],
     ["{config}", "key 'true_parameters'", "entry 2", "> -1"]),
    ("config true parameter below -1", None, None, "true_parameters = [-0.6, -0.1, -0.3, -0.2, -0.2, -3]", [],
     ["{config}", "key 'true_parameters'", "entry 6"]),
    ("config true parameters wrong length", None, None, "true_parameters = [0.1, 0.2]", [],
     ["key 'true_parameters'", "6 parameters"]),
    ("config negative disk reserve", None, None, "min_free_mb = -5", [], ["{config}", "key 'min_free_mb'"]),
    ("command line s of zero", None, None, "", ["-s", "0"], ["command line", "key 's'"]),
    ("command line unknown trainer", None, None, "", ["--trainer", "newton"], ["--trainer", "invalid choice"]),
    ("config key that is gone", None, None, 'loop = "paper"', [], ["{config}", "key 'loop'", "removed"]),
    ("config unknown emulation", None, None, 'emulate = "frf"', [], ["{config}", "key 'emulate'", "modes, errors"]),
    # the paper's loop fits its first MRGP (linear mean [1, x]: 7 columns on the benchmark's 6 factors) on q runs
    ("command line q below the first MRGP's columns", None, None, "", ["--strategy", "adaptive", "-q", "6"],
     ["key 'q'", "7 columns", "at least 7 runs", "got 6", "raise -q"]),
]


def _snapshot(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def existing_run(tmp_path) -> Path:
    """A run folder as a run leaves it after its start: the manifest of the default settings."""
    runs = tmp_path / "runs"
    # As the command line makes it for the benchmark measurement (true parameters known).
    config = load_config(None, runs_dir=str(runs), run_id="existing", true_parameters=ALPHA_ACTUAL.tolist())
    store = RunStore(runs / "existing")
    write_manifest(store, config)
    (store.root / "iteration=1" / "stage=samples").mkdir(parents=True)
    return store.root


@pytest.mark.parametrize("run_id", ["new", "existing"])
@pytest.mark.parametrize("case", BAD_INPUTS, ids=[c[0] for c in BAD_INPUTS])
def test_bad_input_exits_2_names_the_place_and_writes_nothing(case, run_id, tmp_path, existing_run, capsys):
    _, name, content, config_text, extra, needles = case
    runs = tmp_path / "runs"
    args = ["--run-id", run_id, "--runs-dir", str(runs)]
    measured = None
    if name is not None:
        measured = tmp_path / name
        if callable(content):
            content(measured)
        elif isinstance(content, bytes):
            measured.write_bytes(content)
        else:
            measured.write_text(content)
        args += ["--measured", str(measured)]
    config = None
    if config_text:
        config = tmp_path / "bad.toml"
        config.write_text(config_text + "\n")
        args += ["--config", str(config)]
    before = _snapshot(runs)
    if "invalid choice" in needles:  # argparse's own refusal: SystemExit(2)
        with pytest.raises(SystemExit) as info:
            update.main(args + extra)
        code = info.value.code
    else:
        code = update.main(args + extra)
    err = capsys.readouterr().err
    assert code == 2, err
    for needle in needles:
        assert needle.format(measured=measured, config=config) in err, err
    assert "Traceback" not in err
    assert _snapshot(runs) == before  # the existing run folder unchanged
    assert not (runs / "new").exists()


def test_resume_with_other_settings_is_refused_before_any_write(tmp_path, existing_run, capsys):
    before = _snapshot(existing_run)
    assert update.main(["--run-id", "existing", "--runs-dir", str(tmp_path / "runs"), "--seed", "5"]) == 2
    err = capsys.readouterr().err
    assert f"{existing_run / 'manifest.json'}: run 'existing' was started with other inputs: setting seed (" in err
    assert _snapshot(existing_run) == before


def test_the_model_frequency_limit_follows_the_six_elements_per_wavelength_rule():
    """An independent check of max_frequency_hz: bending wavelength at that frequency = 6 x 14.375 mm."""
    from flows.preflight import max_frequency_hz

    f = max_frequency_hz("three_plate")
    E, nu, rho, t = 2.06e11, 0.3, 7850.0, 0.010  # SPEC.md section 3
    D = E * t**3 / (12 * (1 - nu**2))
    wavelength = 2 * np.pi / (2 * np.pi * f) ** 0.5 * (D / (rho * t)) ** 0.25
    assert wavelength == pytest.approx(6 * 0.230 / 16, rel=1e-12)
    assert 295.0 < f  # the benchmark's measurement is inside


def test_the_real_command_exits_2(tmp_path):
    bad = tmp_path / "m.csv"
    bad.write_text(_replace(7, 2, "nan"))
    runs = tmp_path / "runs"
    proc = subprocess.run([sys.executable, "-m", "flows.update", "--measured", str(bad), "--runs-dir", str(runs),
                           "--run-id", "x"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert f"{bad}: line 7: amplitude is nan" in proc.stderr
    assert not runs.exists() or not any(runs.iterdir())
