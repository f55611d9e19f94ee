"""MAC, modal scale factor, MAC-based pairing, frequency differences and COMAC.

Definitions (Allemang, "The modal assurance criterion - twenty years of use and abuse", 2003):

- ``MAC(a, b) = |a . b|^2 / ((a . a)(b . b))`` for real shapes (``|a^H b|^2 / (a^H a)(b^H b)`` for complex);
  1 for proportional shapes, 0 for orthogonal ones;
- modal scale factor ``MSF(a, b) = (a . b) / (b . b)``: the factor that brings ``b`` closest to ``a`` in the
  least-squares sense, so ``a - MSF b`` is the part of ``a`` that ``b`` does not explain;
- ``COMAC_j = (sum_r |a_rj b_rj|)^2 / (sum_r a_rj^2 sum_r b_rj^2)`` over paired modes r at DOF j, with each
  shape pair first brought to one scale and sign by the MSF (so COMAC reads the *shape* agreement at a DOF,
  not the arbitrary scale of the test shapes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["mac_matrix", "modal_scale_factor", "pair_modes", "Pairing", "frequency_differences", "comac",
           "pairing_report"]


def _shapes(a, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2:
        raise ValueError(f"{name} must have shape (n_modes, n_dofs), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} holds non-finite values")
    norms = np.einsum("ij,ij->i", a.conj(), a).real
    if np.any(norms <= 0):
        raise ValueError(f"{name}: mode {int(np.flatnonzero(norms <= 0)[0]) + 1} is zero at every DOF")
    return a


def mac_matrix(a, b) -> np.ndarray:
    """MAC of every pair of shapes of ``a`` (rows) and ``b`` (columns).

    Parameters
    ----------
    a : array_like, shape (n_a, n_dofs) (or (n_dofs,)), real or complex
    b : array_like, shape (n_b, n_dofs) (or (n_dofs,))

    Returns
    -------
    ndarray, shape (n_a, n_b), in [0, 1]
    """
    a, b = _shapes(a, "a"), _shapes(b, "b")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"shapes at different DOFs: {a.shape[1]} and {b.shape[1]} values per mode")
    cross = np.abs(a.conj() @ b.T) ** 2
    na = np.einsum("ij,ij->i", a.conj(), a).real
    nb = np.einsum("ij,ij->i", b.conj(), b).real
    return np.clip(cross / np.outer(na, nb), 0.0, 1.0)


def modal_scale_factor(a, b) -> np.ndarray:
    """MSF of each row pair: ``(a_r . b_r) / (b_r . b_r)``, shape (n,); ``a_r ~ MSF_r b_r``."""
    a, b = _shapes(a, "a"), _shapes(b, "b")
    if a.shape != b.shape:
        raise ValueError(f"a and b must have one shape, got {a.shape} and {b.shape}")
    return np.einsum("ij,ij->i", b.conj(), a) / np.einsum("ij,ij->i", b.conj(), b).real


@dataclass
class Pairing:
    """Measured (test) modes paired with model modes.

    Attributes
    ----------
    test, model : ndarray of int, shape (n_pairs,)
        0-based indices of the paired modes, in ascending test order.
    mac : ndarray, shape (n_pairs,)
        MAC of each pair.
    unpaired_test, unpaired_model : list of int
        Test modes no model mode matches with MAC >= threshold; model modes left over.
    messages : list of str
        One sentence per unpaired test mode (its best candidate and MAC), for the report.
    threshold : float
    """

    test: np.ndarray
    model: np.ndarray
    mac: np.ndarray
    unpaired_test: list = field(default_factory=list)
    unpaired_model: list = field(default_factory=list)
    messages: list = field(default_factory=list)
    threshold: float = 0.8

    @property
    def n_pairs(self) -> int:
        return int(self.test.size)


def pair_modes(mac, threshold: float = 0.8, test_names=None, model_names=None) -> Pairing:
    """Pair test modes (rows of ``mac``) with model modes (columns) one to one.

    Rule: the assignment maximising the summed MAC over pairs (the Hungarian algorithm,
    ``scipy.optimize.linear_sum_assignment``), then every pair below ``threshold`` is dropped. A greedy
    "best column per row" pairing would give one model mode to two test modes when two close modes mix;
    the assignment cannot.

    Parameters
    ----------
    mac : array_like, shape (n_test, n_model)
    threshold : float in (0, 1]
    test_names, model_names : list of str, optional
        Names used in the messages (default ``test mode k``, ``model mode k``, 1-based).

    Returns
    -------
    Pairing
    """
    from scipy.optimize import linear_sum_assignment

    mac = np.asarray(mac, dtype=float)
    if mac.ndim != 2:
        raise ValueError(f"mac must be a matrix, got shape {mac.shape}")
    if not 0.0 < threshold <= 1.0:
        raise ValueError(f"threshold must be in (0, 1], got {threshold}")
    n_t, n_m = mac.shape
    test_names = test_names or [f"test mode {k + 1}" for k in range(n_t)]
    model_names = model_names or [f"model mode {k + 1}" for k in range(n_m)]
    rows, cols = linear_sum_assignment(-mac)
    keep = mac[rows, cols] >= threshold
    rows, cols = rows[keep], cols[keep]
    order = np.argsort(rows)
    rows, cols = rows[order], cols[order]
    unpaired = [k for k in range(n_t) if k not in set(rows.tolist())]
    messages = []
    for k in unpaired:
        best = int(np.argmax(mac[k])) if n_m else None
        if best is None:
            messages.append(f"{test_names[k]}: unpaired, the model has no modes to compare")
            continue
        taken = best in set(cols.tolist())
        messages.append(f"{test_names[k]}: unpaired; its best model mode is {model_names[best]} with MAC "
                        f"{mac[k, best]:.2f} (threshold {threshold:g})"
                        + (f", which is paired with another test mode" if taken else ""))
    left = [j for j in range(n_m) if j not in set(cols.tolist())]
    return Pairing(rows, cols, mac[rows, cols], unpaired, left, messages, float(threshold))


def frequency_differences(f_test, f_model, pairing: Pairing) -> np.ndarray:
    """Relative frequency difference of each pair, ``(f_model - f_test) / f_test``, shape (n_pairs,)."""
    f_test, f_model = np.asarray(f_test, float), np.asarray(f_model, float)
    return (f_model[pairing.model] - f_test[pairing.test]) / f_test[pairing.test]


def comac(a, b) -> np.ndarray:
    """COMAC per DOF of paired shapes ``a[r]`` <-> ``b[r]`` (rows already paired), shape (n_dofs,).

    Each ``b[r]`` is first scaled by its MSF onto ``a[r]`` (scale and sign of test shapes are arbitrary).
    1 where the paired shapes agree at the DOF, lower where they disagree; a DOF where every shape
    is zero in both sets gives 1 (nothing disagrees).
    """
    a, b = _shapes(a, "a"), _shapes(b, "b")
    if a.shape != b.shape:
        raise ValueError(f"paired shapes must have one shape, got {a.shape} and {b.shape}")
    b = b * modal_scale_factor(a, b)[:, None]
    num = np.sum(np.abs(a * b.conj()), axis=0) ** 2
    den = np.sum(np.abs(a) ** 2, axis=0) * np.sum(np.abs(b) ** 2, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)


def pairing_report(pairing: Pairing, f_test, f_model, test_names=None, model_names=None) -> list[str]:
    """Lines of a table: test mode, model mode, frequencies, difference, MAC; then the unpaired modes."""
    f_test, f_model = np.asarray(f_test, float), np.asarray(f_model, float)
    test_names = test_names or [f"test mode {k + 1}" for k in range(f_test.size)]
    model_names = model_names or [f"model mode {k + 1}" for k in range(f_model.size)]
    lines = [f"{'test':<16} {'f test Hz':>10} {'model':<16} {'f model Hz':>10} {'diff %':>8} {'MAC':>6}"]
    diffs = frequency_differences(f_test, f_model, pairing)
    for t, m, d, v in zip(pairing.test, pairing.model, diffs, pairing.mac):
        lines.append(f"{test_names[t]:<16} {f_test[t]:>10.3f} {model_names[m]:<16} {f_model[m]:>10.3f} "
                     f"{100 * d:>8.3f} {v:>6.3f}")
    lines += pairing.messages
    return lines
