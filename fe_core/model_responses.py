"""What a :class:`fe_core.model.ParametricModel` answers, in a mixin it inherits (:class:`ModelResponses`):
the receptance at the sensors under the model's load (:meth:`~ModelResponses.frf`), of chosen
(sensor, excitation) channels and their load columns, of a parameter vector, sensor by sensor; the modal
terms of the lowest modes, natural frequencies and labelled mode shapes."""

from __future__ import annotations

import numpy as np

from .assembly import DOFS_PER_NODE
from .solvers import recycle
from .solvers.frf import direct_frf, hz_to_rad, krylov_frf
from .solvers.modal import classify_mode, eigenmodes

__all__ = ["ModelResponses", "FRF_METHODS"]

FRF_METHODS = ("krylov", "direct")


class ModelResponses:
    """FRFs and modes of a :class:`~fe_core.model.ParametricModel`, which inherits them: they use its
    matrices (``stiffness``, ``mass``, ``damping``), outputs and loads."""

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
        else:  # a large model's space starts from its last FE run's (fe_core.solvers.recycle)
            keep = {} if recycle.active(self) else None
            point = np.concatenate([np.ravel(alpha), np.ravel(gamma if gamma is not None else [])])
            Z = krylov_frf(K, M, a, b, F, omegas, self._out_rows, seed=recycle.take(self, point), keep=keep)
            if keep is not None:
                recycle.store(self, keep, point)
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

    def natural_frequencies(self, alpha, n_modes: int = 6, gamma=None, tol: float = 0.0) -> np.ndarray:
        """Lowest natural frequencies, Hz, shape (n_modes,); ``tol``: ARPACK's relative tolerance (0: machine
        precision)."""
        return eigenmodes(self.stiffness(alpha), self.mass(gamma), n_modes, tol=tol)[0]

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
