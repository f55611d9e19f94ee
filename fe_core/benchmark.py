"""The three-plate benchmark of ``shared/benchmark/SPEC.md``.

Three 10 mm steel plates joined end to end (230 x 140, 166 x 60 and
230 x 140 mm), clamped at both ends, meshed with 16 hex8 elements per plate
along x, 10 mm across and one through the thickness: 544 elements, 1230
nodes, 3510 free DOFs. Each plate is split at mid-length into two segments
(six stiffness parameters). Six sensors measure u_z on the top face at
y = +20 mm, a quarter of the way into each segment; all six carry a unit
in-phase force at the same time.

Example
-------
>>> from fe_core.benchmark import three_plate, ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ
>>> model = three_plate()
>>> Z = model.frf(ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ)   # (12, 6) complex, m/N
>>> model.natural_frequencies(ALPHA_ACTUAL, 2)                 # Hz
array([112.2249..., 291.4273...])
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .material import Material
from .mesh import Block, mesh_blocks
from .model import ParametricModel, build_model

__all__ = [
    "three_plate",
    "STEEL",
    "DAMPING",
    "ALPHA_NOMINAL",
    "ALPHA_ACTUAL",
    "MEASUREMENT_FREQUENCIES_HZ",
    "PLATES",
    "THICKNESS",
    "sensor_positions",
]

STEEL = Material(E=2.06e11, nu=0.3, rho=7850.0)
#: Rayleigh damping (a [1/s], b [s]).
DAMPING = (1e-2, 1e-4)
THICKNESS = 0.010
#: (x0, x1, half-width) of each plate, m.
PLATES = ((0.0, 0.230, 0.070), (0.230, 0.396, 0.030), (0.396, 0.626, 0.070))
ELEMENTS_ALONG_X = 16
ELEMENT_SIZE_Y = 0.010
ALPHA_NOMINAL = np.zeros(6)
ALPHA_ACTUAL = np.array([-0.6, -0.1, -0.3, -0.2, -0.2, -0.4])
MEASUREMENT_FREQUENCIES_HZ = np.array(
    [106.0, 108.0, 110.0, 112.0, 114.0, 116.0, 285.0, 287.0, 289.0, 291.0, 293.0, 295.0]
)
SENSOR_Y = 0.020


def segment_bounds() -> list[tuple[float, float]]:
    """x ranges of the six segments (each plate split at mid-length), m."""
    bounds = []
    for x0, x1, _ in PLATES:
        mid = 0.5 * (x0 + x1)
        bounds += [(x0, mid), (mid, x1)]
    return bounds


def sensor_positions() -> np.ndarray:
    """Sensor coordinates, shape (6, 3), m: a quarter into each segment, y = +20 mm, top face."""
    return np.array([[x0 + 0.25 * (x1 - x0), SENSOR_Y, THICKNESS] for x0, x1 in segment_bounds()])


@lru_cache(maxsize=4)
def three_plate(formulation: str = "incompatible", refine: tuple[int, int, int] = (1, 1, 1)) -> ParametricModel:
    """The benchmark model (cached per formulation and refinement; treat it as read-only).

    Parameters
    ----------
    formulation : {"incompatible", "plain"}
        hex8 stiffness formulation. The benchmark uses the incompatible-modes
        element; the plain one locks (150.7 / 389.3 Hz instead of 112.2 / 291.4).
    refine : (int, int, int)
        Elements per benchmark element along x, y and through the thickness:
        (1, 1, 1) is the SPEC's mesh; a finer mesh of the same plates (same
        segments, clamps and sensor points, which stay on nodes) is an
        independent reference for it (``benchmarks/closure.py --discretisation``).

    Returns
    -------
    ParametricModel
        Node sets ``clamped``, ``top``, ``sensors``; cell sets ``plate1..3``
        and ``segment1..6``.
    """
    fx, fy, fz = (int(f) for f in refine)
    if min(fx, fy, fz) < 1:
        raise ValueError(f"refine factors must be positive integers, got {refine!r}")
    blocks = []
    for k, (x0, x1, half) in enumerate(PLATES, start=1):
        n_y = int(round(2 * half / ELEMENT_SIZE_Y)) * fy
        blocks.append(
            Block(
                x=np.linspace(x0, x1, ELEMENTS_ALONG_X * fx + 1),
                y=np.linspace(-half, half, n_y + 1),
                z=np.linspace(0.0, THICKNESS, fz + 1),
                name=f"plate{k}",
            )
        )
    mesh = mesh_blocks(blocks)
    cx = mesh.centroids[:, 0]
    segments = {}
    for s, (x0, x1) in enumerate(segment_bounds(), start=1):
        cells = np.flatnonzero((cx > x0) & (cx < x1))
        mesh.add_cell_set(f"segment{s}", cells)
        segments[f"segment{s}"] = cells
    length = PLATES[-1][1]
    clamped = np.concatenate([mesh.nodes_where(x=0.0), mesh.nodes_where(x=length)])
    mesh.add_node_set("clamped", clamped)
    mesh.add_node_set("top", mesh.nodes_where(z=THICKNESS))
    sensors = np.array([mesh.nearest_node(p) for p in sensor_positions()])
    mesh.add_node_set("sensors", sensors)
    return build_model(
        mesh,
        STEEL,
        segments,
        fixed_nodes=clamped,
        sensor_nodes=sensors,
        damping=DAMPING,
        formulation=formulation,
    )
