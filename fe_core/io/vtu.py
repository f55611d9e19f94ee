"""The updated model as a VTK unstructured grid (``model.vtu``) for ParaView, through meshio.

Cell data:

- ``segment``: the cell's segment index (0-based, the model file's order), -1 for the
  fixed remainder;
- ``alpha``: the updated stiffness factor of the cell's segment, NaN for the remainder
  (it is not updated; its stiffness is the nominal one);
- ``gamma``: the mass factor likewise, when the update has mass factors.

Point data: the first modes of the updated model ``K(alpha) phi = w^2 M(gamma) phi`` as
displacement vectors (x, y, z per node, mass-normalised: ``phi^T M phi = 1``, so
1/sqrt(kg); zero on supported DOFs), one array per mode named
``mode <k> at <frequency> Hz`` (10 significant digits; VTU has no field data, so the
frequency travels in the name). In ParaView: colour by ``segment`` or ``alpha``; *Warp
By Vector* with a mode and a scale factor of about 1e-3 of the model's size times
sqrt(mass) to see it move.
"""

from __future__ import annotations

import logging
import re

import numpy as np

from ..model import ParametricModel
from ..surface import cell_type_of

__all__ = ["model_vtu", "mode_field_name", "parse_mode_field", "DEFAULT_MODES"]

log = logging.getLogger(__name__)

#: Modes written by default.
DEFAULT_MODES = 6
_MODE_NAME = re.compile(r"^mode (\d+) at ([-+0-9.eE]+) Hz$")


def mode_field_name(k: int, freq_hz: float) -> str:
    """The point-data name of mode ``k`` (1-based) at ``freq_hz``: ``"mode 1 at 308.5614363 Hz"``."""
    return f"mode {k} at {freq_hz:.10g} Hz"


def parse_mode_field(name: str) -> tuple[int, float] | None:
    """(k, frequency in Hz) of a mode field name, or None for another field."""
    m = _MODE_NAME.match(name)
    return (int(m.group(1)), float(m.group(2))) if m else None


def model_vtu(model: ParametricModel, alpha, gamma=None, n_modes: int = DEFAULT_MODES):
    """The mesh with segments, factors and modes of the model at ``alpha`` (and ``gamma``).

    Parameters
    ----------
    model : ParametricModel
        With a mesh (nodes in m).
    alpha : array_like, shape (n_segments,)
        Updated stiffness factors.
    gamma : array_like, shape (n_segments,), optional
        Updated mass factors; without them no ``gamma`` cell data is written and
        the modes use the nominal mass.
    n_modes : int
        Modes written (fewer when the model has fewer free DOFs).

    Returns
    -------
    meshio.Mesh
        One cell block of the model's type (``hexahedron``, ``tetra``, ``tetra10``).

    Raises
    ------
    ValueError
        For a model without a mesh (matrices), or parameters outside (-1, inf).
    """
    import meshio

    if model.mesh is None:
        raise ValueError("the model is given as matrices (no mesh): there are no cells to write")
    if model.cell_segment is None:
        raise ValueError("the model does not record which segment each cell belongs to")
    mesh = model.mesh
    seg = np.asarray(model.cell_segment, dtype=np.int64)
    cell_data = {"segment": [seg], "alpha": [_per_cell(seg, alpha, model.n_segments, "alpha")]}
    if gamma is not None:
        cell_data["gamma"] = [_per_cell(seg, gamma, model.n_segments, "gamma")]
    n = min(int(n_modes), model.n_dofs - 1)
    point_data = {}
    if n >= 1:
        freqs, shapes, _ = model.modes(alpha, n, gamma)  # (n, n_nodes, 3), mass-normalised
        for k, (f, shape) in enumerate(zip(freqs, shapes), start=1):
            big = np.unravel_index(np.argmax(np.abs(shape)), shape.shape)
            sign = 1.0 if shape[big] >= 0 else -1.0  # deterministic sign: largest entry positive
            point_data[mode_field_name(k, float(f))] = sign * shape
        log.info("model.vtu: modes of the updated model at %s Hz", ", ".join(f"{f:.4g}" for f in freqs))
    return meshio.Mesh(points=mesh.nodes, cells=[(cell_type_of(mesh.cells), mesh.cells)],
                       point_data=point_data, cell_data=cell_data)


def _per_cell(seg: np.ndarray, values, n_segments: int, name: str) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if values.shape != (n_segments,):
        raise ValueError(f"{name} must have {n_segments} entries (one per segment), got shape {values.shape}")
    return np.where(seg >= 0, values[np.maximum(seg, 0)], np.nan)
