"""Finite element core: segment-parametrised models, their FRFs, derivatives and modes.

Plain numpy/scipy. Its rooms:

* ``elements/`` (hex8 with incompatible modes, tet4, tet10), ``mesh.py``, ``tet_mesh.py``, ``surface.py``,
  ``material.py``, ``assembly.py``: discretisation;
* ``model.py``: :class:`ParametricModel`, ``K = sum_i K_i (1 + alpha_i)`` with sensors and excitations, and
  ``model_responses.py``: its FRFs and modes;
* ``io/``: model files (``model.toml`` with a mesh or exported matrices) and the VTU writer;
* ``solvers/``: FRFs, their exact derivatives, Jacobians, modes;
* ``inference/``: residual statistics, parameter intervals, the sampled posterior;
* ``closure/``: effects the model lacks, traced from the residual and fitted;
* ``benchmark.py``: the paper's three-plate structure. The public entry for the paper's benchmark is
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
