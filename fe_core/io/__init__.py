"""Reading models from files: ``read_model(path)`` behind one entry, one module per format.

- :mod:`fe_core.io.model_toml`: the ``model.toml`` schema (a mesh or matrices,
  segments, supports, damping, sensors, excitations);
- :mod:`fe_core.io.mesh_file`: meshes with named sets through meshio;
- :mod:`fe_core.io.matrices`: exported matrices (``.mtx``, ``.npz``) and the DOF table.

Example::

    from fe_core.io import read_model
    model = read_model("data/benchmark/model.toml")   # same FRF as fe_core.three_plate()
"""

from __future__ import annotations

from pathlib import Path

from .model_toml import ModelFileError, model_files, read_model_toml

__all__ = ["read_model", "model_files", "ModelFileError"]


def read_model(path: str | Path):
    """The :class:`fe_core.model.ParametricModel` of a model file (``.toml``).

    Raises
    ------
    ModelFileError
        Naming the file and the key.
    """
    path = Path(path)
    if path.suffix != ".toml":
        raise ModelFileError(f"{path}: unknown model file format {path.suffix!r}; a model file is a .toml")
    return read_model_toml(path)
