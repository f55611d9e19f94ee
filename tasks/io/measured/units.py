"""Units of measured FRFs: the labels test systems write, their SI factors, and UFF58's unit records.

An FRF is a response over a force. Each reader finds the unit of its values
(UFF58: records 9 and 10 of each dataset 58 and the units dataset 164 before
it; CSV/Parquet: ``# unit = g/N`` per file or a ``unit`` column per row) and
multiplies them by the factor to SI found here, so the internal form is always
m/N, (m/s)/N or (m/s^2)/N. A label that is not in the tables below, or that
names a quantity other than the one the data type declares (``g`` on a
displacement), is refused: a unit is never assumed.

=============  ======================================================  ===================
quantity       labels (case of the letters kept where it matters)      SI factor
=============  ======================================================  ===================
acceleration   ``m/s^2`` (``m/s2``, ``m/s**2``, ``m s^-2``), ``mm/s^2``,   1, 1e-3, 0.0254,
               ``in/s^2``, ``g`` (standard gravity, also ``gn``, ``G``)  9.80665
velocity       ``m/s``, ``mm/s``, ``in/s``                              1, 1e-3, 0.0254
displacement   ``m``, ``mm``, ``um`` (``µm``), ``in``                    1, 1e-3, 1e-6, 0.0254
force          ``N``, ``kN``, ``mN``, ``lbf``                           1, 1e3, 1e-3, 4.4482216152605
=============  ======================================================  ===================

UFF58 (records 8-10: specific data type, length/force/temperature exponents,
axis label, axis units label): the units label of record 9 (the response, or
the whole FRF as ``g/N``) and of record 10 (the force) take precedence over
the unit system of dataset 164 (the standard's note: supplied labels take
precedence); an empty or ``NONE`` label means the unit of the data type in
the system of the last dataset 164 before the dataset (its length and force
factors: file value / factor = SI), and SI when the file has no dataset 164
(noted). The exponents are checked against the data type when they are not 0.
The abscissa (record 8) must be a frequency: ``Hz`` (``1/s``, ``cps``), or
``rad/s`` (converted), or no label.
"""

from __future__ import annotations

import math
import re

__all__ = ["QUANTITY_OF_KIND", "KIND_OF_QUANTITY", "numerator_unit", "force_unit", "frf_unit", "frequency_unit",
           "UnitError", "uff_units", "SI_FRF_UNIT"]

G = 9.80665          # m/s^2, standard gravity (CGPM 1901)
INCH = 0.0254        # m
LBF = 4.4482216152605  # N: 1 lb x standard gravity

#: The FRF kind of a response quantity and back.
KIND_OF_QUANTITY = {"displacement": "receptance", "velocity": "mobility", "acceleration": "accelerance"}
QUANTITY_OF_KIND = {kind: q for q, kind in KIND_OF_QUANTITY.items()}
#: The SI unit of each kind, as written in notes and the manifest.
SI_FRF_UNIT = {"receptance": "m/N", "mobility": "(m/s)/N", "accelerance": "(m/s^2)/N"}
#: UFF58 record 9/10 specific data types.
UFF_QUANTITY = {8: "displacement", 11: "velocity", 12: "acceleration"}
UFF_FORCE_TYPES = (9, 13)

_LENGTH = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "μm": 1e-6, "in": INCH}
_RESPONSE = {}
for _name, _factor in _LENGTH.items():
    _RESPONSE[_name] = ("displacement", _factor)
    _RESPONSE[f"{_name}/s"] = ("velocity", _factor)
    for _square in ("/s^2", "/s2", "/s**2", "s^-2", "/s/s", "/sec^2", "/sec2"):
        _RESPONSE[f"{_name}{_square}"] = ("acceleration", _factor)
for _name in ("g", "gn", "g's"):
    _RESPONSE[_name] = ("acceleration", G)
_FORCE = {"n": 1.0, "kn": 1e3, "mn": 1e-3, "lbf": LBF}
_FREQUENCY = {"hz": 1.0, "1/s": 1.0, "cps": 1.0, "rad/s": 1.0 / (2.0 * math.pi)}
_NONE = {"", "none"}


class UnitError(ValueError):
    """A units label that is unknown or contradicts the data type (the reader adds the file and the place)."""


def _norm(label) -> str:
    text = str(label).strip()
    text = re.sub(r"\s+", "", text)
    return text.replace("²", "^2").replace("(", "").replace(")", "")


def numerator_unit(label: str) -> tuple[str, float]:
    """``(quantity, SI factor)`` of a response unit label (``"g"`` -> ``("acceleration", 9.80665)``).

    Lengths keep their case except ``M``/``MM`` (test systems write upper case): ``mm`` and ``MM`` are
    millimetres; ``mN`` vs ``MN`` matters only for forces, where mega-newtons are not accepted.
    """
    key = _norm(label).lower().replace("ms^-2", "m/s^2")
    if key in _RESPONSE:
        return _RESPONSE[key]
    raise UnitError(f"unknown response unit {label!r} (known: m, mm, in, m/s, mm/s, in/s, m/s^2, mm/s^2, "
                    "in/s^2, g)")


def force_unit(label: str) -> float:
    """SI factor of a force unit label (``"lbf"`` -> 4.448...)."""
    key = _norm(label)
    if key == "MN":
        raise UnitError(f"force unit {label!r} (mega-newton) is not accepted; write mN for milli-newton")
    if key.lower() in _FORCE:
        return _FORCE[key.lower()]
    raise UnitError(f"unknown force unit {label!r} (known: N, kN, mN, lbf)")


def frf_unit(label: str) -> tuple[str, float]:
    """``(kind, SI factor)`` of a whole FRF unit ``response/force`` (``"g/N"``, ``"(m/s^2)/lbf"``, ``"mm/s/N"``).

    The force is what follows the last ``/``; a label without a force is refused.
    """
    text = _norm(label)
    if "/" not in text:
        raise UnitError(f"unit {label!r} is not response/force (e.g. g/N, m/s^2/N, mm/s/N, m/lbf)")
    response, force = text.rsplit("/", 1)
    try:
        force_factor = force_unit(force)
    except UnitError:
        raise UnitError(f"unit {label!r}: unknown force unit {force!r} after the last '/' (known: N, kN, mN, "
                        "lbf)") from None
    try:
        quantity, factor = numerator_unit(response)
    except UnitError:
        raise UnitError(f"unit {label!r}: unknown response unit {response!r} (known: m, mm, in, m/s, mm/s, in/s, "
                        "m/s^2, mm/s^2, in/s^2, g)") from None
    return KIND_OF_QUANTITY[quantity], factor / force_factor


def frequency_unit(label) -> float:
    """Factor from an abscissa units label to Hz (``""``/``NONE``/``Hz`` -> 1, ``rad/s`` -> 1/(2 pi))."""
    key = _norm(label).lower()
    if key in _NONE:
        return 1.0
    if key in _FREQUENCY:
        return _FREQUENCY[key]
    raise UnitError(f"abscissa units label {label!r} is not a frequency (Hz, 1/s, cps or rad/s)")


def _label(dataset, key) -> str:
    value = dataset.get(key, "")
    return "" if value is None else str(value).strip()


def _exponents(dataset, prefix) -> tuple[int, int, int]:
    return tuple(int(dataset.get(f"{prefix}_{name}_unit_exp", 0) or 0) for name in ("len", "force", "temp"))


def uff_units(dataset, system, ordinate_type: int) -> dict:
    """The units of one dataset 58 FRF: kind, SI factor of its values and of its abscissa, and what was read.

    Parameters
    ----------
    dataset : dict
        pyuff's dataset 58.
    system : dict or None
        The last dataset 164 before it (pyuff's dict: ``units_code``, ``units_description``, ``length``,
        ``force``), or None.
    ordinate_type : int
        Record 9's specific data type (8, 11, 12, or 0/1 unknown/general: then the label decides).

    Returns
    -------
    dict
        ``kind``, ``factor`` (file value x factor = SI), ``frequency_factor``, ``unit`` (the unit as the file
        gives it, e.g. ``"g/N"``), ``source`` (where the unit came from).

    Raises
    ------
    UnitError
        Naming the record and the label.
    """
    abscissa = _label(dataset, "abscissa_axis_units_lab")
    if int(dataset.get("abscissa_spec_data_type", 18) or 0) not in (0, 1, 18):
        raise UnitError(f"record 8: abscissa data type {dataset.get('abscissa_spec_data_type')} is not a "
                        "frequency (18)")
    try:
        frequency_factor = frequency_unit(abscissa)
    except UnitError as exc:
        raise UnitError(f"record 8: {exc}") from None
    numerator, denominator = _label(dataset, "ordinate_axis_units_lab"), _label(dataset, "orddenom_axis_units_lab")
    declared = UFF_QUANTITY.get(ordinate_type)
    exp = _exponents(dataset, "ordinate")
    if declared is not None and any(exp) and exp != (1, 0, 0):
        raise UnitError(f"record 9: unit exponents (length, force, temperature) {exp} contradict the data type "
                        f"{ordinate_type} ({declared}: (1, 0, 0) or all 0)")
    exp = _exponents(dataset, "orddenom")
    if any(exp) and exp != (0, 1, 0):
        raise UnitError(f"record 10: unit exponents (length, force, temperature) {exp} are not a force (0, 1, 0)")
    force_factor, force_label, whole = None, None, False
    if numerator.lower() not in _NONE:
        text = _norm(numerator)
        whole = "/" in text and text.rsplit("/", 1)[1].lower() in set(_FORCE)
        try:
            if whole:
                kind, factor = frf_unit(numerator)
                quantity = QUANTITY_OF_KIND[kind]
                force_label = text.rsplit("/", 1)[1]
            else:
                quantity, factor = numerator_unit(numerator)
        except UnitError as exc:
            raise UnitError(f"record 9: units label: {exc}") from None
        if declared is not None and quantity != declared:
            raise UnitError(f"record 9: units label {numerator!r} is a {quantity}, but the data type "
                            f"{ordinate_type} says {declared}")
        source = "units labels of records 9 and 10"
    elif declared is not None:
        quantity, factor = declared, _system_factor(system, "length")
        numerator = _system_name(system, quantity)
        source = "dataset 164" if system is not None else "no label, no dataset 164: SI assumed"
    else:
        raise UnitError(f"ordinate specific data type {ordinate_type} (record 9) and no units label: the response "
                        "is not an FRF's (8 displacement, 11 velocity, 12 acceleration, or a label such as g)")
    if whole:
        if denominator.lower() not in _NONE and _norm(denominator).lower() != force_label.lower():
            raise UnitError(f"record 10: units label {denominator!r} contradicts the force {force_label!r} of "
                            f"record 9's label {numerator!r}")
        unit = numerator
    else:
        if denominator.lower() not in _NONE:
            try:
                force_factor = force_unit(denominator)
            except UnitError as exc:
                raise UnitError(f"record 10: units label: {exc}") from None
            force_label = denominator
        else:
            force_factor = _system_factor(system, "force")
            force_label = "N" if system is None else f"force unit of dataset 164 ({_system_text(system)})"
        factor = factor / force_factor
        unit = f"{numerator}/{force_label}"
    return {"kind": KIND_OF_QUANTITY[quantity], "factor": factor, "frequency_factor": frequency_factor,
            "unit": unit, "source": source}


def _system_factor(system, what) -> float:
    """SI factor of the system's length or force unit: dataset 164 gives file units per SI unit."""
    if system is None:
        return 1.0
    value = float(system.get(what, 1.0))
    if not value > 0:
        raise UnitError(f"dataset 164: {what} factor {value!r} is not > 0")
    return 1.0 / value


def _system_text(system) -> str:
    return f"units code {system.get('units_code')} {str(system.get('units_description', '')).strip()}".strip()


def _system_name(system, quantity) -> str:
    base = "m" if system is None or float(system.get("length", 1.0)) == 1.0 else \
        f"length unit of dataset 164 ({_system_text(system)})"
    return {"displacement": base, "velocity": f"{base}/s", "acceleration": f"{base}/s^2"}[quantity]
