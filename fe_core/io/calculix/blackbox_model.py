"""Route B as a model the flows run: a deck whose parameters are relative factors on numbers of the deck.

:class:`BlackBoxDeckModel` answers what the flows ask of a model (its parameters, sensors, excitations and
:meth:`~BlackBoxDeckModel.parameter_frf`) with one ccx run per FE run: the deck written with its numbers
scaled by ``1 + theta_k`` into its own folder ``<workdir>/<SHA-256 of the deck>/``, ccx's modal steady state
(:func:`fe_core.io.calculix.blackbox.run_steady_state`: a complete folder is read again, not run) and the
sensors' complex receptance. It has no solver Jacobians (``exact_jacobians = False``): who needs a derivative
takes forward differences, m + 1 runs that may go in parallel (:meth:`~BlackBoxDeckModel.fd_points`; the
flow's FE stage sends them as one round, :meth:`~BlackBoxDeckModel.frf_jacobian` runs them in threads).

Sensors and excitations are those of the model file (:mod:`fe_core.io.model_toml.calculix_blackbox`) as
vectors on the deck's nodal DOFs (node index * 3 + component): an output of a sensor is a combination of
ccx's printed displacements, a load becomes ``*CLOAD`` lines.
"""

from __future__ import annotations

import copy
import hashlib
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from ...threads import cores, thread_map
from .deck import Deck, NumberRef
from .results import ResultError, read_eigenfrequencies
from .blackbox import run_in_folder, run_steady_state
from .runner import CcxError

__all__ = ["BlackBoxDeckModel", "FD_STEP", "default_workdir"]

#: Forward-difference step on a relative factor: ccx prints 7 significant digits (5e-7 relative), so the
#: derivative's round-off is ~5e-4 of its size, its truncation error ~1e-3 (thickness enters as t^3).
FD_STEP = 1e-3


def default_workdir() -> Path:
    """Where FE runs go outside a run folder: ``$FE_CALCULIX_CACHE/blackbox`` (default under the temp dir)."""
    base = os.environ.get("FE_CALCULIX_CACHE")
    return Path(base) / "blackbox" if base else Path(tempfile.gettempdir()) / "fe-update-blackbox"


@dataclass
class BlackBoxDeckModel:
    """A deck with parameters on its numbers; one ccx run per FE run (see the module docstring)."""

    deck: Deck
    numbers: list                       # NumberRef per parameter
    segment_names: list                 # the model file's parameter names (the runs' columns: alpha_i)
    parameter_bounds: np.ndarray        # (m, 2)
    node_ids: np.ndarray                # deck node id of DOF block k (DOF = 3 k + component)
    outputs: sp.csr_matrix              # (3 n_nodes, n_sensors)
    load: np.ndarray                    # (3 n_nodes,)
    excitation_loads: np.ndarray        # (3 n_nodes, n_excitations)
    sensor_names: list
    excitation_name: str
    excitation_names: list
    sensor_test_dofs: list
    excitation_test_dofs: list
    placements: list
    damping: tuple
    n_modes: int = 40
    timeout: float = 600.0
    source: str = ""
    workdir: str | None = None
    fd_step: float = FD_STEP
    threads: int = 1
    nominal: list = field(init=False)

    exact_jacobians = False             # capability: no solver derivatives; use forward differences
    mesh = None                         # no mesh of our own (model.vtu is not written)
    mass_parameters = np.zeros(0, dtype=np.int64)

    def __post_init__(self):
        self.nominal = [self.deck.number(r) for r in self.numbers]

    # -- what the flows read ------------------------------------------------------------------------
    @property
    def parameter_names(self) -> list[str]:
        """``alpha_1 .. alpha_m``, the run record's columns (the model file's names: ``segment_names``)."""
        return [f"alpha_{i + 1}" for i in range(self.n_parameters)]

    @property
    def n_parameters(self) -> int:
        return len(self.numbers)

    @property
    def n_segments(self) -> int:
        return len(self.numbers)

    @property
    def n_sensors(self) -> int:
        return self.outputs.shape[1]

    @property
    def n_dofs(self) -> int:
        return 3 * len(self.node_ids)

    @property
    def jacobian_cost(self) -> float:
        """FE runs of one forward-difference Jacobian with its point."""
        return float(self.n_parameters + 1)

    def factors(self, theta):
        return np.asarray(theta, float), np.zeros(0)

    def with_workdir(self, workdir) -> "BlackBoxDeckModel":
        """A copy whose FE runs go into ``workdir`` (a run's ``fe/`` folder)."""
        out = copy.copy(self)
        out.workdir = str(workdir)
        return out

    # -- one FE run -----------------------------------------------------------------------------------
    def _folder(self, text: str) -> Path:
        root = Path(self.workdir) if self.workdir else default_workdir()
        return root / hashlib.sha256(text.encode()).hexdigest()[:24]

    def _model_text(self, theta, steps: str) -> str:
        theta = np.asarray(theta, float)
        if theta.shape != (self.n_parameters,) or not np.all(np.isfinite(theta)) or np.any(theta <= -1.0):
            raise ValueError(f"parameters {theta.tolist()}: expected {self.n_parameters} finite factors > -1")
        numbers = {r: v * (1.0 + float(t)) for r, v, t in zip(self.numbers, self.nominal, theta)}
        return self.deck.text(numbers=numbers, steps=steps)

    def _cload(self, F: np.ndarray) -> str:
        rows = np.flatnonzero(F)
        return "\n".join(f"{int(self.node_ids[r // 3])}, {r % 3 + 1}, {float(F[r])!r}" for r in rows)

    def deck_text(self, theta, freqs_hz, F: np.ndarray) -> str:
        """The deck of one FE run: modes stored, one steady-state step per frequency under the load ``F``."""
        rows = np.unique(sp.csr_matrix(self.outputs).nonzero()[0])
        nodes = sorted({int(self.node_ids[r // 3]) for r in rows})
        a, b = self.damping
        zero = "\n".join(line.rsplit(",", 1)[0] + ", 0." for line in self._cload(F).splitlines())
        steps = ["*NSET, NSET=FE_UPDATE_SENSORS\n" + "\n".join(", ".join(map(str, nodes[k:k + 12]))
                                                              for k in range(0, len(nodes), 12)),
                 f"*STEP\n*FREQUENCY, STORAGE=YES\n{self.n_modes}\n*CLOAD\n{zero}\n*END STEP"]
        for f in map(float, np.asarray(freqs_hz, float)):
            steps.append(f"*STEP\n*STEADY STATE DYNAMICS\n{f!r}, {f!r}, 1, 1.\n*MODAL DAMPING, RAYLEIGH\n"
                         f",,{a!r},{b!r}\n*CLOAD\n{self._cload(F)}\n*NODE PRINT, NSET=FE_UPDATE_SENSORS\nU\n*END STEP")
        return self._model_text(theta, "\n".join(steps) + "\n")

    def _response(self, theta, freqs_hz, F: np.ndarray, outputs) -> np.ndarray:
        """(p, k) receptance of the output columns ``outputs`` under ``F`` (one ccx run, or its folder)."""
        text = self.deck_text(theta, freqs_hz, F)
        try:
            disp = run_steady_state(text, self._folder(text), self.timeout, freqs_hz)
        except ResultError as exc:
            raise CcxError(str(exc)) from None
        outputs = sp.csc_matrix(outputs)
        rows = np.unique(outputs.nonzero()[0])
        U = np.column_stack([disp[int(self.node_ids[r // 3])][:, r % 3] for r in rows])
        return U @ outputs[rows].toarray()

    def parameter_frf(self, theta, freqs_hz, channels=None) -> np.ndarray:
        """The complex receptance, shape (p, n_sensors) or (p, n_channels) for ``channels = (responses,
        references)``: one ccx run per reference. Raises CcxError (a failed or timed-out run)."""
        if channels is None:
            return self._response(theta, freqs_hz, self.load, self.outputs)
        responses, references = (np.asarray(c, int) for c in channels)
        out = np.empty((len(np.atleast_1d(freqs_hz)), responses.size), complex)
        for r in np.unique(references):
            cols = np.flatnonzero(references == r)
            out[:, cols] = self._response(theta, freqs_hz, self.excitation_loads[:, r],
                                          sp.csc_matrix(self.outputs)[:, responses[cols]])
        return out

    def frf(self, alpha, freqs_hz, gamma=None, method=None) -> np.ndarray:
        return self.parameter_frf(alpha, freqs_hz)

    # -- forward differences --------------------------------------------------------------------------
    def fd_points(self, theta, upper=None) -> tuple[list[np.ndarray], np.ndarray]:
        """The m + 1 points of a forward-difference Jacobian at ``theta`` and the steps (backward where the
        forward step would leave ``upper``)."""
        theta = np.asarray(theta, float)
        hi = np.full(theta.size, np.inf) if upper is None else np.asarray(upper, float)
        h = np.where(theta + self.fd_step <= hi, self.fd_step, -self.fd_step)
        return [theta] + [theta + h[i] * np.eye(theta.size)[i] for i in range(theta.size)], h

    def frf_jacobian(self, theta, freqs_hz, channels=None, upper=None):
        """``(Z, dZ)``: the receptance and its forward-difference derivative, shape (p, n) and (p, n, m);
        the m + 1 ccx runs in parallel threads (one ccx process each)."""
        points, h = self.fd_points(theta, upper)
        Zs = thread_map(lambda x: self.parameter_frf(x, freqs_hz, channels), points, threads=cores(-1))
        dZ = np.stack([(Zs[i + 1] - Zs[0]) / h[i] for i in range(len(h))], axis=-1)
        return Zs[0], dZ

    # -- modes (the band check) -------------------------------------------------------------------------
    def natural_frequencies(self, alpha, n_modes: int = 6, gamma=None) -> np.ndarray:
        """The lowest ``n_modes`` natural frequencies (Hz) from ccx's ``*FREQUENCY`` (its own folder)."""
        text = self._model_text(alpha, f"*STEP\n*FREQUENCY\n{int(n_modes)}\n*END STEP\n")
        freqs = run_in_folder(text, self._folder(text), self.timeout, lambda f: read_eigenfrequencies(f / "deck.dat"))
        return freqs[:n_modes]
