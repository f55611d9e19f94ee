"""The model's own error, sized from the model: what it cannot fit of its own refined mesh, and what is left beyond it.

A model of a given mesh is stiffer than the structure it stands for; an update absorbs much of that into the
stiffness factors (biased by it) and leaves the rest as a smooth misfit that no noise test calls noise. With a finer
model of the same structure (``fine``: the once-refined mesh, :func:`fe_core.io.refined.write_refined`),
:func:`own_error` measures both, noise-free, at the point the data put the model:

1. the model fitted to the data (alpha only, from ``alpha``): ``alpha_d`` and the data residual ``r_d``;
2. the fine model's amplitudes at ``alpha_d``, the model fitted to them from ``alpha_d``: it lands at
   ``alpha_d + bias`` (the factors' discretisation bias);
3. the fine model's amplitudes at ``alpha_d - bias`` (where the structure would be, the bias taken out), the model
   fitted to them: it lands near ``alpha_d`` again and leaves the **floor** ``r_f``, the misfit the mesh makes there;
4. what is left beyond the mesh, ``r_d - r_f``, tested against the noise (chi-square and runs,
   :func:`fe_core.inference.residual.analyse_residual`): noise means the data say nothing more than noise and the
   mesh's own error; structure means something the mesh does not explain (an effect, a wrong basin, a model error
   of another kind).

The fine model's residual is one more discretisation level, not the converged structure: the floor and the bias are
those of one halving of the element size, an estimate of the mesh's error that is close to it for elements
converging at their nominal order (on tet10, the frequency error falls ~16 times per halving, so the fine model's own
error is a small part of the coarse one's).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .closure.effects.extended import extended_frf
from .closure.fits import ALPHA_BOUNDS, fit_update
from .inference.residual import ResidualAnalysis, analyse_residual

__all__ = ["OwnError", "own_error", "MeshFloor", "mesh_floor", "floor_of"]


@dataclass
class OwnError:
    """The result of :func:`own_error` (factors and residuals as described there; rms values of ln residuals)."""

    alpha_data: np.ndarray
    bias: np.ndarray
    alpha_corrected: np.ndarray
    alpha_check: np.ndarray  # where the model fitted to the fine model at alpha_corrected landed (~ alpha_data)
    data_residual: np.ndarray
    floor_residual: np.ndarray
    data: ResidualAnalysis
    beyond: ResidualAnalysis
    fine_dofs: int
    seconds: dict = field(default_factory=dict)

    @property
    def beyond_residual(self) -> np.ndarray:
        return self.data_residual - self.floor_residual

    @staticmethod
    def _rms(r) -> float:
        return float(np.sqrt(np.mean(np.asarray(r) ** 2)))

    def to_dict(self) -> dict:
        share = float(np.sum(self.floor_residual ** 2) / max(np.sum(self.data_residual ** 2), 1e-300))
        return {"alpha_data": self.alpha_data.tolist(), "bias": self.bias.tolist(),
                "alpha_corrected": self.alpha_corrected.tolist(), "alpha_check": self.alpha_check.tolist(),
                "rms_data": self._rms(self.data_residual), "rms_floor": self._rms(self.floor_residual),
                "rms_beyond": self._rms(self.beyond_residual), "floor_share_of_data": share,
                "data": self.data.summary(), "beyond": self.beyond.summary(),
                "beyond_structured": bool(self.beyond.structured), "data_structured": bool(self.data.structured),
                "fine_dofs": int(self.fine_dofs), "seconds": {k: round(v, 1) for k, v in self.seconds.items()}}


def own_error(model, fine, freqs_hz, amplitude, alpha, *, noise=None, significance: float = 0.01,
              alpha_bounds: tuple[float, float] = ALPHA_BOUNDS, log=None) -> OwnError:
    """The model's own error against ``fine`` (the same structure on a finer mesh, the same segments and sensors)
    at the data's estimate (module docstring). ``amplitude``: measured amplitudes (p, n) at ``freqs_hz``;
    ``alpha``: where the model's fit to them starts (a run's estimate); ``noise``: as
    :func:`fe_core.inference.residual.analyse_residual` takes it (the measured noise per line and channel)."""
    if list(model.segment_names) != list(fine.segment_names) or model.n_sensors != fine.n_sensors:
        raise ValueError(f"the finer model has segments {fine.segment_names} and {fine.n_sensors} sensors, the "
                         f"model {model.segment_names} and {model.n_sensors}: not the same structure")
    say = log if log is not None else (lambda *a: None)
    freqs = np.asarray(freqs_hz, float)
    u = np.asarray(amplitude, float)
    lo, hi = alpha_bounds
    seconds = {}

    def timed(key, fn, *args, **kwargs):
        t = time.perf_counter()
        out = fn(*args, **kwargs)
        seconds[key] = seconds.get(key, 0.0) + time.perf_counter() - t
        return out

    data_fit = timed("fits", fit_update, model, freqs, u, np.asarray(alpha, float), alpha_bounds=alpha_bounds)
    a_d = np.asarray(data_fit.alpha, float)
    say("model error: the model fitted to the data: alpha %s", np.round(a_d, 4).tolist())
    biased = timed("fine", mesh_floor, model, fine, freqs, a_d, alpha_bounds=alpha_bounds)   # step 2: the bias
    bias = biased.alpha - a_d
    a_c = np.clip(a_d - bias, lo, hi)
    say("model error: the factors' bias from the mesh %s; the structure's factors %s", np.round(bias, 4).tolist(),
        np.round(a_c, 4).tolist())
    u_c = np.abs(timed("fine", extended_frf, fine, a_c, freqs))
    floor = timed("fits", fit_update, model, freqs, u_c, a_d, alpha_bounds=alpha_bounds)
    data = analyse_residual(data_fit.residual, freqs, a_d.size, noise, significance, data_fit.relative(u))
    beyond = analyse_residual(data_fit.residual - floor.residual, freqs, a_d.size, noise, significance)
    say("model error: floor rms %.3f%% (the mesh), data rms %.3f%%, beyond the mesh: %s",
        100 * OwnError._rms(floor.residual), 100 * OwnError._rms(data_fit.residual), beyond.summary())
    return OwnError(alpha_data=a_d, bias=bias, alpha_corrected=a_c, alpha_check=np.asarray(floor.alpha, float),
                    data_residual=np.asarray(data_fit.residual, float),
                    floor_residual=np.asarray(floor.residual, float), data=data, beyond=beyond,
                    fine_dofs=int(fine.n_dofs), seconds=seconds)


@dataclass
class MeshFloor:
    """What the model leaves fitted to its own refined mesh at ``alpha``, noise-free: ``rms`` of ``ln|Z|`` over the
    lines (the mesh's own misfit once the factors have taken what they can), ``fine_dofs``, ``seconds``."""

    rms: float
    alpha: np.ndarray
    fine_dofs: int
    seconds: float

    def to_dict(self) -> dict:
        return {"rms": self.rms, "alpha": np.asarray(self.alpha, float).tolist(), "fine_dofs": int(self.fine_dofs),
                "seconds": round(self.seconds, 1)}


def mesh_floor(model, fine, freqs_hz, alpha, *, alpha_bounds: tuple[float, float] = ALPHA_BOUNDS) -> MeshFloor:
    """The model fitted (alpha only, from ``alpha``) to ``fine``'s amplitudes at ``alpha`` on ``freqs_hz``: the
    misfit the model's mesh makes there (step 2 of :func:`own_error`, without the bias correction: the floor's size
    changes little with a few hundredths of the factors)."""
    t = time.perf_counter()
    freqs = np.asarray(freqs_hz, float)
    a = np.asarray(alpha, float)
    u_f = np.abs(extended_frf(fine, a, freqs))
    fit = fit_update(model, freqs, u_f, a, alpha_bounds=alpha_bounds)
    return MeshFloor(float(np.sqrt(np.mean(np.asarray(fit.residual, float) ** 2))), np.asarray(fit.alpha, float),
                     int(fine.n_dofs), time.perf_counter() - t)


def floor_of(model, freqs_hz, alpha, log=None) -> MeshFloor | None:
    """:func:`mesh_floor` against the model's own refined mesh (:func:`fe_core.io.refined.refined_model`), None
    (and the reason logged) when the model cannot be refined."""
    from .io.refined import refined_model

    t = time.perf_counter()
    fine, why = refined_model(model)
    if fine is not None:
        fine, why = _seen_as(model, fine)
    if fine is None:
        if log is not None:
            log.info("the model's own error from its refined mesh: not measured (%s)", why)
        return None
    built = time.perf_counter() - t
    floor = mesh_floor(model, fine, freqs_hz, alpha)
    floor.seconds += built
    if log is not None:
        log.info("the model's own error from its refined mesh (%d free DOFs): %.2f%% rms of ln|Z| (%.0f s)",
                 floor.fine_dofs, 100 * floor.rms, floor.seconds)
    return floor


def _seen_as(model, fine):
    """``fine`` read through the same channels as ``model`` (a model file's model, or one seen through a
    measurement's channels: its outputs and load chosen by sensor and excitation name), or (None, why)."""
    import dataclasses

    names = list(fine.sensor_names)
    missing = [n for n in model.sensor_names if n not in names]
    if missing:
        return None, f"the refined model has no sensor {missing[0]!r}"
    cols = [names.index(n) for n in model.sensor_names]
    load = fine.load
    if model.excitation_name != fine.excitation_name:
        if model.excitation_name not in list(fine.excitation_names):
            return None, f"the refined model has no excitation {model.excitation_name!r}"
        load = fine.excitation_loads[:, list(fine.excitation_names).index(model.excitation_name)].copy()
    return dataclasses.replace(fine, outputs=fine.outputs[:, cols], load=load,
                               sensor_names=list(model.sensor_names), excitation_name=model.excitation_name,
                               sensor_test_dofs=[fine.sensor_test_dofs[c] for c in cols] if fine.sensor_test_dofs else []), ""
