"""Configuration of an updating run: defaults (Table 2), a TOML file, CLI overrides.

Every key is documented in ``data/update.example.toml``. A TOML file may set
any subset of the keys at its top level; unknown keys and wrong types are
refused with a :class:`ConfigError` that names the file and the key.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["UpdateConfig", "ConfigError", "load_config", "stored_settings", "TRAINERS", "STRATEGIES",
           "EMULATES", "MODELS", "OUTPUTS", "LINES", "RESIDUALS", "parse_windows"]

REPO = Path(__file__).resolve().parents[1]
TRAINERS = ("sao", "pso", "gradient")
STRATEGIES = ("hybrid", "adaptive", "conventional")
EMULATES = ("modes", "errors")  # what the paper loop's MRGP emulates (strategies.paper)
MODELS = ("three_plate",)
FE_BACKENDS = ("loky", "dask")  # tasks.fe_backends.FE_BACKENDS
OUTPUTS = ("full", "reduced", "auto")  # strategies.emulation.reduced_outputs
LINES = ("all", "windows", "resonances")  # tasks.lines.LINE_MODES
RESIDUALS = ("auto", "amplitude", "complex")  # tasks.update_data.RESIDUALS

#: Keys added after runs were made whose default changed what a run does: a run manifest without the key was
#: made with this value (a run of the paper loop before ``emulate`` existed emulated the errors).
BEFORE_THEIR_KEY = {"emulate": "errors"}
#: Keys of earlier versions that are gone, and why.
REMOVED_KEYS = {"loop": "the trust-region variant of the paper loop, dominated by its modal emulation: "
                        "docs/update-results.md"}


def stored_settings(config: dict) -> dict:
    """A run manifest's ``config`` with the values its run used for keys added since (:data:`BEFORE_THEIR_KEY`),
    without keys that are gone (:data:`REMOVED_KEYS`)."""
    return {k: v for k, v in {**BEFORE_THEIR_KEY, **config}.items() if k not in REMOVED_KEYS}


class ConfigError(ValueError):
    """A configuration value that cannot be used; the message names its source and key."""


@dataclass(frozen=True)
class UpdateConfig:
    """All settings of one updating run (defaults: Table 2 of Zhou & Tang).

    Attributes
    ----------
    run_id : str or None
        Folder name under ``runs_dir``; a new id is made when None.
    runs_dir : str
    measured : str
        Measured FRF amplitudes (CSV, Parquet or UFF58).
    model : str
        FE model: a name (``three_plate``, the benchmark) or the path of a model
        file ``model.toml`` (relative to the repository when not absolute; see
        :mod:`fe_core.io.model_toml`). Parameter names and count come from the model.
    strategy : {"hybrid", "adaptive", "conventional"}
        ``hybrid`` (default, :mod:`flows.hybrid`): Gauss-Newton with exact
        Jacobians from the nominal model; when what is left is not noise,
        global cycles (``s`` space-filling FE runs, an MRGP emulator over
        ``w`` candidates, ``starts`` parallel Gauss-Newton runs); its budget
        ``max_fe_evaluations`` counts FE-run equivalents (an FE run with its
        Jacobian costs :data:`tasks.fe_runs.JACOBIAN_COST`), its target is
        ``polish_target``, its noise level ``noise`` (or estimated).
        ``adaptive`` is the paper's MRGP loop (with ``polish = false``
        exactly its procedure); ``conventional`` is Section 3.4's baseline:
        ``conventional_samples`` uniform FE runs, one MRGP, the best of ``w``
        predictions.
    trainer : {"sao", "pso", "gradient"}
        MRGP hyper-parameter trainer.
    seed : int
        Master seed; every stage derives its own generator from it.
    n_jobs : int
        Parallel FE runs (joblib; -1 = all cores); loky backend only.
    fe_backend : {"loky", "dask"}
        Where FE runs execute: loky processes on this machine, or the
        workers of the Dask cluster at ``dask_address``
        (:mod:`tasks.fe_backends`). Results do not depend on it.
    dask_address : str or None
        Scheduler address for ``fe_backend = "dask"``, e.g.
        ``tcp://10.0.0.5:8786``; not used with loky.
    repeats : int
        Independent runs with seeds ``seed, seed + 1, ...`` (Figures 10-13).
    q, w, s, z : int
        Initial samples, candidates per iteration, FE runs per iteration,
        best samples defining the sampling distribution.
    threshold : float
        Overall error (Eq. 6b) that ends the run, e.g. 0.01 = 1 %.
    max_iterations, max_fe_evaluations : int
        Budgets (iteration 1 is the initial sampling).
    lower, upper : float
        Search box for every parameter; ``lower`` must be >= -1 (the
        domain's edge, itself excluded).
    min_distance_factor : float
        Minimum distance between samples selected in one iteration, as a
        fraction of the sampling distribution's spread.
    std_floor : float
        Smallest standard deviation of the sampling distribution.
    conventional_samples : int
    polish : bool
        After the MRGP loop (adaptive strategy only), run the polish stage:
        trust-region least squares on the FE model from the best sample
        (:mod:`tasks.polish`). Its FE runs count in ``fe_evaluations``.
    polish_max_fe : int
        FE runs reserved for the polish out of ``max_fe_evaluations``: the
        MRGP loop stops at ``max_fe_evaluations - polish_max_fe``. The
        default, 200 of 240, hands over after 2 iterations (40 FE runs):
        ``python -m benchmarks.handover`` (docs/handover.md) polished from
        the loop's best sample after k = 1, 2, 3 iterations; k = 2 reached
        the noise floor in every seed with the fewest FE runs in total, k = 1
        missed it in some seeds (and in session 2's trials, k = 5 and k = 8
        in most: later iterations narrow in on wrong basins).
    polish_target : float
        Overall error at which the polish stops, e.g. 1e-4 = 0.01 %
        (the noise floor of noise-free data; set it near the measurement's
        noise level for real data).
    polish_stall_rtol : float
        The polish also stops when its best overall error improved by less
        than this (relative) over its last three Jacobians and steps
        (``3 * (m + 1)`` FE runs): on noisy data the error levels off at the
        noise and cannot reach ``polish_target``. 0 turns this stop off.
    true_parameters : list of float or None
        Known true values (synthetic data), only for reporting errors;
        each must be > -1.
    intervals : bool
        After the polish, 95 % intervals and the covariance of the
        parameters (:mod:`tasks.intervals`: Gauss-Newton steps to the
        log-amplitude least-squares optimum, exact Jacobian, at most
        3 Jacobians), written to ``summary.json``.
    posterior_fe : int
        FE runs of the sampled posterior (:mod:`fe_core.inference.posterior`) that
        replaces the Laplace intervals where their linearisation fails its
        check (an interval crossing the box, a curved valley); 0 = never
        sample. Default 400.
    noise : float or None
        Relative noise of the measured amplitudes (standard deviation, e.g.
        0.01 = 1 %) for the intervals; None (default) estimates it from the
        residual at the least-squares optimum.
    averages : int or None
        The number of averages (hits) behind each measured FRF and its coherence, where the file does not
        say (UFF58 ID lines, a table's ``averages``); with the coherence it gives the noise per line
        (:func:`fe_core.inference.coherence_noise.frf_random_error`). None (default): the file's, or unknown.
    lines : {"all", "windows", "resonances"}
        Which measured frequency lines enter the update (:mod:`tasks.lines`):
        every line (default), those in ``line_windows``, or windows around the
        measured resonances (half-power band widened by ``resonance_widen``).
    line_windows : list of [low, high] or None
        Hz, for ``lines = "windows"``.
    resonance_widen : float
        Factor (>= 1) on each resonance's half-power band, for ``lines = "resonances"``.
    min_coherence : float
        Values (line, channel) whose measured coherence is below this are left
        out and counted (default 0.9; data without coherence lose nothing).
    residuals : {"auto", "amplitude", "complex"}
        The residual (:mod:`tasks.update_data`): the paper's amplitude
        residual of Eq. (5), the real and imaginary parts of ``(Z - H)/|H|``,
        or auto (default): complex when the data carry phase, amplitude for
        the legacy ``sensor`` form.
    min_free_mb : float
        Free disk space the run folder needs before any work starts, MB;
        0 (default) = twice the run's estimated output
        (:func:`flows.preflight.expected_output_mb`).
    outputs : {"auto", "full", "reduced"}
        How the MRGP emulates the k responses: ``full`` (the paper's k x k
        ``Q``), ``reduced`` (a reduced output basis, :mod:`mrgp_core.reduced`)
        or ``auto`` (default): reduced when k > 200
        (:data:`strategies.emulation.AUTO_REDUCED_ABOVE`), so the benchmark's k = 72
        keeps the full MRGP.
    starts : int
        Parallel Gauss-Newton runs of a global cycle of the hybrid strategy,
        started from the emulator's best distinct candidates.
    emulate : {"modes", "errors"}
        What the MRGP of the adaptive strategy's paper loop emulates.
        ``modes`` (default, :mod:`strategies.modal_emulation`, a change to the
        paper's loop): the lowest modes of each FE run and the remainder of
        its receptance, one length scale per parameter; a candidate's error
        is computed from the receptance they give, Gauss-Newton end points on
        the emulator's mean join the candidates, the nominal model is one of
        the first samples. ``errors``: the paper's emulation of the relative
        residuals (isotropic, Table 1's ``l~`` bound). Other strategies and
        the trust-region loop ignore it.
    """

    run_id: str | None = None
    runs_dir: str = "runs"
    measured: str = "data/benchmark/measured.csv"
    model: str = "three_plate"
    strategy: str = "hybrid"
    trainer: str = "gradient"
    seed: int = 0
    n_jobs: int = 2
    fe_backend: str = "loky"
    dask_address: str | None = None
    repeats: int = 1
    q: int = 20
    w: int = 10_000
    s: int = 20
    z: int = 20
    threshold: float = 0.01
    max_iterations: int = 12
    max_fe_evaluations: int = 240
    lower: float = -1.0
    upper: float = 1.0
    min_distance_factor: float = 0.1
    std_floor: float = 1e-4
    conventional_samples: int = 300
    polish: bool = True
    polish_max_fe: int = 200
    polish_target: float = 1e-4
    polish_stall_rtol: float = 0.01
    true_parameters: list[float] | None = field(default=None)
    min_free_mb: float = 0.0
    outputs: str = "auto"
    intervals: bool = True
    noise: float | None = None
    averages: int | None = None
    posterior_fe: int = 400
    lines: str = "all"
    line_windows: list[list[float]] | None = field(default=None)
    resonance_widen: float = 2.0
    min_coherence: float = 0.9
    residuals: str = "auto"
    starts: int = 6
    emulate: str = "modes"

    def __post_init__(self) -> None:
        self.validate("config")

    def validate(self, source: str) -> None:
        def bad(key: str, why: str) -> ConfigError:
            return ConfigError(f"{source}: key '{key}': {why}")

        for key in ("q", "w", "s", "z", "max_iterations", "max_fe_evaluations", "repeats", "conventional_samples",
                    "starts"):
            if getattr(self, key) < 1:
                raise bad(key, f"must be at least 1, got {getattr(self, key)}")
        if self.n_jobs == 0 or self.n_jobs < -1:
            raise bad("n_jobs", f"must be a positive number of processes or -1 (all cores), got {self.n_jobs}")
        if self.fe_backend not in FE_BACKENDS:
            raise bad("fe_backend", f"unknown backend {self.fe_backend!r}; choose one of {', '.join(FE_BACKENDS)}")
        if self.fe_backend == "dask" and not self.dask_address:
            raise bad("dask_address", "is required with fe_backend 'dask': the scheduler's address, "
                                      "e.g. tcp://127.0.0.1:8786")
        if self.trainer not in TRAINERS:
            raise bad("trainer", f"unknown trainer {self.trainer!r}; choose one of {', '.join(TRAINERS)}")
        if self.emulate not in EMULATES:
            raise bad("emulate", f"unknown emulation {self.emulate!r}; choose one of {', '.join(EMULATES)}")
        if self.strategy not in STRATEGIES:
            raise bad("strategy", f"unknown strategy {self.strategy!r}; choose one of {', '.join(STRATEGIES)}")
        if self.model not in MODELS:
            check_model_path(self, bad)
        if not self.threshold > 0:
            raise bad("threshold", f"must be positive, got {self.threshold}")
        if self.lower < -1.0:
            raise bad("lower", f"must be >= -1 (stiffness factors live in (-1, inf)), got {self.lower}")
        if not self.lower < self.upper:
            raise bad("lower", f"lower bound {self.lower} must be below upper bound {self.upper}")
        if self.z < 2:
            raise bad("z", f"must be at least 2 to estimate a variance, got {self.z}")
        if not self.min_distance_factor >= 0:
            raise bad("min_distance_factor", f"must be >= 0, got {self.min_distance_factor}")
        if not self.std_floor > 0:
            raise bad("std_floor", f"must be positive, got {self.std_floor}")
        if self.true_parameters is not None:
            for i, v in enumerate(self.true_parameters):
                if not (isinstance(v, (int, float)) and math.isfinite(v) and v > -1.0):
                    raise bad("true_parameters", f"entry {i + 1} is {v!r}; parameters must be finite and > -1")
        if not (math.isfinite(self.min_free_mb) and self.min_free_mb >= 0):
            raise bad("min_free_mb", f"must be >= 0 (0 = derived from the run's size), got {self.min_free_mb}")
        if self.polish and self.strategy == "adaptive":
            if self.polish_max_fe < 1:
                raise bad("polish_max_fe", f"must be at least 1 when polish is on, got {self.polish_max_fe}")
            if self.max_fe_evaluations - self.polish_max_fe < self.q:
                raise bad("polish_max_fe", f"{self.polish_max_fe} reserved for the polish leaves fewer than q = "
                                           f"{self.q} of max_fe_evaluations = {self.max_fe_evaluations} for the "
                                           "MRGP loop")
        if not self.polish_target > 0:
            raise bad("polish_target", f"must be positive, got {self.polish_target}")
        if not 0 <= self.polish_stall_rtol < 1:
            raise bad("polish_stall_rtol", f"must be in [0, 1) (0 = no stagnation stop), got {self.polish_stall_rtol}")
        if self.outputs not in OUTPUTS:
            raise bad("outputs", f"unknown output model {self.outputs!r}; choose one of {', '.join(OUTPUTS)}")
        if self.noise is not None and not (isinstance(self.noise, (int, float)) and 0 < self.noise < 1):
            raise bad("noise", f"must be a relative amplitude noise in (0, 1), e.g. 0.01 = 1 %, got {self.noise!r}")
        if self.averages is not None and not (isinstance(self.averages, int) and self.averages >= 1):
            raise bad("averages", f"must be a whole number of averages >= 1, got {self.averages!r}")
        if not (isinstance(self.posterior_fe, int) and self.posterior_fe >= 0):
            raise bad("posterior_fe", f"must be a whole number of FE runs >= 0 (0 = never sample), "
                                      f"got {self.posterior_fe!r}")
        self._validate_lines(bad)
        if self.run_id is not None and (not self.run_id or "/" in self.run_id or self.run_id.startswith(".")):
            raise bad("run_id", f"must be a plain folder name, got {self.run_id!r}")

    def _validate_lines(self, bad) -> None:
        if self.lines not in LINES:
            raise bad("lines", f"unknown line selection {self.lines!r}; choose one of {', '.join(LINES)}")
        if self.line_windows is not None:
            for i, w in enumerate(self.line_windows):
                ok = (isinstance(w, (list, tuple)) and len(w) == 2
                      and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in w))
                if not ok or not 0 <= w[0] < w[1]:
                    raise bad("line_windows", f"window {i + 1} is {w!r}; each window is [low, high] in Hz with "
                                              "0 <= low < high")
        if self.lines == "windows" and not self.line_windows:
            raise bad("line_windows", "is required with lines = 'windows', e.g. [[100.0, 120.0], [280.0, 300.0]]")
        if not (isinstance(self.resonance_widen, (int, float)) and math.isfinite(self.resonance_widen)
                and self.resonance_widen >= 1):
            raise bad("resonance_widen", f"must be a factor >= 1 on the half-power band, got {self.resonance_widen!r}")
        if not 0 <= self.min_coherence <= 1:
            raise bad("min_coherence", f"must lie in [0, 1] (0 keeps every line), got {self.min_coherence!r}")
        if self.residuals not in RESIDUALS:
            raise bad("residuals", f"unknown residual {self.residuals!r}; choose one of {', '.join(RESIDUALS)}")

    def replace(self, **changes: Any) -> "UpdateConfig":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def resolve(self, path: str) -> Path:
        """A path from the config, relative to the repository when not absolute."""
        p = Path(path)
        return p if p.is_absolute() else REPO / p


def check_model_path(config: UpdateConfig, bad) -> None:
    """``model`` is not a known name: it must be an existing ``.toml`` model file."""
    path = config.resolve(config.model)
    if path.suffix != ".toml":
        raise bad("model", f"unknown model {config.model!r}; give a model name ({', '.join(MODELS)}) "
                           "or the path of a model file (.toml)")
    if not path.is_file():
        raise bad("model", f"model file {str(path)!r} does not exist")


_TYPES: dict[str, tuple[type, ...]] = {}
for _f in dataclasses.fields(UpdateConfig):
    if _f.name in ("true_parameters", "line_windows"):
        _TYPES[_f.name] = (list,)
    elif _f.type in ("bool", bool):
        _TYPES[_f.name] = (bool,)
    elif _f.type in ("int", int):
        _TYPES[_f.name] = (int,)
    elif _f.type in ("float", float, "float | None"):
        _TYPES[_f.name] = (int, float)
    else:
        _TYPES[_f.name] = (str,)


def _check_types(values: dict[str, Any], source: str) -> dict[str, Any]:
    known = {f.name for f in dataclasses.fields(UpdateConfig)}
    for key, value in values.items():
        if key in REMOVED_KEYS:
            raise ConfigError(f"{source}: key '{key}' was removed ({REMOVED_KEYS[key]}); delete it")
        if key not in known:
            raise ConfigError(f"{source}: unknown key '{key}'; valid keys are {', '.join(sorted(known))}")
        expected = _TYPES[key]
        if (isinstance(value, bool) and bool not in expected) or not isinstance(value, expected):
            names = " or ".join(t.__name__ for t in expected)
            raise ConfigError(f"{source}: key '{key}' must be {names}, got {type(value).__name__} {value!r}")
        if key == "true_parameters" and not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
        ):
            raise ConfigError(f"{source}: key 'true_parameters' must be a list of numbers, got {value!r}")
    return values


def parse_windows(text: str) -> list[list[float]]:
    """``"100-120,280-300"`` -> ``[[100.0, 120.0], [280.0, 300.0]]`` (the ``--line-windows`` flag)."""
    out = []
    for part in text.split(","):
        lo, sep, hi = part.strip().partition("-")
        try:
            if not sep:
                raise ValueError
            out.append([float(lo), float(hi)])
        except ValueError:
            raise ConfigError(f"command line: key 'line_windows': {part.strip()!r} is not LOW-HIGH in Hz "
                              "(e.g. --line-windows 100-120,280-300)") from None
    return out


def load_config(path: str | Path | None = None, **overrides: Any) -> UpdateConfig:
    """Defaults, then the TOML file (if any), then non-None ``overrides``.

    Raises
    ------
    ConfigError
        Naming the file (or "command line") and the key.
    """
    values: dict[str, Any] = {}
    source = "defaults"
    if path is not None:
        path = Path(path)
        source = str(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read the config file ({exc.strerror})") from exc
        try:
            values = tomllib.loads(text)
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path}: not valid TOML ({exc})") from exc
        for key, value in values.items():
            if isinstance(value, dict):
                raise ConfigError(f"{path}: key '{key}' is a table; all settings go at the top level")
        _check_types(values, source)
    cli = _check_types({k: v for k, v in overrides.items() if v is not None}, "command line")
    merged = {**values, **cli}
    try:
        config = UpdateConfig(**merged)
    except ConfigError as exc:
        # Re-attribute to the source that set the key.
        key = str(exc).split("'")[1] if "'" in str(exc) else ""
        origin = "command line" if key in cli else source
        raise ConfigError(str(exc).replace("config:", f"{origin}:", 1)) from None
    return config
