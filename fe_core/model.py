"""A finite element model parametrised by segment stiffness and mass factors.

``K(alpha) = K_0 + sum_i K_i (1 + alpha_i)`` and ``M(gamma) = M_0 + sum_i M_i (1 + gamma_i)``
(Eq. 2 of Zhou & Tang, plus a fixed remainder ``K_0, M_0`` of cells in no segment,
absent in the benchmark), with Rayleigh damping ``C = a M(gamma) + b K(alpha)``
from the updated matrices. Sensors are output vectors (a DOF, or a direction
combining a node's DOFs) and the structure is driven by one load vector (the
excitation). Models are built by :func:`build_model` (the benchmark's path) or
read from a model file (:func:`fe_core.io.read_model`). Every alpha_i and gamma_i must be finite and
greater than -1; the model refuses anything else before doing any work.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from .assembly import DOFS_PER_NODE, SegmentedMatrix, assemble, cell_dofs, free_dof_map
from .solvers.frf import direct_frf, hz_to_rad, krylov_frf
from .elements.hex8 import element_mass, element_stiffness
from .material import Material
from .mesh import Mesh
from .solvers.modal import classify_mode, eigenmodes

__all__ = ["ParametricModel", "check_parameters", "build_model"]

log = logging.getLogger(__name__)

FRF_METHODS = ("krylov", "direct")


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
class ParametricModel:
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
        Node of each sensor (None when the outputs are given directly).
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

    # -- responses -------------------------------------------------------
    def frf(self, alpha, freqs_hz, gamma=None, method: str = "krylov") -> np.ndarray:
        """Receptance at the sensors under the combined unit load.

        Parameters
        ----------
        alpha : array_like, shape (n_segments,)
        freqs_hz : array_like, shape (p,), Hz
        gamma : array_like, shape (n_segments,), optional
            Mass factors; zero by default.
        method : {"krylov", "direct"}
            ``"direct"`` solves one complex sparse system per frequency
            (reference); ``"krylov"`` projects on a converged Krylov space
            (same result to about 1e-10, several times faster).

        Returns
        -------
        ndarray, shape (p, n_sensors), complex, m/N
            The measured quantity is its modulus.
        """
        return self._solve(alpha, freqs_hz, gamma, method, self.combined_load())[:, :, 0]

    def frf_channels(self, alpha, freqs_hz, responses, references, gamma=None, method: str = "krylov") -> np.ndarray:
        """Receptance of (response sensor, reference excitation) channels.

        One solve with one load column per distinct reference (the Krylov
        space is built for all of them at once), then the channels are picked.

        Parameters
        ----------
        alpha, freqs_hz, gamma, method
            As in :meth:`frf`.
        responses : array_like of int, shape (n_channels,)
            0-based sensor of each channel.
        references : array_like of int, shape (n_channels,)
            0-based excitation (column of :attr:`excitation_loads`) of each channel.

        Returns
        -------
        ndarray, shape (p, n_channels), complex, m/N
            Column j is the response at sensor ``responses[j]`` to a unit
            ``excitation_loads[:, references[j]]``; for every sensor under the
            default excitation it equals :meth:`frf`.
        """
        loads, responses, column = self.channel_loads(responses, references)
        Z = self._solve(alpha, freqs_hz, gamma, method, loads)
        return Z[:, responses, column]

    def channel_loads(self, responses, references) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The load columns a set of channels needs, once each, and how to pick the channels.

        Returns ``(loads (n_dofs, k), responses (n_channels,), column (n_channels,))``: the k distinct
        references' load vectors; a result ``Z[:, sensor, load]`` of one solve with them gives the
        channels as ``Z[:, responses, column]``. Raises ValueError for bad indices.
        """
        responses = np.asarray(responses, dtype=int)
        references = np.asarray(references, dtype=int)
        if responses.shape != references.shape or responses.ndim != 1:
            raise ValueError("responses and references must be 1-D and of one length (one entry per channel)")
        if np.any((responses < 0) | (responses >= self.n_sensors)):
            raise ValueError(f"responses must be sensor indices 0..{self.n_sensors - 1}")
        if np.any((references < 0) | (references >= self.excitation_loads.shape[1])):
            raise ValueError(f"references must be excitation indices 0..{self.excitation_loads.shape[1] - 1}")
        used, column = np.unique(references, return_inverse=True)
        return self.excitation_loads[:, used], responses, column

    def parameter_frf(self, theta, freqs_hz, channels=None, method: str = "krylov") -> np.ndarray:
        """What the updating flow evaluates: the FRF of a parameter vector ``theta``.

        ``theta`` has shape (n_parameters,) (:meth:`factors`). With ``channels``
        None the result is :meth:`frf`, shape (p, n_sensors); with ``channels =
        (responses, references)`` it is :meth:`frf_channels`, shape (p, n_channels).
        Complex, m/N.
        """
        alpha, gamma = self.factors(theta)
        if channels is None:
            return self.frf(alpha, freqs_hz, gamma, method)
        responses, references = channels
        return self.frf_channels(alpha, freqs_hz, responses, references, gamma, method)

    def frf_matrix(self, alpha, freqs_hz, gamma=None, method: str = "krylov") -> np.ndarray:
        """Sensor-by-sensor receptance matrix, one load case per sensor.

        Returns
        -------
        ndarray, shape (p, n_sensors, n_sensors), complex, m/N
            ``[f, i, j]`` is the response at sensor i to a unit load at
            sensor j. Summed over j it equals :meth:`frf`.
        """
        return self._solve(alpha, freqs_hz, gamma, method, self.sensor_loads())

    def _solve(self, alpha, freqs_hz, gamma, method, F) -> np.ndarray:
        if method not in FRF_METHODS:
            raise ValueError(f"unknown FRF method {method!r}; choose one of {FRF_METHODS}")
        freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
        if freqs.ndim != 1 or freqs.size == 0 or np.any(~np.isfinite(freqs)) or np.any(freqs <= 0):
            raise ValueError(f"frequencies must be a non-empty 1-D array of positive values in Hz, got {freqs_hz!r}")
        K = self.stiffness(alpha)
        M = self.mass(gamma)
        a, b = self.damping
        omegas = hz_to_rad(freqs)
        if method == "direct":
            Z = direct_frf(K, M, a * M + b * K, F, omegas, self._out_rows)
        else:
            Z = krylov_frf(K, M, a, b, F, omegas, self._out_rows)
        # (p, k, n_loads) at the output DOFs -> (p, n_sensors, n_loads)
        return np.einsum("pkl,ks->psl", Z, self._out_weights)

    def modal_terms(self, theta, n_modes: int, channels=None) -> tuple[np.ndarray, np.ndarray]:
        """Squared natural circular frequencies and participations of the lowest modes of ``theta``.

        With Rayleigh damping ``C = a M + b K`` the modes decouple the damped system, so the
        receptance of channel c is exactly ::

            Z_c(w) = sum_r P[r, c] / (w_r^2 - w^2 + i w (a + b w_r^2))

        summed over all modes; the lowest ``n_modes`` carry the resonances of a band below their
        frequencies and the rest is a smooth remainder. ``P[r, c] = (l_c . phi_r) (phi_r . f_c)``
        (``phi_r`` mass-normalised, ``l_c`` the channel's output vector, ``f_c`` its load) does not
        depend on the sign of ``phi_r``.

        Parameters
        ----------
        theta : array_like, shape (n_parameters,)
            As in :meth:`parameter_frf`.
        n_modes : int
        channels : (responses, references) or None
            As in :meth:`parameter_frf`: None is every sensor under the default excitation.

        Returns
        -------
        omega2 : ndarray, shape (n_modes,), (rad/s)^2, ascending
        participation : ndarray, shape (n_modes, n_channels), m/N (rad/s)^2
        """
        alpha, gamma = self.factors(theta)
        freqs, vecs = eigenmodes(self.stiffness(alpha), self.mass(gamma), n_modes)
        if channels is None:
            loads, responses, column = self.load[:, None], np.arange(self.n_sensors), np.zeros(self.n_sensors, int)
        else:
            loads, responses, column = self.channel_loads(*channels)
        at_sensors = self.read_outputs(vecs.T)  # (n_modes, n_sensors)
        forces = vecs.T @ loads  # (n_modes, n_loads)
        return (2.0 * np.pi * freqs) ** 2, at_sensors[:, responses] * forces[:, column]

    def natural_frequencies(self, alpha, n_modes: int = 6, gamma=None) -> np.ndarray:
        """Lowest natural frequencies, Hz, shape (n_modes,)."""
        return eigenmodes(self.stiffness(alpha), self.mass(gamma), n_modes)[0]

    def modes(self, alpha, n_modes: int = 6, gamma=None) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """Natural frequencies, nodal mode shapes and labels.

        Returns
        -------
        freqs : ndarray, shape (n_modes,), Hz
        shapes : ndarray, shape (n_modes, n_nodes, 3), or (n_modes, n_total_dofs) without a mesh
            Mass-normalised, zero on constrained DOFs.
        labels : list of str
            ``"z-bending 1"``, ``"torsion 1"``, ... numbered per family, as in
            the benchmark SPEC (symmetry of u_z about y = 0); ``"mode 1"``,
            ``"mode 2"``, ... for a model without a mesh or a mesh that is not
            symmetric about y = 0 (the classification is the benchmark's).
        """
        freqs, vecs = eigenmodes(self.stiffness(alpha), self.mass(gamma), n_modes)
        full = np.zeros((n_modes, self.n_total_dofs))
        full[:, self.free_dofs] = vecs.T
        plain = [f"mode {k + 1}" for k in range(n_modes)]
        if self.mesh is None:
            return freqs, full, plain
        shapes = full.reshape(n_modes, self.mesh.n_nodes, DOFS_PER_NODE)
        try:
            mirror = self._mirror_nodes()
        except ValueError:
            return freqs, shapes, plain
        counts: dict[str, int] = {}
        labels = []
        for shape in shapes:
            family = classify_mode(shape, mirror)
            counts[family] = counts.get(family, 0) + 1
            labels.append(f"{family} {counts[family]}")
        return freqs, shapes, labels

    def _mirror_nodes(self) -> np.ndarray:
        nodes = self.mesh.nodes
        key = {tuple(np.round(p, 9)): i for i, p in enumerate(nodes)}
        mirrored = np.round(nodes * np.array([1.0, -1.0, 1.0]), 9) + 0.0  # +0.0 folds -0.0
        try:
            return np.array([key[tuple(p)] for p in mirrored])
        except KeyError as exc:
            raise ValueError("the mesh is not symmetric about y = 0; modes cannot be labelled") from exc


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
