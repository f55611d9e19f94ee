"""Prefect tasks of the model-error check (``python -m flows.model_error``): one core call each."""

from __future__ import annotations

from prefect import task
from prefect.cache_policies import NO_CACHE

from fe_core.io.model_toml import read_model_toml
from fe_core.io.refined import write_refined
from fe_core.model_error import OwnError, own_error


@task(name="refine-mesh", cache_policy=NO_CACHE)
def refine_task(model_file: str, out_dir: str) -> str:
    """The model file on its once-refined mesh (:func:`fe_core.io.refined.write_refined`), kept when written
    before from the same model file."""
    return str(write_refined(model_file, out_dir))


@task(name="own-error", cache_policy=NO_CACHE)
def own_error_task(model, fine_file: str, freqs, amplitude, alpha, noise, significance: float,
                   alpha_bounds: tuple[float, float], log=None) -> OwnError:
    """The finer model read and assembled, then :func:`fe_core.model_error.own_error`."""
    fine = read_model_toml(fine_file)
    return own_error(model, fine, freqs, amplitude, alpha, noise=noise, significance=significance,
                     alpha_bounds=alpha_bounds, log=log)
