"""How much memory an update of a mesh model will take, from its files before anything is assembled (issue 41).

:func:`estimate` reads the model file's mesh (meshio: nodes and cells only, seconds), takes the size of K and
of its Cholesky factor from PARDISO's symbolic analysis of the node graph (:func:`fe_core.solvers.fill.mesh_fill`,
a few per cent above the factor PARDISO then makes) and adds up what the run holds at its peak:

* the flow's process: Python with Prefect and the run's data (:data:`MAIN_BASE`), and the model: the segment
  matrices of K and M on their own entries (:data:`MODEL_BYTES_PER_ENTRY` bytes per entry of K);
* Prefect's temporary server (:data:`SERVER`);
* the first read of a model not yet in the model cache: the assembly's temporaries (:data:`ASSEMBLY_BYTES_PER_ENTRY`
  per entry of K, beside the model);
* one FE run: K(alpha) and M(gamma) and the upper triangle PARDISO reads (:data:`RUN_BYTES_PER_ENTRY` per entry
  of K), PARDISO's factor and work space (:data:`FACTOR_BYTES_PER_ENTRY` per entry of L), the Krylov basis
  and its products (``(2 + m) w`` columns of n doubles besides a basis of ``12 w`` columns, ``w`` = the
  excitations plus the sensors: the block the space grows by);
* the global reduced basis of the Gauss-Newton rounds, in the flow's process only, for models between its
  bounds (:func:`fe_core.solvers.reduced_basis.basis_bytes`: up to 720 columns of n doubles and 1.5 GB, 50k to
  721k DOFs);
* FE runs at once: a Gauss-Newton round is one FE run in the flow's process; a global round runs ``n_jobs``
  worker processes (:data:`WORKER_BASE` each), each with its FE run, while the flow waits (its own factor
  freed). The model's pages are shared through the cache (counted once). While the run is under way, a
  round of several FE runs takes as many workers as the memory left then holds (:func:`tasks.machine.runs_that_fit`
  with :attr:`Footprint.per_worker`), one at a time in the flow's process when not two.

The peak is the larger of the two phases. The constants are calibrated on the bracket's tet10 meshes of
118k-464k DOFs against the sampled peak of the whole process tree (``python -m benchmarks.scaling update``;
estimate against measurement in docs/results/scaling.md).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from tasks.machine import MEMORY_ENV, available_bytes

__all__ = ["Footprint", "estimate", "available_bytes", "MEMORY_ENV"]

GB = 1e9
#: The flow's process without the model (Python, numpy/scipy, Prefect, pandas, the run's tables), bytes.
MAIN_BASE = 0.45 * GB
#: An FE worker process without the model (loky; the mapped model is shared), bytes.
WORKER_BASE = 0.25 * GB
#: Prefect's temporary local server, bytes.
SERVER = 0.35 * GB
#: The model's segment matrices (K and M: the union pattern with its sum, each part's slots and values), per
#: entry of K.
MODEL_BYTES_PER_ENTRY = 52.0
#: The assembly's temporaries on the first read (a chunk's triplets, the parts before they are merged), per
#: entry of K.
ASSEMBLY_BYTES_PER_ENTRY = 70.0
#: One FE run's matrices: K(alpha), M(gamma), K's upper triangle for PARDISO, per entry of K.
RUN_BYTES_PER_ENTRY = 36.0
#: PARDISO's factor and work space per entry of L (its own peak, iparm(17): 8.2 bytes per entry of L on the
#: brackets).
FACTOR_BYTES_PER_ENTRY = 8.3
#: Krylov basis columns per column of the starting block (the loads and the sensors): 84 on the bracket
#: (7 columns, 15 lines over five modes).
BASIS_PER_COLUMN = 12


@dataclass(frozen=True)
class Footprint:
    """The estimated peak memory of an update, bytes, and its parts.

    Attributes
    ----------
    model_file : str
    n_dofs, nnz_K, nnz_L : int
        DOFs, entries of K and of its Cholesky factor (:class:`fe_core.solvers.fill.Fill`).
    model, fe_run, assembly : float
        The model held, one FE run (factor, matrices, Krylov space), the first read's temporaries.
    local, parallel : float
        The run's peak in the Gauss-Newton rounds (one FE run in the flow's process) and in a global round
        (``n_jobs`` FE runs in workers).
    n_jobs : int
    """

    model_file: str
    n_dofs: int
    nnz_K: int
    nnz_L: int
    model: float
    fe_run: float
    assembly: float
    local: float
    parallel: float
    n_jobs: int

    @property
    def total(self) -> float:
        return max(self.local, self.parallel)

    @property
    def per_worker(self) -> float:
        """What one more FE run in a worker process needs (the model's pages are shared)."""
        return WORKER_BASE + self.fe_run

    def with_jobs(self, n_jobs: int) -> "Footprint":
        """The same model with ``n_jobs`` FE runs at once."""
        parallel = SERVER + MAIN_BASE + self.model + n_jobs * (WORKER_BASE + self.fe_run) if n_jobs > 1 else 0.0
        return Footprint(self.model_file, self.n_dofs, self.nnz_K, self.nnz_L, self.model, self.fe_run,
                         self.assembly, self.local, parallel, n_jobs)

    def describe(self) -> str:
        parts = [f"the model {self.model / GB:.1f} GB", f"one FE run {self.fe_run / GB:.1f} GB (the factor of K, "
                 f"{self.nnz_L / 1e6:.0f}M entries)"]
        if self.assembly:
            parts.append(f"its first assembly {self.assembly / GB:.1f} GB")
        if self.parallel > self.local:
            parts.append(f"{self.n_jobs} FE runs at once in a global round")
        return (f"{self.model_file} ({self.n_dofs:,} DOFs): about {self.total / GB:.1f} GB at its peak ("
                + ", ".join(parts) + ")")


def _mesh_and_width(model_file: Path) -> tuple[Path, int] | None:
    """The mesh file of a mesh model file and the Krylov block's width, or None for another kind of model."""
    try:
        data = tomllib.loads(model_file.read_text())
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return None  # the model's reader reports it, with the key
    mesh = data.get("mesh")
    if not isinstance(mesh, str) or "solver" in data:
        return None
    path = Path(mesh) if Path(mesh).is_absolute() else model_file.parent / mesh
    sensors = data.get("sensors") if isinstance(data.get("sensors"), list) else []
    excitations = data.get("excitations") if isinstance(data.get("excitations"), list) else []
    return (path if path.exists() else None), max(1, len(excitations)) + len(sensors)


def estimate(model_file: Path, n_jobs: int, n_parameters: int | None = None, cached: bool = False) -> Footprint | None:
    """The :class:`Footprint` of an update of a mesh model file with ``n_jobs`` FE runs at once, or None for a
    model of another kind (matrices, a solver deck) or a file its reader will refuse.

    ``n_parameters``: the parameters whose directions the Jacobian's space carries (default: the file's
    segments); ``cached``: the model is in the model cache already (no assembly).
    """
    from fe_core.io.mesh_file import MeshFileError, read_mesh
    from fe_core.solvers.fill import mesh_fill
    from fe_core.solvers.reduced_basis import basis_bytes

    found = _mesh_and_width(Path(model_file))
    if found is None or found[0] is None:
        return None
    mesh_path, width = found
    try:
        mesh = read_mesh(mesh_path).mesh
    except MeshFileError:
        return None
    fill = mesh_fill(mesh.cells, mesh.n_nodes, fixed_nodes=_clamped_nodes(Path(model_file), mesh))
    if n_parameters is None:
        data = tomllib.loads(Path(model_file).read_text())
        n_parameters = len(data.get("segments", [])) if isinstance(data.get("segments"), list) else 1
    n, z = fill.n_dofs, fill.nnz_K
    basis = 8.0 * n * (BASIS_PER_COLUMN * width + (2 + n_parameters) * width)
    fe_run = FACTOR_BYTES_PER_ENTRY * fill.nnz_L + RUN_BYTES_PER_ENTRY * z + basis
    model = MODEL_BYTES_PER_ENTRY * z
    assembly = 0.0 if cached else ASSEMBLY_BYTES_PER_ENTRY * z
    local = SERVER + MAIN_BASE + model + max(assembly, fe_run + basis_bytes(n))  # the global basis: the flow's only
    out = Footprint(str(model_file), n, z, fill.nnz_L, model, fe_run, assembly, local, 0.0, n_jobs)
    return out.with_jobs(n_jobs)


def _clamped_nodes(model_file: Path, mesh):
    """Nodes of the model file's supports given as a node set and fixed in x, y and z (their DOFs leave K)."""
    data = tomllib.loads(model_file.read_text())
    nodes = []
    for tab in data.get("supports", []) if isinstance(data.get("supports"), list) else []:
        if (isinstance(tab, dict) and isinstance(tab.get("nodes"), str) and tab["nodes"] in mesh.node_sets
                and {"x", "y", "z"} <= set(tab.get("fix", []) if isinstance(tab.get("fix"), list) else [])):
            nodes.append(mesh.node_sets[tab["nodes"]])
    import numpy as np

    return np.unique(np.concatenate(nodes)) if nodes else None
