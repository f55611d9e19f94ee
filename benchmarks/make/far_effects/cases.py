"""The far-effect cases (issue 40, item 2): which structure, factors, effect and noise seed; fixed before tuning.

``DEV`` is what the closure was developed on; ``CHECK`` was written at the same time and looked at only at the end
(docs/results/closure-far-effects.md reports both separately). Every case: lines 1-750 Hz at 1 Hz (``LINES``), a relative
response noise of 1 %, a floor of 1e-3 of each channel's peak and 0.2 % force noise (:mod:`.noise`), the factors
far from nominal.

Effects: ``point_mass`` (``share``: of the structure's mass) at the vertex nearest ``point``;
``grounded_spring_<x|y|z>`` (``share``: of the model's static stiffness at that node along the axis);
``layer`` (outside the library: the density of the cells whose centres lie within ``radius`` of ``point`` raised
so that they carry ``share`` of the structure's mass more; scikit-fem only).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .plate import PlateSpec, default_sensors
from .shell import BoxSpec

LINES = np.arange(1.0, 751.0)

PLATE_A = PlateSpec(name="plate_a", size=0.0225)
PLATE_A = PlateSpec(**{**PLATE_A.__dict__, "sensors": default_sensors(PLATE_A)})
#: the check set's plate: another hole and rib, another excitation point
PLATE_B = PlateSpec(name="plate_b", length=0.55, width=0.42, thickness=0.011, hole=(0.2, 0.27, 0.045), rib_y=0.33,
                    size=0.0225, excitation=("tip low z", (0.55, 0.0, 0.011), (0.0, 0.3, 1.0)))
PLATE_B = PlateSpec(**{**PLATE_B.__dict__, "sensors": default_sensors(PLATE_B)})
BOX = BoxSpec()


@dataclass(frozen=True)
class Case:
    name: str
    structure: str                      # "plate_a", "plate_b", "box_arm"
    alpha: tuple
    effect: dict | None
    seed: int
    expected: str                       # "explained", "noise", "not explained"
    note: str = ""
    extra: dict = field(default_factory=dict)


DEV = (
    Case("plate-mass-4", "plate_a", (-0.25, 0.10, -0.15, 0.05, -0.20),
         {"kind": "point_mass", "point": (0.47, 0.33, 0.01), "share": 0.04}, 1, "explained"),
    Case("plate-mount", "plate_a", (0.08, -0.20, 0.10, -0.25, 0.0),
         {"kind": "grounded_spring_z", "point": (0.55, 0.12, 0.01), "share": 0.3}, 2, "explained"),
    Case("plate-clean", "plate_a", (-0.20, 0.05, 0.10, -0.10, 0.08), None, 3, "noise"),
    Case("plate-layer", "plate_a", (-0.10, -0.15, 0.05, 0.10, -0.05),
         {"kind": "layer", "point": (0.2, 0.25, 0.01), "radius": 0.07, "share": 0.05}, 4, "not explained"),
    Case("box-mass-3", "box_arm", (-0.15, 0.10, 0.05, -0.20, 0.10),
         {"kind": "point_mass", "point": (0.5, -0.03, 0.04), "share": 0.03}, 5, "explained"),
    Case("box-clean", "box_arm", (0.10, -0.10, -0.20, 0.05, -0.15), None, 6, "noise"),
)

CHECK = (
    Case("check-plate-mass-6", "plate_b", (0.10, -0.20, -0.10, 0.05, -0.25),
         {"kind": "point_mass", "point": (0.12, 0.08, 0.011), "share": 0.06}, 11, "explained"),
    Case("check-plate-mount", "plate_b", (-0.15, -0.05, 0.10, -0.20, 0.05),
         {"kind": "grounded_spring_z", "point": (0.42, 0.36, 0.011), "share": 0.2}, 12, "explained"),
    Case("check-box-mass-5", "box_arm", (0.05, -0.25, 0.10, 0.0, -0.10),
         {"kind": "point_mass", "point": (0.7, 0.06, 0.0), "share": 0.05}, 13, "explained"),
)

CASES = {c.name: c for c in DEV + CHECK}
STRUCTURES = {"plate_a": PLATE_A, "plate_b": PLATE_B, "box_arm": BOX}
