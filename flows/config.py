"""Configuration of an updating run: defaults, a TOML file, CLI overrides, all made from one declaration.

Every setting is declared once, as a dataclass field with its help (:func:`strategies.options.setting`): the
run's own settings in :class:`RunSettings` below, each strategy's in its options dataclass (``HybridOptions``,
``PaperOptions``, ``PolishOptions``, ...), registered in :mod:`strategies.registry`. :class:`UpdateConfig` (the
run's config, one flat set of keys), the keys a TOML file may set (``data/update.example.toml`` lists them all)
and the command line's flags with their ``--help`` (:func:`add_setting_flags`) are made from those fields; a
strategy's options are made back from the config (:func:`strategies.options.from_settings`). A TOML file may
set any subset of the keys at its top level; unknown keys and wrong types are refused with a
:class:`ConfigError` that names the file and the key.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from strategies import registry
from strategies.options import Key, keys_of, setting
from strategies.paper import EMULATES, TRAINERS
from tasks.fe_backends import FE_BACKENDS
from tasks.lines import LINE_MODES as LINES
from tasks.update_data import RESIDUALS

__all__ = ["UpdateConfig", "RunSettings", "KEYS", "ConfigError", "load_config", "stored_settings", "TRAINERS",
           "STRATEGIES", "EMULATES", "MODELS", "OUTPUTS", "LINES", "RESIDUALS", "parse_windows", "add_setting_flags",
           "settings_from_args"]

REPO = Path(__file__).resolve().parents[1]
STRATEGIES = registry.names()
MODELS = ("three_plate",)
OUTPUTS = ("full", "reduced", "auto")  # strategies.emulation.reduced_outputs

#: Keys added after runs were made whose default changed what a run does: a run manifest without the key was
#: made with this value (a run of the paper loop before ``emulate`` existed emulated the errors).
BEFORE_THEIR_KEY = {"emulate": "errors"}
#: Keys of earlier versions that are gone, and why.
REMOVED_KEYS = {"loop": "the trust-region variant of the paper loop, dominated by its modal emulation: "
                        "git show 0cbca1f:docs/update-results.md"}


def stored_settings(config: dict) -> dict:
    """A run manifest's ``config`` with the values its run used for keys added since (:data:`BEFORE_THEIR_KEY`),
    without keys that are gone (:data:`REMOVED_KEYS`)."""
    return {k: v for k, v in {**BEFORE_THEIR_KEY, **config}.items() if k not in REMOVED_KEYS}


class ConfigError(ValueError):
    """A configuration value that cannot be used; the message names its source and key."""


@dataclass(frozen=True)
class RunSettings:
    """The run's own settings (those of its strategy: the strategy's options dataclass)."""

    run_id: str | None = setting(None, metavar="ID", help="the run folder's name under runs_dir; an existing id "
                                 "resumes that run; omitted: a new time-stamped id")
    runs_dir: str = setting("runs", metavar="PATH", help="where run folders go")
    measured: str = setting("data/benchmark/measured.csv", metavar="PATH", help="measured FRFs: .csv, .parquet or "
                            ".uff (docs/guide/measured-formats.md); measured modes (.uff dataset 55, a modal CSV) take "
                            "the modal update (docs/guide/modal-data.md)")
    model: str = setting("three_plate", metavar="NAME|PATH", help="FE model: three_plate (the benchmark) or a model "
                         "file model.toml (docs/guide/model-files.md), relative to the repository when not absolute")
    strategy: str = setting("hybrid", choices=STRATEGIES, help="; ".join(
        f"{s.name}: {s.help}" for s in registry.REGISTRY.values()) + " (docs/guide/strategies.md)")
    seed: int = setting(0, help="master random seed; every stage derives its own generator from it")
    n_jobs: int = setting(2, help="parallel FE processes (joblib; -1 = all cores); loky backend only")
    fe_backend: str = setting("loky", choices=FE_BACKENDS, help="where FE runs execute: loky processes here, or the "
                              "workers of the Dask cluster at dask_address (results do not depend on it)")
    dask_address: str | None = setting(None, metavar="ADDR", help="Dask scheduler for fe_backend dask, e.g. "
                                       "tcp://127.0.0.1:8786")
    repeats: int = setting(1, help="independent runs with seeds seed..seed+N-1 (Figures 10-13)")
    max_fe_evaluations: int = setting(240, help="FE-run budget of the strategy (the hybrid's in FE-run "
                                      "equivalents: an FE run with its exact Jacobian costs 2.5)")
    lower: float = setting(-1.0, help="lower end of every parameter's search box (>= -1, the domain's edge, itself "
                           "excluded); a model file's bounds take precedence")
    upper: float = setting(1.0, help="upper end of every parameter's search box")
    true_parameters: list[float] | None = setting(None, metavar="A,B,...", help="known true values (synthetic "
                                                  "data), only for reporting parameter errors; each > -1")
    min_free_mb: float = setting(0.0, help="free disk space the runs folder needs before any work starts, MB; 0 = "
                                 "twice the run's estimated output")
    intervals: bool = setting(True, help="after the update, 95 % intervals and the covariance of the parameters "
                              "(strategies ending with a local least-squares fit; their noise level: noise, else "
                              "estimated from the residual)")
    noise: float | None = setting(None, metavar="SIGMA", help="relative noise of the measured amplitudes (standard "
                                  "deviation, e.g. 0.01 = 1 %) for the hybrid's check, the intervals and the closure; "
                                  "default: estimated from the residual")
    posterior_fe: int = setting(400, metavar="N", help="FE runs of the sampled posterior used instead of the Laplace "
                                "intervals where their linearisation fails its check (a bound, a curved valley); "
                                "0 = never")
    lines: str = setting("all", choices=LINES, help="measured lines that enter the update: all, those in "
                         "line_windows, or windows around the measured resonances (half-power band x "
                         "resonance_widen)")
    line_windows: list[list[float]] | None = setting(None, metavar="LO-HI[,LO-HI...]", help="frequency windows in "
                                                     "Hz for lines = windows, e.g. 100-120,280-300")
    resonance_widen: float = setting(2.0, metavar="F", help="factor (>= 1) on each resonance's half-power band for "
                                     "lines = resonances")
    min_coherence: float = setting(0.9, metavar="C", help="leave out measured values whose coherence is below C "
                                   "(0 keeps every value; data without coherence lose nothing)")
    averages: int | None = setting(None, metavar="N", help="the number of averages (hits) behind the measured FRFs "
                                   "and coherence where the file does not say (UFF58 ID lines, a table's averages); "
                                   "with the coherence it sets the noise per line")
    residuals: str = setting("auto", choices=RESIDUALS, help="amplitude residuals (Eq. 5), complex ones (real and "
                             "imaginary parts of (Z - H)/|H|), or auto: complex when the data carry phase, except "
                             "the legacy sensor form")


def _keys() -> list[Key]:
    """Every config key, declared once: the run's, then each registered strategy's options."""
    out: dict[str, Key] = {}
    bound: dict[str, str] = {}
    for cls in [RunSettings, *registry.option_classes()]:
        declared, uses = keys_of(cls)
        for key in declared:
            if key.name in out:
                raise TypeError(f"config key {key.name!r} declared twice: by {out[key.name].owner} and {key.owner}")
            out[key.name] = key
        bound.update({k: cls.__name__ for k in uses.values()})
    missing = sorted(set(bound) - set(out))
    if missing:
        raise TypeError(f"config keys used but declared nowhere: {', '.join(missing)}")
    return list(out.values())


#: Every key of the run's config, in the order of :class:`UpdateConfig`'s fields.
KEYS = _keys()
#: What a refused choice is called in its message ("unknown backend 'x'"), where not the key's name.
CHOICE_WORDS = {"fe_backend": "backend", "emulate": "emulation", "outputs": "output model", "lines": "line selection",
                "residuals": "residual"}


class _Config:
    """The methods of :class:`UpdateConfig` (its fields: :data:`KEYS`)."""

    def __post_init__(self) -> None:
        self.validate("config")

    def validate(self, source: str) -> None:
        def bad(key: str, why: str) -> ConfigError:
            return ConfigError(f"{source}: key '{key}': {why}")

        for key in ("q", "w", "s", "z", "max_iterations", "max_fe_evaluations", "repeats", "conventional_samples",
                    "starts"):
            if getattr(self, key) < 1:
                raise bad(key, f"must be at least 1, got {getattr(self, key)}")
        for key in KEYS:  # the choices as each key declares them (``setting(choices=...)``)
            value = getattr(self, key.name)
            if key.choices and value not in key.choices:
                raise bad(key.name, f"unknown {CHOICE_WORDS.get(key.name, key.name)} {value!r}; choose one of "
                                    f"{', '.join(key.choices)}")
        if self.n_jobs == 0 or self.n_jobs < -1:
            raise bad("n_jobs", f"must be a positive number of processes or -1 (all cores), got {self.n_jobs}")
        if self.fe_backend == "dask" and not self.dask_address:
            raise bad("dask_address", "is required with fe_backend 'dask': the scheduler's address, "
                                      "e.g. tcp://127.0.0.1:8786")
        if self.model not in MODELS:
            check_model_path(self, bad)
        if not self.threshold > 0:
            raise bad("threshold", f"must be positive, got {self.threshold}")
        if self.averages is not None and not (isinstance(self.averages, int) and self.averages >= 1):
            raise bad("averages", f"must be a whole number of averages >= 1, got {self.averages!r}")
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
        if not self.coordinate_step > 0:
            raise bad("coordinate_step", f"must be positive, got {self.coordinate_step}")
        if not self.polish_target > 0:
            raise bad("polish_target", f"must be positive, got {self.polish_target}")
        if not 0 <= self.polish_stall_rtol < 1:
            raise bad("polish_stall_rtol", f"must be in [0, 1) (0 = no stagnation stop), got {self.polish_stall_rtol}")
        if self.noise is not None and not (isinstance(self.noise, (int, float)) and 0 < self.noise < 1):
            raise bad("noise", f"must be a relative amplitude noise in (0, 1), e.g. 0.01 = 1 %, got {self.noise!r}")
        if not (isinstance(self.posterior_fe, int) and self.posterior_fe >= 0):
            raise bad("posterior_fe", f"must be a whole number of FE runs >= 0 (0 = never sample), "
                                      f"got {self.posterior_fe!r}")
        self._validate_lines(bad)
        if self.run_id is not None and (not self.run_id or "/" in self.run_id or self.run_id.startswith(".")):
            raise bad("run_id", f"must be a plain folder name, got {self.run_id!r}")

    def _validate_lines(self, bad) -> None:
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

    def replace(self, **changes: Any) -> "UpdateConfig":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def resolve(self, path: str) -> Path:
        """A path from the config, relative to the repository when not absolute."""
        p = Path(path)
        return p if p.is_absolute() else REPO / p


def _docstring() -> str:
    lines = ["All settings of one updating run, one field per key of :data:`KEYS` (made from their declarations).",
             "", "Attributes", "----------"]
    for k in KEYS:
        lines += [f"{k.name} : {getattr(k.type, '__name__', str(k.type))} (default {k.default!r}; {k.owner})",
                  f"    {k.help}"]
    return "\n".join(lines)


UpdateConfig = dataclasses.make_dataclass(
    "UpdateConfig", [(k.name, k.type, dataclasses.field(default=None if k.default is None else k.default))
                     for k in KEYS], bases=(_Config,), frozen=True)
UpdateConfig.__module__, UpdateConfig.__doc__ = __name__, _docstring()


def check_model_path(config, bad) -> None:
    """``model`` is not a known name: it must be an existing ``.toml`` model file."""
    path = config.resolve(config.model)
    if path.suffix != ".toml":
        raise bad("model", f"unknown model {config.model!r}; give a model name ({', '.join(MODELS)}) "
                           "or the path of a model file (.toml)")
    if not path.is_file():
        raise bad("model", f"model file {str(path)!r} does not exist")


def _accepts(tp) -> tuple[type, ...]:
    """The TOML value types a key of type ``tp`` accepts."""
    args = [a for a in typing.get_args(tp) if a is not type(None)] or [tp]
    base = typing.get_origin(args[0]) or args[0]
    if base is list:
        return (list,)
    if base is bool:
        return (bool,)
    if base is int:
        return (int,)
    if base is float:
        return (int, float)
    return (str,)


_TYPES: dict[str, tuple[type, ...]] = {k.name: _accepts(k.type) for k in KEYS}


def _check_types(values: dict[str, Any], source: str) -> dict[str, Any]:
    known = set(_TYPES)
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


# -- the command line, from the same declarations ------------------------------------------------------------
def _comma_floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"command line: {text!r} is not a comma-separated list of numbers") from None


def add_setting_flags(parser, skip: tuple = ()) -> None:
    """A flag for every key of :data:`KEYS` (its ``--help`` from the key's declaration; none for ``skip``):
    ``--max-fe-evaluations``, ``-q``, ``--polish/--no-polish``, ``--true-parameters 0.1,0.2``,
    ``--line-windows 100-120,280-300``. Every flag defaults to None (not given: the config file's or the
    default value)."""
    import argparse

    for key in KEYS:
        if key.name in skip or not key.flags:
            continue
        kind = _accepts(key.type)
        default = "" if key.default is None else f" (default {key.default})"
        kw = {"dest": key.name, "default": None, "help": (key.help + default).replace("%", "%%")}
        if key.metavar:
            kw["metavar"] = key.metavar
        if kind == (bool,):
            kw["action"] = argparse.BooleanOptionalAction
        elif key.choices:
            kw["choices"] = key.choices
        elif key.name == "line_windows":
            kw["type"] = str
        elif kind == (list,):
            kw["type"] = _comma_floats
        else:
            kw["type"] = {(int,): int, (int, float): float}.get(kind, str)
        parser.add_argument(*key.flags, **kw)


def settings_from_args(args) -> dict[str, Any]:
    """The keys given on the command line (parsed by :func:`add_setting_flags`), for :func:`load_config`."""
    out = {k.name: getattr(args, k.name, None) for k in KEYS}
    if out.get("line_windows") is not None:
        out["line_windows"] = parse_windows(out["line_windows"])
    return out
