"""What a run solves, resolved once: the FE model, the measured data matched to it, the search box.

The flow (``flows/problem.py``) builds one :class:`Problem` per run and hands it to every stage; no stage
looks the model up again. FE runs in worker processes (loky, Dask) receive only the small
:class:`ModelRef` and load the model once per process (:func:`worker_model`), so a large mesh is
never pickled per run. A large model (at least :data:`CACHE_MIN_DOFS` free DOFs) is assembled once: the flow
writes it to the model cache (:mod:`fe_core.io.cache`, keyed by the model's checksum and the code) and every
process, the flow's included, maps the cached arrays instead of assembling again (``ModelRef.cache``).

Model names: ``three_plate`` is a shortcut for the benchmark's model file ``data/benchmark/model.toml``;
anything else is the path of a model file (relative to the repository when not absolute).
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ModelRef", "Problem", "MODEL_SHORTCUTS", "DOMAIN_MARGIN", "model_path", "model_checksum",
           "read_model_ref", "worker_model", "search_box", "FE_FOLDER", "black_box", "CACHE_MIN_DOFS",
           "MODEL_CACHE_ENV"]

log = logging.getLogger(__name__)

REPO = Path(__file__).resolve().parents[1]
#: Model names and the model files they stand for.
MODEL_SHORTCUTS = {"three_plate": "data/benchmark/model.toml"}
#: The run's folder of a black-box model's FE runs (one folder per solver run, named by its deck's hash).
FE_FOLDER = "fe"
#: The FE model refuses alpha = -1 (zero stiffness): local solvers and fixed points stay this far inside.
DOMAIN_MARGIN = 1e-3
#: Models with at least this many free DOFs are cached (:func:`read_model_ref`); smaller ones are read in a
#: few seconds, and their cache entries would only fill the disk.
CACHE_MIN_DOFS = 50_000
#: Environment variable: "0" turns the model cache off.
MODEL_CACHE_ENV = "MRGP_MODEL_CACHE"


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
    the run's ``fe/`` folder ("" for in-process models). ``cache``: the model's entry in the model cache
    (:mod:`fe_core.io.cache`), mapped instead of reading the file ("" for none; a worker that cannot reach it,
    on another machine, reads the file).
    """

    name: str
    path: str
    checksum: str
    workdir: str = ""
    cache: str = ""

    def load(self):
        """The model (built once per process for this checksum)."""
        return worker_model(self)


#: Models kept per process (a test process may alternate between a few).
_CACHE_SIZE = 4
_MODELS: dict[tuple[str, str], object] = {}


def worker_model(ref: ModelRef):
    """The model of ``ref``, read from its file the first time this process asks for it.

    The checksum was taken once when the run's problem was resolved; the file is not hashed again here. With
    ``ref.cache`` the model is mapped from its cache entry (named by that checksum), not assembled.
    """
    key = (ref.path, ref.checksum)
    if key not in _MODELS:
        while len(_MODELS) >= _CACHE_SIZE:
            del _MODELS[next(iter(_MODELS))]
        _MODELS[key] = _load(ref)
    model = _MODELS[key]
    if ref.workdir and hasattr(model, "with_workdir"):  # a black-box model: FE runs under the run folder
        return model.with_workdir(ref.workdir)
    return model


def _load(ref: ModelRef):
    from fe_core.io import cache, read_model

    if ref.cache:
        try:
            return cache.load(ref.cache)
        except (OSError, ValueError) as exc:  # e.g. a Dask worker on another machine
            log.info("model cache entry %s not usable here (%s); reading %s", ref.cache, exc, ref.path)
    return read_model(Path(ref.path))


def read_model_ref(name: str, cache_root: str | Path | None = None):
    """(model, :class:`ModelRef`) of a model name or file: hashed and read once (the flow's call).

    ``cache_root``: the model cache's folder (:mod:`fe_core.io.cache`). A model found there is mapped from
    it; one read from its file with at least :data:`CACHE_MIN_DOFS` free DOFs is written there, and this
    process then keeps the mapped copy (its pages shared with the FE workers'), not the assembled one.
    ``MRGP_MODEL_CACHE=0`` turns the cache off.

    Raises :class:`fe_core.io.ModelFileError` for a file that cannot be used.
    """
    from fe_core.io import cache

    path = model_path(name)
    ref = ModelRef(name, str(path), model_checksum(path) if path.exists() else "")
    if cache_root is None or not ref.checksum or os.environ.get(MODEL_CACHE_ENV, "1") == "0":
        return worker_model(ref), ref
    folder = cache.lookup(cache_root, ref.checksum)
    if folder is not None:
        ref = dataclasses.replace(ref, cache=str(folder))
        _MODELS.pop((ref.path, ref.checksum), None)  # an assembled copy read earlier makes way for the shared one
        return worker_model(ref), ref
    model = worker_model(ref)
    if black_box(model) or getattr(model, "n_dofs", 0) < CACHE_MIN_DOFS:
        return model, ref
    try:
        folder = cache.save(model, cache_root, ref.checksum, {"n_dofs": int(model.n_dofs)})
        cache.prune(cache_root)
    except OSError as exc:  # a full or read-only disk: the run goes on without the cache
        log.warning("model cache %s not written (%s); every FE worker assembles the model itself", cache_root, exc)
        return model, ref
    ref = dataclasses.replace(ref, cache=str(folder))
    del model
    _MODELS.pop((ref.path, ref.checksum), None)
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
    worker_bytes : float or None
        The memory one FE run in a worker process needs, estimated from the mesh before the run
        (:attr:`flows.memory.Footprint.per_worker`; None: not a mesh model): a large model's round of several FE
        runs takes as many workers as the memory left then holds (:func:`tasks.machine.runs_that_fit`).
    """

    __slots__ = ("model", "ref", "data", "lower", "upper", "names", "modes", "inputs", "worker_bytes")

    def __init__(self, model, ref: ModelRef, data, lower: np.ndarray, upper: np.ndarray, modes: int = 0,
                 inputs: dict | None = None, worker_bytes: float | None = None):
        self.model, self.ref, self.data, self.worker_bytes = model, ref, data, worker_bytes
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
        return Problem(self.model, self.ref, self.data, self.lower, self.upper, modes, self.inputs, self.worker_bytes)
