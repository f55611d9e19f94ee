"""``<run folder>/model.vtu``: the updated model for ParaView, written at the end of a run.

One core call (:func:`fe_core.io.vtu.model_vtu`: segments, updated factors per cell,
the first modes of the updated model as point data) and one atomic write
(:func:`tasks.runstore.atomic_write_file`: a temporary ``.model.vtu.*.tmp`` beside it,
renamed into place; a killed writer's temporary file is removed when the run starts
again). A model without a mesh (matrices) writes nothing and says why in the log.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
from prefect import task
from prefect.cache_policies import NO_CACHE

from fe_core.solvers import pardiso
from tasks.common import logger as run_logger
from tasks.runstore import atomic_write_file

__all__ = ["VTU_NAME", "factors_from_parameters", "write_model_vtu", "model_vtu_task"]

VTU_NAME = "model.vtu"


def factors_from_parameters(parameters: dict, model) -> tuple[np.ndarray, np.ndarray | None]:
    """``alpha`` (and ``gamma`` when the model updates mass factors) from a summary's ``parameters``
    (``{"alpha_1": ..., "gamma_2": ...}``), shape (n_segments,) each (:meth:`fe_core.ParametricModel.factors`:
    zero gamma for segments whose mass is not updated).

    Raises ``ValueError`` naming a missing parameter, or one the model does not have.
    """
    names = model.parameter_names
    missing = [n for n in names if n not in parameters]
    if missing:
        raise ValueError(f"the parameters lack {', '.join(missing)} (the model's parameters: {', '.join(names)})")
    extra = [n for n in parameters if n not in names]
    if extra:
        raise ValueError(f"{', '.join(extra)}: not parameters of the model (its parameters: {', '.join(names)})")
    return model.factors([float(parameters[n]) for n in names])


def write_model_vtu(root: str | Path, model, parameters: dict, n_modes: int | None = None,
                    threads: int = 1) -> Path | None:
    """Write ``<root>/model.vtu`` of the run's model at its updated parameters.

    Parameters
    ----------
    root : path
        The run folder.
    model : fe_core.model.ParametricModel
        The run's model.
    parameters : dict
        The summary's ``parameters`` (``alpha_i``, and ``gamma_i`` if updated).
    n_modes : int, optional
        Modes written (default :data:`fe_core.io.vtu.DEFAULT_MODES`).
    threads : int
        PARDISO threads of the modes' factorisation: a large model's run passes its cores, as its intervals
        and FE runs in this process did, so that a factor of K they left at these parameters is found in that
        thread count's pool and reused (:mod:`fe_core.solvers.pardiso`); at 500k DOFs the modes took 63 s on
        one thread with a factorisation of their own.

    Returns
    -------
    Path or None
        None when the model has no mesh or its modes could not be computed (logged).
    """
    import meshio
    import scipy.sparse.linalg as spla

    from fe_core.io.vtu import DEFAULT_MODES

    logger = run_logger()
    view = getattr(model, "deck_view", None)   # a solver deck's mesh (fe_core.io.calculix.vtu)
    if model.mesh is None and view is None:
        logger.info("%s not written: the model is given as matrices (no mesh to draw)", VTU_NAME)
        return None
    alpha, gamma = factors_from_parameters(parameters, model)
    t0 = time.perf_counter()
    try:
        with pardiso.threads(threads):
            grid = _grid(model, view, alpha, gamma, DEFAULT_MODES if n_modes is None else n_modes)
    except (ArithmeticError, RuntimeError, np.linalg.LinAlgError, spla.ArpackError) as exc:
        logger.warning("%s not written: the modes of the updated model failed (%s: %s)", VTU_NAME,
                       type(exc).__name__, exc)
        return None
    path = Path(root) / VTU_NAME
    atomic_write_file(path, lambda tmp: meshio.write(tmp, grid, file_format="vtu"))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)  # readable like any other file (mkstemp's file is private)
    logger.info("%s written (%d cells, %d modes) in %.1f s", path, len(grid.cells[0].data), len(grid.point_data),
                time.perf_counter() - t0)
    return path


def _grid(model, view, alpha, gamma, n_modes: int):
    if view is not None:  # a solver deck's mesh
        from fe_core.io.calculix.vtu import deck_vtu

        return deck_vtu(model, view, alpha, gamma, n_modes)
    from fe_core.io.vtu import model_vtu

    return model_vtu(model, alpha, gamma, n_modes)


model_vtu_task = task(write_model_vtu, name="model-vtu", cache_policy=NO_CACHE)
