"""What a run solves, resolved once: the FE model, the measured data matched to it, the search box.

The flow (``flows/problem.py``) builds one :class:`Problem` per run and hands it to every stage; no stage
looks the model up again. FE runs in worker processes (loky, Dask) receive only the small
:class:`ModelRef` and read the model file once per process (:func:`worker_model`), so a large mesh is
never pickled per run.

Model names: ``three_plate`` is a shortcut for the benchmark's model file ``data/benchmark/model.toml``;
anything else is the path of a model file (relative to the repository when not absolute).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ModelRef", "Problem", "MODEL_SHORTCUTS", "DOMAIN_MARGIN", "model_path", "model_checksum",
           "read_model_ref", "worker_model", "search_box", "FE_FOLDER", "black_box"]

REPO = Path(__file__).resolve().parents[1]
#: Model names and the model files they stand for.
MODEL_SHORTCUTS = {"three_plate": "data/benchmark/model.toml"}
#: The run's folder of a black-box model's FE runs (one folder per solver run, named by its deck's hash).
FE_FOLDER = "fe"
#: The FE model refuses alpha = -1 (zero stiffness): local solvers and fixed points stay this far inside.
DOMAIN_MARGIN = 1e-3


def model_path(name: str) -> Path:
    """The model file a model name or path stands for."""
    name = MODEL_SHORTCUTS.get(name, name)
    path = Path(name)
    return path if path.is_absolute() else REPO / path


def model_checksum(path: Path) -> str:
    """SHA-256 over the model file and the files it refers to (mesh, matrices, DOF table)."""
    from fe_core.io import model_files

    digest = hashlib.sha256()
    for f in model_files(path):
        digest.update(f.name.encode() + b"\0" + f.read_bytes())
    return digest.hexdigest()


@dataclass(frozen=True)
class ModelRef:
    """Where a worker finds the run's model: the model file and the checksum of its contents.

    ``name`` is what the run's config says (``three_plate`` or a path), kept for the records. ``workdir``: where
    a black-box model (a solver deck run per FE run, ``exact_jacobians = False``) writes its FE runs' folders,
    the run's ``fe/`` folder ("" for in-process models).
    """

    name: str
    path: str
    checksum: str
    workdir: str = ""

    def load(self):
        """The model (built once per process for this checksum)."""
        return worker_model(self)


#: Models kept per process (a test process may alternate between a few).
_CACHE_SIZE = 4
_MODELS: dict[tuple[str, str], object] = {}


def worker_model(ref: ModelRef):
    """The model of ``ref``, read from its file the first time this process asks for it.

    The checksum was taken once when the run's problem was resolved; the file is not hashed again here.
    """
    from fe_core.io import read_model

    key = (ref.path, ref.checksum)
    if key not in _MODELS:
        while len(_MODELS) >= _CACHE_SIZE:
            del _MODELS[next(iter(_MODELS))]
        _MODELS[key] = read_model(Path(ref.path))
    model = _MODELS[key]
    if ref.workdir and hasattr(model, "with_workdir"):  # a black-box model: FE runs under the run folder
        return model.with_workdir(ref.workdir)
    return model


def read_model_ref(name: str):
    """(model, :class:`ModelRef`) of a model name or file: hashed and read once (the flow's call).

    Raises :class:`fe_core.io.ModelFileError` for a file that cannot be used.
    """
    path = model_path(name)
    ref = ModelRef(name, str(path), model_checksum(path) if path.exists() else "")
    return worker_model(ref), ref


def black_box(model) -> bool:
    """A model without solver Jacobians (route B: a solver deck run per FE run); derivatives by differences."""
    return getattr(model, "exact_jacobians", True) is False


def search_box(model, lower: float, upper: float) -> tuple[np.ndarray, np.ndarray]:
    """The search box, shape (m,) each: the model file's bounds (of alpha, and of gamma where the mass is
    updated) where given, else ``lower``/``upper``."""
    m = model.n_parameters
    lo, hi = np.full(m, float(lower)), np.full(m, float(upper))
    bounds = getattr(model, "parameter_bounds", None)
    if bounds is not None:
        lo = np.where(np.isfinite(bounds[:, 0]), bounds[:, 0], lo)
        hi = np.where(np.isfinite(bounds[:, 1]), bounds[:, 1], hi)
    return lo, hi


class Problem:
    """One run's model, data and box (plain attributes; a class with slots, so Prefect records it as
    ``<Problem>`` instead of encoding the model).

    Attributes
    ----------
    model : fe_core.model.ParametricModel
    ref : ModelRef
        For FE runs in worker processes.
    data : tasks.update_data.UpdateData or None
        The measured channels matched to the model, the selected lines, the residual (None for the closure,
        which fits amplitudes of its own selection).
    lower, upper : ndarray, shape (m,)
        The search box.
    names : list of str
        The parameters, the columns of the run's tables (``alpha_i``, then ``gamma_j``).
    modes : int
        Modes each FE run gives for the paper loop's modal emulation (0: none).
    inputs : dict
        SHA-256 of the files the run reads (``model_checksum``, ``measured_checksum``), for its manifest.
    """

    __slots__ = ("model", "ref", "data", "lower", "upper", "names", "modes", "inputs")

    def __init__(self, model, ref: ModelRef, data, lower: np.ndarray, upper: np.ndarray, modes: int = 0,
                 inputs: dict | None = None):
        self.model, self.ref, self.data = model, ref, data
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.names = list(model.parameter_names)
        self.modes = int(modes)
        self.inputs = dict(inputs or {"model_checksum": ref.checksum})

    def __repr__(self) -> str:
        values = "" if self.data is None else f", values={self.data.n_values}"
        return f"Problem(model={self.ref.name!r}, parameters={self.m}{values})"

    @property
    def m(self) -> int:
        return len(self.names)

    @property
    def solver_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The search box with its lower bound at least ``DOMAIN_MARGIN`` inside the domain's edge -1: the box
        of the polish, the hybrid's Gauss-Newton, the intervals and the nominal model as a sample."""
        return np.maximum(self.lower, -1.0 + DOMAIN_MARGIN), self.upper

    @property
    def nominal(self) -> np.ndarray:
        """The nominal model (every factor 0), inside the solver's box."""
        return np.clip(np.zeros(self.m), *self.solver_box)

    @property
    def freqs_hz(self) -> np.ndarray:
        return np.asarray(self.data.frequencies_hz, float)

    @property
    def channels(self):
        """``(responses, references)`` of the measured channels, or None (the model's sensors, its default
        excitation)."""
        return self.data.channels

    def with_modes(self, modes: int) -> "Problem":
        return Problem(self.model, self.ref, self.data, self.lower, self.upper, modes, self.inputs)
