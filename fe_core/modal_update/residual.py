"""The modal residual: paired frequencies and scale-free shape differences, with mode tracking.

For each measured mode r paired (by MAC, :func:`fe_core.correlation.pair_modes`) with model mode s:

- frequency: ``(f_s - f_r) / (sigma_f f_r)``, ``sigma_f`` the stated relative standard deviation of a
  measured frequency;
- shape: ``(u_r - P_s u_r) / sigma_u``, one entry per test DOF, where ``u_r`` is the measured shape scaled
  to unit norm and ``P_s`` the projection on the model shape at the test DOFs ``psi_s``. This is the
  difference between the measured shape and the model shape scaled by its modal scale factor
  (``MSF psi_s``); its squared norm is exactly ``1 - MAC``. It depends neither on the scale nor the sign of
  either shape, so it serves unscaled OMA shapes and mass-normalised EMA shapes alike. ``sigma_u`` is the
  noise of one DOF of the unit-norm shape: a stated relative shape noise ``sigma_s`` (standard deviation
  of each DOF's value over the shape's RMS value) gives ``sigma_u = sigma_s / sqrt(n_dofs)``.

Mode tracking: every evaluation computes ``n_model`` modes (more than measured) and pairs them anew with the
measured shapes by MAC (the assignment, not the order), so two close modes that swap order along the
update stay paired with their measured partners; :attr:`ModalResidual.swaps` records each change.
"""

from __future__ import annotations

import numpy as np

from ..correlation import mac_matrix, pair_modes
from ..solvers.modal import eigenmodes
from .nelson import eigen_derivatives, parameter_matrices

__all__ = ["ModalResidual", "identifiability"]


class ModalResidual:
    """Residual and exact Jacobian of a model against measured modes.

    Parameters
    ----------
    model : fe_core.model.ParametricModel
    outputs : ndarray or sparse, shape (n_free, n_dofs)
        The model's reading of each test DOF (signed), as the model's sensor output vectors.
    freqs_hz : ndarray, shape (n_test,)
    shapes : ndarray, shape (n_test, n_dofs), any scale
    sigma_f : float
        Relative standard deviation of the measured frequencies (0.002 = 0.2 %).
    sigma_s : float or None
        Relative standard deviation of each shape value (over the shape's RMS); None leaves the shapes out.
    n_model : int
        Model modes computed and paired each evaluation.
    threshold : float
        MAC below which a pair is refused.
    """

    def __init__(self, model, outputs, freqs_hz, shapes, sigma_f=0.002, sigma_s=0.02, n_model=None,
                 threshold=0.6, names=None):
        import scipy.sparse as sp

        self.model = model
        self.L = sp.csc_matrix(outputs)
        self.f_test = np.asarray(freqs_hz, float)
        shapes = np.asarray(shapes, float)
        self.u_test = shapes / np.linalg.norm(shapes, axis=1, keepdims=True)
        # one sign per measured shape, its largest entry positive: the residual u - P u is then free of the
        # scale and sign of both shapes (P, the projection on the model shape, ignores the model's sign)
        big = self.u_test[np.arange(len(self.u_test)), np.argmax(np.abs(self.u_test), axis=1)]
        self.u_test *= np.sign(big)[:, None]
        self.sigma_f, self.sigma_s = float(sigma_f), sigma_s
        self.n_dofs = shapes.shape[1]
        self.sigma_u = None if sigma_s is None else float(sigma_s) / np.sqrt(self.n_dofs)
        self.n_model = int(n_model or min(self.f_test.size + 6, model.n_dofs - 1))
        self.threshold = float(threshold)
        self.names = names or [f"mode {k + 1}" for k in range(self.f_test.size)]
        self.dmats = parameter_matrices(model)
        self.n_evaluations = 0
        self.history: list[dict] = []  # every FE run (eigen-solve): parameters, frequencies, who asked
        self.label = "fit"  # the stage whose FE runs these are (history's "stage")
        self.n_jacobians = 0
        self._modes: dict = {}
        self.swaps: list[str] = []
        self.last_pairs: tuple | None = None
        self._cache: dict = {}
        self.active = np.arange(self.f_test.size)

    def set_active(self, theta) -> "Pairing":
        """Pair at ``theta`` (MAC >= threshold) and keep the paired test modes for the update: the residual
        has one fixed length; each later evaluation pairs these modes anew (assignment, no threshold)."""
        key = tuple(np.asarray(theta, float).tolist())
        if key not in self._modes:
            self._modes = {key: self.modes_at(theta)}
        freqs, psi, *_ = self._modes[key]
        p = self.pairing(psi)
        self.active = p.test.copy()
        self.last_pairs = (tuple(p.test.tolist()), tuple(p.model.tolist()))
        self._cache.clear()
        return p

    def modes_at(self, theta):
        """(freqs Hz (n_model,), shapes at the test DOFs (n_model, n_dofs), full vectors, lam, K, M)."""
        K, M = self.matrices(theta)
        freqs, vecs = eigenmodes(K, M, self.n_model)
        self.history.append({"run": len(self.history) + 1, "stage": self.label,
                             "theta": np.asarray(theta, float).tolist(), "frequencies_hz": freqs.tolist()})
        self.n_evaluations = len(self.history)
        return freqs, (self.L.T @ vecs).T, vecs, (2 * np.pi * freqs) ** 2, K, M

    def matrices(self, theta):
        """(K, M) of the model at ``theta``."""
        alpha, gamma = self.model.factors(theta)
        return self.model.stiffness(alpha), self.model.mass(gamma)

    def pairing(self, psi):
        return pair_modes(mac_matrix(self.u_test, psi), self.threshold, self.names,
                          [f"model mode {k + 1}" for k in range(psi.shape[0])])

    def evaluate(self, theta, jacobian=True) -> dict:
        """Residual (and Jacobian) at ``theta``: dict with ``r`` (n_res,), ``J`` (n_res, n_par) or None,
        ``pairing``, ``f_model`` of the pairs, ``mac``, ``unpaired`` (test-mode names)."""
        from scipy.optimize import linear_sum_assignment

        key = tuple(np.asarray(theta, float).tolist())
        if (key, jacobian) in self._cache:
            return self._cache[(key, jacobian)]
        if (key, True) in self._cache:
            return self._cache[(key, True)]
        if key not in self._modes:
            # one FE run: the eigen-solve (the Jacobian's solves are counted apart)
            self._modes = {key: self.modes_at(theta)}
        freqs, psi, vecs, lam, K, M = self._modes[key]
        pairing = self.pairing(psi)
        mac = mac_matrix(self.u_test[self.active], psi)
        rows, cols = linear_sum_assignment(-mac)
        order = np.argsort(rows)
        pairing.test, pairing.model = self.active[rows[order]], cols[order]
        pairing.mac = mac[rows[order], cols[order]]
        pairs = (tuple(pairing.test.tolist()), tuple(pairing.model.tolist()))
        if self.last_pairs is not None and pairs != self.last_pairs:
            before = dict(zip(*self.last_pairs))
            for t, m in zip(*pairs):
                if t in before and before[t] != m:
                    self.swaps.append(f"{self.names[t]}: model mode {before[t] + 1} -> {m + 1} at evaluation "
                                      f"{self.n_evaluations}")
        self.last_pairs = pairs
        res, rows = [], []
        for t, m in zip(pairing.test, pairing.model):
            res.append((freqs[m] - self.f_test[t]) / (self.sigma_f * self.f_test[t]))
            if self.sigma_u is not None:
                p = psi[m]
                u = self.u_test[t]
                res.extend((u - p * (p @ u) / (p @ p)) / self.sigma_u)
        J = None
        if jacobian:
            self.n_jacobians += 1
            dlam, dphi = eigen_derivatives(K, M, lam, vecs, self.dmats, pairing.model)
            J = self.jacobian(freqs, psi, pairing, dlam, dphi)
        out = {"r": np.asarray(res), "J": J, "pairing": pairing, "f_model_all": freqs,
               "f_model": freqs[pairing.model], "mac": pairing.mac,
               "unpaired": [self.names[k] for k in pairing.unpaired_test]}
        self._cache[(key, jacobian)] = out
        return out

    def jacobian(self, freqs, psi, pairing, dlam, dphi, at_test: bool = False) -> np.ndarray:
        """The residual's derivatives (n_res, p) from the paired modes' eigenvalue and shape derivatives
        (``dlam`` (n_pairs, p), ``dphi`` (n_pairs, n_free, p), :func:`eigen_derivatives`; with ``at_test``
        already read at the test DOFs, (n_pairs, n_dofs, p)), in the rows of :meth:`evaluate`."""
        blocks = []
        for a, (t, m) in enumerate(zip(pairing.test, pairing.model)):
            df = dlam[a] / (8 * np.pi ** 2 * freqs[m])
            blocks.append(df[None, :] / (self.sigma_f * self.f_test[t]))
            if self.sigma_u is not None:
                p = psi[m]
                u = self.u_test[t]
                dp = dphi[a] if at_test else self.L.T @ dphi[a]  # (n_dofs, n_par)
                pp, pu = p @ p, p @ u
                d = -(np.outer(p, u @ dp) + dp * pu) / pp + np.outer(p, 2 * pu * (p @ dp)) / pp ** 2
                blocks.append(d / self.sigma_u)
        return np.vstack(blocks)


def identifiability(dfreq: np.ndarray, names: list[str], rtol: float = 1e-3) -> list[str]:
    """Parameters the paired frequencies cannot determine.

    ``dfreq`` (n_pairs, n_par) are the frequency sensitivities. With fewer paired frequencies than
    parameters, a QR factorisation with column pivoting of the column-normalised sensitivities ranks the
    parameters; those after the numerical rank (``rtol`` of the largest pivot) are not identifiable from
    the frequencies. Returns their names (empty when all are identifiable).
    """
    from scipy.linalg import qr

    S = np.asarray(dfreq, float)
    norms = np.linalg.norm(S, axis=0)
    S = S / np.where(norms > 0, norms, 1.0)
    _, R, piv = qr(S, pivoting=True, mode="economic")
    diag = np.abs(np.diag(R))
    rank = int(np.sum(diag > rtol * diag[0])) if diag.size else 0
    return [names[i] for i in piv[rank:]]
