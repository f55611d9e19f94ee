"""Finite element core: hex8 solids, segment-parametrised models, FRFs and modes.

Plain numpy/scipy. The public entry for the paper's benchmark is
:func:`fe_core.benchmark.three_plate`::

    from fe_core import three_plate, ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ
    model = three_plate()
    Z = model.frf(ALPHA_ACTUAL, MEASUREMENT_FREQUENCIES_HZ)  # (12, 6) complex, m/N
    f = model.natural_frequencies(ALPHA_ACTUAL, n_modes=6)   # Hz
"""

from .benchmark import ALPHA_ACTUAL, ALPHA_NOMINAL, MEASUREMENT_FREQUENCIES_HZ, three_plate
from .material import Material, isotropic_elasticity
from .mesh import Block, Mesh, mesh_blocks
from .model import ParametricModel, build_model, check_parameters

__all__ = [
    "ALPHA_ACTUAL",
    "ALPHA_NOMINAL",
    "MEASUREMENT_FREQUENCIES_HZ",
    "three_plate",
    "Material",
    "isotropic_elasticity",
    "Block",
    "Mesh",
    "mesh_blocks",
    "ParametricModel",
    "build_model",
    "check_parameters",
]
