"""Sensor calibration: :class:`SensorGain`, a relative amplitude error of one sensor (the comparison
changes, not the structure)."""

from __future__ import annotations

import numpy as np

from .base import Effect, Terms, _sensor_nodes

__all__ = ["SensorGain"]


class SensorGain(Effect):
    """A calibration error of one sensor: the measured amplitude is ``|Z_s| (1 + g)``.

    Changes the comparison, not the structure (no matrix changes): the
    predicted amplitude at that sensor is scaled. Plausible within +-50 %.
    """

    kind = "sensor_gain"
    parameters = ("g",)
    units = ("-",)
    lower = (-0.5,)
    upper = (0.5,)
    scale = (0.05,)

    def locations(self) -> list[str]:
        return [f"sensor {s + 1}" for s in range(self.model.n_sensors)]

    def terms(self, alpha, location, values) -> Terms:
        gain = np.zeros(self.model.n_sensors)
        gain[self.locations().index(location)] = float(values[0])
        return Terms(gain=gain)

    def describe(self, location) -> dict:
        s = self.locations().index(location)
        return {"sensor": s + 1, "node": int(_sensor_nodes(self.model)[s])}
