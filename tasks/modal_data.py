"""Measured modes matched to a model: each test DOF ``NODE:DIR`` to the model sensor whose ``test_node`` is
NODE and whose test direction is along DIR (as UFF58 channels are matched, :mod:`tasks.update_data`), a
response named as a model sensor to that sensor, and
the checks that need the model (test nodes, the model's band, identifiability)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from tasks.io.measured.frf import MeasuredDataError, parse_dof
from tasks.io.measured.modes import MeasuredModes

__all__ = ["ModalData", "match_modes", "check_band", "band_limit"]


@dataclass
class ModalData:
    modes: MeasuredModes
    outputs: sp.csc_matrix  # (n_free, n_dofs): the model's reading of each test DOF, signed
    sensors: list  # model sensor name of each test DOF


def match_modes(modes: MeasuredModes, model) -> ModalData:
    """The model's output vector of every test DOF (or sensor name); a test node, direction or name the model lacks
    is refused."""
    tests = model.sensor_test_dofs
    known = sorted({t[0] for t in tests if t is not None})
    place = modes.places[0] if modes.places and modes.places[0] else "data"
    columns, signs, names = [], [], []
    for label in modes.dofs:
        if parse_dof(label) is None:  # a channel named as a model sensor (a table's response column)
            if label not in model.sensor_names:
                raise MeasuredDataError(
                    f"{modes.source}: {place}: response {label!r} is neither a test DOF NODE:DIR nor a sensor of "
                    f"the model {model.source or ''} (its sensors: {', '.join(model.sensor_names)})")
            k = list(model.sensor_names).index(label)
            columns.append(k)
            signs.append(1.0)
            names.append(label)
            continue
        node, direction = parse_dof(label)
        here = [(k, t) for k, t in enumerate(tests) if t is not None and t[0] == node]
        if not here:
            raise MeasuredDataError(
                f"{modes.source}: {place}: test node {node} ({label}) is not in the model "
                f"{model.source or ''}: no sensor has test_node = {node} (the model's test nodes: "
                f"{known or 'none; add test_node keys to its [[sensors]]'})")
        match = [(k, t) for k, t in here if abs(t[1]) == abs(direction)]
        if not match:
            raise MeasuredDataError(f"{modes.source}: {place}: test DOF {label}: the model has no sensor along "
                                    f"this direction at test node {node}")
        k, t = match[0]
        columns.append(k)
        signs.append(float(np.sign(direction) * np.sign(t[1])))
        names.append(model.sensor_names[k])
    L = sp.csc_matrix(model.outputs)[:, columns] @ sp.diags(signs)
    return ModalData(modes, sp.csc_matrix(L), names)


def band_limit(model, n_model: int, upper: float, gamma_lower: float | None = None) -> float:
    """Highest frequency a model mode among the lowest ``n_model`` can reach in the box, Hz.

    By the Rayleigh quotient, ``f_r(alpha) <= sqrt((1 + max alpha) / (1 + min gamma)) f_r(0)``: a measured
    frequency above this for the highest computed mode has no partner among them.
    """
    theta0 = np.zeros(model.n_parameters)
    alpha, gamma = model.factors(theta0)
    f = model.natural_frequencies(alpha, n_model, gamma)
    factor = (1.0 + upper) / (1.0 + (gamma_lower if gamma_lower is not None and model.mass_parameters.size else 0))
    return float(f[-1] * np.sqrt(factor))


def check_band(modes: MeasuredModes, limit_hz: float, n_model: int) -> None:
    """Refuse a measured frequency above the model's band (:func:`band_limit`)."""
    for k, f in enumerate(modes.frequencies_hz):
        if f > limit_hz:
            raise MeasuredDataError(
                f"{modes.source}: {modes.places[k] or modes.names[k]} ({modes.names[k]}): frequency {f:g} Hz is "
                f"above the model's band: its lowest {n_model} modes reach at most {limit_hz:.1f} Hz within the "
                "search box, so no model mode can pair with it")
