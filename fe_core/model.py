"""A finite element model parametrised by segment stiffness and mass factors.

``K(alpha) = K_0 + sum_i K_i (1 + alpha_i)`` and ``M(gamma) = M_0 + sum_i M_i (1 + gamma_i)``
(Eq. 2 of Zhou & Tang, plus a fixed remainder ``K_0, M_0`` of cells in no segment,
absent in the benchmark), with Rayleigh damping ``C = a M(gamma) + b K(alpha)``
from the updated matrices. Sensors are output vectors (a DOF, or a direction
combining a node's DOFs) and the structure is driven by one load vector (the
excitation). Models are built by :func:`build_model` (the benchmark's path) or
read from a model file (:func:`fe_core.io.read_model`). Every alpha_i and gamma_i must be finite and
greater than -1; the model refuses anything else before doing any work.

This module holds :func:`check_parameters`, :class:`ParametricModel` (its data, sizes, parameters,
matrices and loads) and :func:`build_model`; the model's FRFs and modes are those of
:class:`fe_core.model_responses.ModelResponses`, which it inherits.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from .assembly import DOFS_PER_NODE, SegmentedMatrix, assemble, cell_dofs, free_dof_map
from .elements.hex8 import element_mass, element_stiffness
from .material import Material
from .mesh import Mesh
from .model_responses import ModelResponses

__all__ = ["ParametricModel", "check_parameters", "build_model"]

log = logging.getLogger(__name__)


def check_parameters(values, n: int, name: str) -> np.ndarray:
    """Validate a parameter vector against the domain ``(-1, inf)``.

    Parameters
    ----------
    values : array_like, shape (n,)
    n : int
        Expected length.
    name : str
        Symbol used in messages, e.g. ``"alpha"``; entries are named 1-based,
        ``alpha_3``, as in the paper.

    Returns
    -------
    ndarray, shape (n,)

    Raises
    ------
    ValueError
        Naming the first offending parameter and its value.
    """
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have {n} entries (one per segment), got shape {arr.shape}")
    for i, v in enumerate(arr):
        if not np.isfinite(v):
            raise ValueError(f"{name}_{i + 1} = {v} is not finite")
        if v <= -1.0:
            raise ValueError(
                f"{name}_{i + 1} = {v} is outside the valid domain: it must be greater than -1 "
                f"(1 + {name}_{i + 1} scales a positive-definite segment matrix)"
            )
    return arr


@dataclass
class ParametricModel(ModelResponses):
    """Segment-parametrised FE model with output vectors (sensors) and a load vector (excitation).

    ``K(alpha) = K_0 + sum_i K_i (1 + alpha_i)``, ``M(gamma) = M_0 + sum_i M_i (1 + gamma_i)``,
    where ``K_0, M_0`` are the fixed remainder (cells in no segment; absent for the benchmark).
    Sensor ``s`` measures ``L[:, s] . u`` and the structure is driven by ``F``.

    Attributes
    ----------
    mesh : Mesh or None
        None for a model given as matrices.
    free_dofs : ndarray, shape (n_free,), int
        Global DOF numbers (``3 * node + component`` for a mesh, rows of the
        DOF table for matrices) of the free DOFs.
    stiffness_segments, mass_segments : SegmentedMatrix
        Segment matrices (and the remainder) restricted to the free DOFs, N/m and kg.
    segment_names : list of str
    damping : (float, float)
        Rayleigh coefficients ``(a [1/s], b [s])``.
    sensor_nodes : ndarray, shape (n_sensors,), int, or None
        Node of each sensor (None when the outputs are given directly); for a model file with
        ``point_placement = "interpolate"``, each sensor's nearest node (its output vector reads the
        element holding the point), for what needs one node (sensor mass, the report).
    sensor_component : int
        0, 1 or 2 for u_x, u_y, u_z (with ``sensor_nodes``).
    segment_masses : list of float, kg
        Mass of each segment (clamped nodes included).
    material : Material or None
        The material the element matrices were built with (None if unknown or several);
        model extensions that add element matrices (:mod:`fe_core.closure.effects`) need it.
    formulation : str or None
        hex8 stiffness formulation, ``"incompatible"`` or ``"plain"``.
    outputs : scipy.sparse.csr_matrix, shape (n_free, n_sensors), or None
        Output vectors ``L`` (a unit entry for a sensor along x, y or z; the
        direction cosines for a sensor along a unit vector). Made from
        ``sensor_nodes`` when None.
    load : ndarray, shape (n_free,), N, or None
        The excitation ``F``; the sum of unit forces at the sensors (the
        benchmark's combined load) when None.
    sensor_names, excitation_name : list of str, str
    n_total_dofs : int or None
        DOFs before constraints (``3 * n_nodes`` for a mesh).
    parameter_bounds : ndarray, shape (n_parameters, 2), or None
        ``(lower, upper)`` of each parameter (:attr:`parameter_names`' order) from the model
        file, +-inf where the file gives none; None = the run's box for every parameter.
    source : str or None
        The model file the model was read from.
    remainder_mass : float, kg
        Mass of the fixed remainder (cells in no segment).
    placements : list of str
        Where each sensor and excitation point landed (node, distance), for the log.
    dof_table : ndarray, shape (n_total_dofs, 2), int, or None
        Node id and direction of each DOF of a matrices model.
    node_coordinates : ndarray, shape (k, 3), m, or None
        Coordinates of the ``k`` nodes of :attr:`dof_table` in ascending node id (a matrices
        model's optional node table); None when not given. A mesh model's are ``mesh.nodes``.
    excitation_nodes : dict or None
        With ``point_placement = "interpolate"``: per excitation name, ``[(nearest node, force vector
        weight * direction), ...]`` of its entries (its load reads the elements holding the points), for the
        report's arrows; None otherwise.
    cell_segment : ndarray, shape (n_cells,), int, or None
        Segment index (0-based, in :attr:`segment_names`' order) of each mesh cell, -1 for
        the fixed remainder; None without a mesh.
    cell_stiffness : callable or None
        ``cell_stiffness(cells) -> (len(cells), d, d)``, N/m: element stiffness matrices of
        mesh cells at alpha = 0, DOFs as :func:`fe_core.assembly.cell_dofs` (model
        extensions that stiffen a set of cells need it; built from ``material`` and
        ``formulation`` when None).
    excitation_loads : ndarray, shape (n_free, n_excitations), N, or None
        Every excitation of the model file, one column each (``load`` is the column of
        ``excitation_name``); ``load`` alone when None. Measured channels with other
        references use them (:meth:`frf_channels`).
    excitation_names : list of str
    sensor_test_dofs, excitation_test_dofs : list of (int, int) or None
        Per sensor / excitation: the test's node id and signed UFF58 direction code
        (``test_node``, ``test_direction`` of the model file), None where not given.
    mass_parameters : ndarray, shape (g,), int
        Segments (0-based, ascending) whose mass factor gamma is updated too; empty for the
        paper's alpha-only parameters. The parameter vector is then
        ``[alpha_1 .. alpha_m, gamma_j for j in mass_parameters]`` (:meth:`factors`).
    """

    mesh: Mesh | None
    free_dofs: np.ndarray
    stiffness_segments: SegmentedMatrix
    mass_segments: SegmentedMatrix
    segment_names: list[str]
    damping: tuple[float, float]
    sensor_nodes: np.ndarray | None = None
    sensor_component: int = 2
    segment_masses: list[float] = field(default_factory=list)
    material: Material | None = None
    formulation: str | None = None
    outputs: sp.csr_matrix | None = None
    load: np.ndarray | None = None
    sensor_names: list[str] = field(default_factory=list)
    excitation_name: str = "combined"
    n_total_dofs: int | None = None
    parameter_bounds: np.ndarray | None = None
    source: str | None = None
    remainder_mass: float = 0.0
    placements: list[str] = field(default_factory=list)
    dof_table: np.ndarray | None = None
    cell_segment: np.ndarray | None = None
    cell_stiffness: Callable[[np.ndarray], np.ndarray] | None = None
    excitation_loads: np.ndarray | None = None
    excitation_names: list[str] = field(default_factory=list)
    sensor_test_dofs: list = field(default_factory=list)
    excitation_test_dofs: list = field(default_factory=list)
    mass_parameters: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    node_coordinates: np.ndarray | None = None
    excitation_nodes: dict | None = None

    def __post_init__(self) -> None:
        self.mass_parameters = np.asarray(self.mass_parameters, dtype=int).ravel()
        if (np.any(np.diff(self.mass_parameters) <= 0) or np.any(self.mass_parameters < 0)
                or np.any(self.mass_parameters >= self.n_segments)):
            raise ValueError(f"mass_parameters must be ascending segment indices below {self.n_segments}, "
                             f"got {self.mass_parameters.tolist()}")
        if self.n_total_dofs is None:
            self.n_total_dofs = self.mesh.n_nodes * DOFS_PER_NODE
        if self.outputs is None:
            position = np.full(self.n_total_dofs, -1)
            position[self.free_dofs] = np.arange(self.free_dofs.size)
            global_dofs = DOFS_PER_NODE * np.asarray(self.sensor_nodes) + self.sensor_component
            rows = position[global_dofs]
            if np.any(rows < 0):
                bad = np.asarray(self.sensor_nodes)[rows < 0]
                raise ValueError(f"sensor nodes {bad.tolist()} lie on constrained DOFs")
            n_s = rows.size
            self.outputs = sp.csr_matrix((np.ones(n_s), (rows, np.arange(n_s))), shape=(self.free_dofs.size, n_s))
        self.outputs = sp.csr_matrix(self.outputs, dtype=float)
        if self.load is None:
            self.load = np.asarray(self.outputs.sum(axis=1)).ravel()
        self.load = np.asarray(self.load, dtype=float)
        if not self.sensor_names:
            self.sensor_names = [f"sensor {j + 1}" for j in range(self.outputs.shape[1])]
        if self.excitation_loads is None:
            self.excitation_loads = self.load[:, None].copy()
            self.excitation_names = [self.excitation_name]
        self.excitation_loads = np.asarray(self.excitation_loads, dtype=float)
        if self.excitation_loads.shape != (self.free_dofs.size, len(self.excitation_names)):
            raise ValueError(f"excitation_loads must have shape (n_free, {len(self.excitation_names)}), "
                             f"got {self.excitation_loads.shape}")
        self.sensor_test_dofs = list(self.sensor_test_dofs) or [None] * self.outputs.shape[1]
        self.excitation_test_dofs = list(self.excitation_test_dofs) or [None] * len(self.excitation_names)
        # The DOFs the outputs read, and how each sensor combines them.
        coo = self.outputs.tocoo()
        self._out_rows = np.unique(coo.row)
        self._out_weights = self.outputs[self._out_rows].toarray()  # (k, n_sensors)

    @property
    def sensor_dofs(self) -> np.ndarray:
        """Free-DOF index of each sensor, shape (n_sensors,), int, when every sensor is one DOF.

        Raises ``ValueError`` for a sensor along a direction that combines DOFs (use :attr:`outputs`).
        """
        L = self.outputs.tocsc()
        for j in range(L.shape[1]):
            col = L.data[L.indptr[j]:L.indptr[j + 1]]
            if col.size != 1 or col[0] != 1.0:
                raise ValueError(f"{self.sensor_names[j]!r} combines several DOFs or is weighted; "
                                 "use the model's output vectors (outputs, read_outputs)")
        return L.indices[L.indptr[:-1]].copy()

    # -- sizes -----------------------------------------------------------
    @property
    def n_segments(self) -> int:
        return self.stiffness_segments.n_segments

    @property
    def n_dofs(self) -> int:
        """Number of free DOFs."""
        return self.free_dofs.size

    # -- geometry --------------------------------------------------------
    def node_position(self, node: int) -> np.ndarray | None:
        """Coordinates of a node, m, shape (3,): the mesh's, or a matrices model's node table's; None when
        the model has neither (or the node is not in it)."""
        if self.mesh is not None:
            return self.mesh.nodes[int(node)].copy()
        if self.node_coordinates is None or self.dof_table is None:
            return None
        ids = getattr(self, "_node_ids_cache", None)
        if ids is None:
            ids = self._node_ids_cache = np.unique(np.asarray(self.dof_table)[:, 0])
        i = int(np.searchsorted(ids, int(node)))
        if i >= ids.size or ids[i] != int(node) or not np.all(np.isfinite(self.node_coordinates[i])):
            return None
        return self.node_coordinates[i].copy()

    @property
    def size_m(self) -> float | None:
        """The structure's size, m: the diagonal of its nodes' bounding box; None without coordinates."""
        xyz = self.mesh.nodes if self.mesh is not None else self.node_coordinates
        if xyz is None:
            return None
        xyz = np.asarray(xyz, float)
        xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
        return float(np.linalg.norm(np.ptp(xyz, axis=0))) if len(xyz) else None

    @property
    def n_sensors(self) -> int:
        return self.outputs.shape[1]

    @property
    def n_parameters(self) -> int:
        """Length of the parameter vector: one alpha per segment plus the updated gammas."""
        return self.n_segments + self.mass_parameters.size

    @property
    def parameter_names(self) -> list[str]:
        """``alpha_1 .. alpha_m`` (stiffness factors, the paper's updating parameters), then
        ``gamma_j`` (mass factor of segment j, 1-based) for each segment whose mass is updated."""
        return ([f"alpha_{i + 1}" for i in range(self.n_segments)]
                + [f"gamma_{j + 1}" for j in self.mass_parameters])

    def factors(self, theta) -> tuple[np.ndarray, np.ndarray | None]:
        """Stiffness and mass factors of a parameter vector.

        Parameters
        ----------
        theta : array_like, shape (n_parameters,)
            ``[alpha_1 .. alpha_m, gamma_j ...]`` in :attr:`parameter_names`' order.

        Returns
        -------
        alpha : ndarray, shape (n_segments,)
        gamma : ndarray, shape (n_segments,), or None
            Zero for segments whose mass is not updated; None when no mass is updated.

        Raises
        ------
        ValueError
            A vector of another length (naming the parameters) or outside the domain (-1, inf).
        """
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.n_parameters,):
            raise ValueError(f"the parameter vector must have {self.n_parameters} entries "
                             f"({', '.join(self.parameter_names)}), got shape {theta.shape}")
        m = self.n_segments
        alpha = check_parameters(theta[:m], m, "alpha")
        if not self.mass_parameters.size:
            return alpha, None
        gamma = np.zeros(m)
        gamma[self.mass_parameters] = theta[m:]
        return alpha, check_parameters(gamma, m, "gamma")

    # -- matrices --------------------------------------------------------
    def _gamma(self, gamma) -> np.ndarray:
        if gamma is None:
            return np.zeros(self.n_segments)
        return check_parameters(gamma, self.n_segments, "gamma")

    def stiffness(self, alpha) -> sp.csr_matrix:
        """``K(alpha)`` on the free DOFs, N/m, shape (n_free, n_free)."""
        alpha = check_parameters(alpha, self.n_segments, "alpha")
        return self.stiffness_segments.combine(1.0 + alpha)

    def mass(self, gamma=None) -> sp.csr_matrix:
        """``M(gamma)`` on the free DOFs, kg, shape (n_free, n_free)."""
        return self.mass_segments.combine(1.0 + self._gamma(gamma))

    def damping_matrix(self, alpha, gamma=None) -> sp.csr_matrix:
        """``C = a M(gamma) + b K(alpha)``, N s/m."""
        a, b = self.damping
        return a * self.mass(gamma) + b * self.stiffness(alpha)

    def total_mass(self, gamma=None) -> float:
        """Total mass in kg, free and clamped nodes included (from the element matrices)."""
        g = self._gamma(gamma)
        return float(sum((1.0 + g[i]) * m for i, m in enumerate(self.segment_masses))) + self.remainder_mass

    # -- loads -----------------------------------------------------------
    def sensor_loads(self) -> np.ndarray:
        """One unit load per sensor, along the sensor's direction, shape (n_free, n_sensors), N.

        These are the output vectors as load cases (by reciprocity, the response at
        the sensors to them is the sensor-by-sensor receptance matrix).
        """
        return self.outputs.toarray()

    def combined_load(self) -> np.ndarray:
        """The excitation, shape (n_free,), N: for the benchmark unit in-phase forces at all sensors."""
        return self.load.copy()

    def read_outputs(self, X: np.ndarray) -> np.ndarray:
        """Sensor readings of response vectors: ``X`` (..., n_free) -> (..., n_sensors)."""
        return X[..., self._out_rows] @ self._out_weights



def build_model(
    mesh: Mesh,
    material: Material,
    segment_cells: dict[str, np.ndarray],
    fixed_nodes: np.ndarray,
    sensor_nodes: Sequence[int],
    damping: tuple[float, float],
    formulation: str = "incompatible",
    sensor_component: int = 2,
) -> ParametricModel:
    """Assemble a :class:`ParametricModel` from a mesh.

    Parameters
    ----------
    mesh : Mesh
    material : Material
    segment_cells : dict of str to ndarray of int
        Ordered segments (name -> cell indices); together they must cover
        every cell exactly once.
    fixed_nodes : ndarray of int
        Nodes with all three translations fixed.
    sensor_nodes : sequence of int
    damping : (a [1/s], b [s])
    formulation : {"incompatible", "plain"}
        Stiffness formulation of the hex8 element.
    sensor_component : int
        Measured component, 2 = u_z.
    """
    owner = np.full(mesh.n_cells, -1)
    for s, cells in enumerate(segment_cells.values()):
        if np.any(owner[cells] >= 0):
            raise ValueError("segments overlap: a cell belongs to two segments")
        owner[cells] = s
    if np.any(owner < 0):
        raise ValueError(f"{int(np.sum(owner < 0))} cells belong to no segment")

    n_total = mesh.n_nodes * DOFS_PER_NODE
    fixed = (DOFS_PER_NODE * np.asarray(fixed_nodes)[:, None] + np.arange(DOFS_PER_NODE)).ravel()
    free = free_dof_map(n_total, fixed)
    coords = mesh.cell_coords
    Ke = element_stiffness(coords, material.D, formulation)
    Me = element_mass(coords, material.rho)
    dofs = cell_dofs(mesh.cells)

    K_parts, M_parts, seg_masses = [], [], []
    for cells in segment_cells.values():
        K = assemble(Ke[cells], dofs[cells], n_total)
        M = assemble(Me[cells], dofs[cells], n_total)
        # Rigid translation in x picks up each node's share of the mass once.
        ux = np.zeros(n_total)
        ux[0::DOFS_PER_NODE] = 1.0
        seg_masses.append(float(ux @ (M @ ux)))
        K_parts.append(K[free][:, free])
        M_parts.append(M[free][:, free])

    model = ParametricModel(
        mesh=mesh,
        free_dofs=free,
        stiffness_segments=SegmentedMatrix.from_matrices(K_parts),
        mass_segments=SegmentedMatrix.from_matrices(M_parts),
        segment_names=list(segment_cells),
        damping=(float(damping[0]), float(damping[1])),
        sensor_nodes=np.asarray(sensor_nodes, dtype=int),
        sensor_component=sensor_component,
        segment_masses=seg_masses,
        material=material,
        formulation=formulation,
        cell_segment=owner,
    )
    log.info(
        "assembled %d cells, %d nodes, %d free DOFs, %d segments (%s hex8)",
        mesh.n_cells,
        mesh.n_nodes,
        free.size,
        len(segment_cells),
        formulation,
    )
    return model
