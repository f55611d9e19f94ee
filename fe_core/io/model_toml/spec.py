"""The model file's tables: loading (:func:`_load`), type and key checks that name the file and the key
(:class:`ModelFileError`, :class:`_Spec`, :func:`_get`, :func:`_keys`, :func:`_tables`), the files a model
refers to (:func:`model_files`), and what the mesh and matrices builders share: the unit systems, the
segments' parameters and bounds, the DOFs a support fixes."""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..matrices import DIRECTIONS

__all__ = ["ModelFileError", "model_files", "UNITS", "UPDATES"]


#: Unit systems: (length to m, stress to Pa, density to kg/m^3).
UNITS = {"SI": (1.0, 1.0, 1.0), "mm-t-s": (1e-3, 1e6, 1e12)}

_TOP_KEYS = {"units", "mesh", "matrices", "point_tolerance", "point_placement", "excitation", "damping", "elements",
             "materials", "segments", "supports", "sensors", "excitations", "name", "description",
             "solver", "deck", "solver_timeout", "include_paths", "parameters", "n_modes"}


class ModelFileError(ValueError):
    """A model file that cannot be used; the message names the file and the key."""


@dataclass
class _Spec:
    """The model file's tables after type checks (paths resolved)."""

    path: Path
    data: dict

    def error(self, key: str, why: str) -> ModelFileError:
        return ModelFileError(f"{self.path}: key '{key}': {why}")

    def file(self, key: str, value: str) -> Path:
        p = Path(value)
        p = p if p.is_absolute() else self.path.parent / p
        if not p.exists():
            raise self.error(key, f"file {str(p)!r} does not exist")
        return p


_MISSING = object()


def _get(spec: _Spec, table: dict, key: str, where: str, types: tuple, default: Any = _MISSING) -> Any:
    name = f"{where}.{key}" if where else key
    if key not in table:
        if default is _MISSING:
            raise spec.error(name, "is missing")
        return default
    value = table[key]
    numeric = float in types
    ok = isinstance(value, types) or (numeric and isinstance(value, int))
    if isinstance(value, bool) and bool not in types:
        ok = False
    if not ok:
        names = " or ".join("number" if t is float else "table" if t is dict else t.__name__ for t in types)
        raise spec.error(name, f"must be {names}, got {type(value).__name__} {value!r}")
    return float(value) if numeric and isinstance(value, int) and not isinstance(value, bool) else value


def _keys(spec: _Spec, table: dict, allowed: set, where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise spec.error(f"{where}.{unknown[0]}" if where else unknown[0],
                         f"unknown key; valid keys here are {', '.join(sorted(allowed))}")


def _tables(spec: _Spec, key: str, required: bool = True) -> list[dict]:
    value = spec.data.get(key)
    if value is None:
        if required:
            raise spec.error(key, f"is missing: give at least one [[{key}]] table")
        return []
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise spec.error(key, f"must be an array of tables ([[{key}]]), got {type(value).__name__}")
    if required and not value:
        raise spec.error(key, f"is empty: give at least one [[{key}]] table")
    return value


def _load(path: Path) -> _Spec:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ModelFileError(f"{path}: no such model file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"{path}: cannot read the model file ({exc})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ModelFileError(f"{path}: not valid TOML ({exc})") from None
    spec = _Spec(path, data)
    _keys(spec, data, _TOP_KEYS, "")
    if sum(k in data for k in ("mesh", "matrices", "deck")) != 1:
        raise spec.error("mesh", "give exactly one of 'mesh' (a mesh file), a [matrices] table or 'deck' (a "
                                 "solver's input deck, with solver = \"calculix\")")
    return spec


def model_files(path: str | Path) -> list[Path]:
    """The model file and every file it refers to (mesh, matrices, DOF table), existing ones only."""
    path = Path(path)
    spec = _load(path)
    out = [path]
    names = []
    for key in ("mesh", "deck"):
        if isinstance(spec.data.get(key), str):
            names.append(spec.data[key])
    mat = spec.data.get("matrices")
    if isinstance(mat, dict):
        names += [v for v in mat.values() if isinstance(v, str)]
    for seg in spec.data.get("segments", []) if isinstance(spec.data.get("segments"), list) else []:
        if isinstance(seg, dict):
            names += [seg[k] for k in ("stiffness", "mass") if isinstance(seg.get(k), str)]
    for name in names:
        p = Path(name) if Path(name).is_absolute() else path.parent / name
        if p.exists():
            out.append(p)
    if isinstance(spec.data.get("deck"), str) and len(out) > 1 and out[-1].suffix.lower() == ".inp":
        out += _included(out[-1])
    return out


def _included(deck: Path, depth: int = 0) -> list[Path]:
    """The files a deck includes (``*INCLUDE, INPUT=...``), those that exist, recursively."""
    found = []
    for line in deck.read_text(errors="replace").splitlines():
        text = line.strip()
        if text.upper().startswith("*INCLUDE") and "=" in text and depth < 10:
            p = Path(text.split("=", 1)[1].strip().strip("\"'"))
            p = p if p.is_absolute() else deck.parent / p
            if p.exists():
                found += [p] + _included(p, depth + 1)
    return found


def _bounds(spec: _Spec, value: Any, key: str, segment: str, symbol: str) -> tuple[float, float]:
    if not (isinstance(value, list) and len(value) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise spec.error(key, f"must be [lower, upper], got {value!r}")
    lo, hi = map(float, value)
    what = "stiffness" if symbol == "alpha" else "mass"
    if not (-1.0 <= lo < hi and np.isfinite(hi)):
        raise spec.error(key, f"segment {segment!r}: need -1 <= lower < upper ({symbol} > -1 keeps the {what} "
                              f"positive), got {value!r}")
    return lo, hi


#: What a segment's ``update`` may list: its stiffness factor alpha (always) and its mass factor gamma.
UPDATES = ("stiffness", "mass")


def _segment_parameters(spec: _Spec, tables: list[dict], names: list[str]) -> tuple[np.ndarray, np.ndarray | None]:
    """The segments whose mass factor is updated (``update = ["stiffness", "mass"]``), and the parameter
    bounds, shape (n_parameters, 2) in the model's parameter order (alphas, then the gammas), +-inf where
    none is given, or None when no segment gives any."""
    mass, alpha_bounds, gamma_bounds = [], [], []
    for i, seg in enumerate(tables):
        where = f"segments[{i}]"
        update = seg.get("update", ["stiffness"])
        if not (isinstance(update, list) and all(isinstance(u, str) for u in update)) \
                or set(update) - set(UPDATES) or len(set(update)) != len(update):
            raise spec.error(f"{where}.update", f"must be a list of distinct {' and '.join(UPDATES)}, got {update!r}")
        if "stiffness" not in update:
            raise spec.error(f"{where}.update", f"segment {names[i]!r}: a segment's stiffness factor alpha is "
                                                "always updated; list \"stiffness\" (a cell set whose stiffness is "
                                                "fixed belongs to no segment)")
        alpha_bounds.append(_bounds(spec, seg["bounds"], f"{where}.bounds", names[i], "alpha") if "bounds" in seg
                            else (-np.inf, np.inf))
        if "mass" in update:
            mass.append(i)
            gamma_bounds.append(_bounds(spec, seg["mass_bounds"], f"{where}.mass_bounds", names[i], "gamma")
                                if "mass_bounds" in seg else (-np.inf, np.inf))
        elif "mass_bounds" in seg:
            raise spec.error(f"{where}.mass_bounds", f"segment {names[i]!r}: its mass factor is not updated; "
                                                     'add update = ["stiffness", "mass"] or remove mass_bounds')
    bounds = np.array(alpha_bounds + gamma_bounds, dtype=float)
    return np.array(mass, dtype=int), bounds if np.isfinite(bounds).any() else None


def _fixed_dofs(spec: _Spec, tab: dict, where: str, nodes: np.ndarray, dof) -> np.ndarray:
    fix = _get(spec, tab, "fix", where, (list,), ["x", "y", "z"])
    comps = []
    for d in fix:
        if not isinstance(d, str) or d.lower() not in ("x", "y", "z"):
            raise spec.error(f"{where}.fix", f"directions are x, y, z; got {d!r}")
        comps.append(DIRECTIONS[d.lower()])
    return np.array([dof(int(n), c) for n in nodes for c in comps], dtype=np.int64)
