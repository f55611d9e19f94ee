"""Squared-exponential correlation functions of Eq. (8), isotropic and ARD.

The paper writes the kernel as ``sigma_f^2 exp(-|x - x'|^2 / (2 l))``: the
squared distance is divided by ``2 l``, so ``l`` is a *squared* length scale
(units of input squared), not the usual length scale. This module keeps that
convention everywhere; scikit-learn's ``RBF(length_scale=s)`` corresponds to
``l = s**2``.

The functions return the *correlation* ``R`` (unit diagonal). The signal
variance ``sigma_f^2`` and the nugget are added by the likelihood and the
model, because with the response covariance ``Q`` estimated, ``sigma_f`` is
not identifiable (see :mod:`mrgp_core`).

Isotropic: one ``l`` for all inputs. ARD (automatic relevance determination):
one ``l_d`` per input, ``exp(-sum_d (x_d - x'_d)^2 / (2 l_d))``.

Derivatives are taken with respect to ``log l`` because every trainer searches
the log of the length scales.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist

__all__ = [
    "KERNELS",
    "check_length_scale",
    "squared_distances",
    "squared_differences",
    "correlation",
    "correlation_from_squared",
    "correlation_grad_log_length_scale",
]

#: Kernel names accepted by :func:`check_length_scale` and the model.
KERNELS = ("iso", "ard")


def check_length_scale(length_scale, kernel: str, n_inputs: int) -> np.ndarray:
    """Validate squared length scales for ``kernel`` and return them as an array.

    Parameters
    ----------
    length_scale : float or array_like, shape (1,) or (d,), input units squared
    kernel : {"iso", "ard"}
    n_inputs : int
        Number of inputs ``d``.

    Returns
    -------
    ndarray, shape (1,) for "iso", (d,) for "ard"
    """
    if kernel not in KERNELS:
        raise ValueError(f"unknown kernel {kernel!r}; valid kernels are {', '.join(KERNELS)}")
    ls = np.atleast_1d(np.asarray(length_scale, dtype=float))
    expected = 1 if kernel == "iso" else n_inputs
    if ls.shape != (expected,):
        raise ValueError(f"{kernel} kernel needs {expected} squared length scale(s), got shape {ls.shape}")
    if not np.all(np.isfinite(ls)) or np.any(ls <= 0):
        raise ValueError(f"squared length scales must be finite and positive, got {ls}")
    return ls


def squared_distances(A: np.ndarray, B: np.ndarray | None = None) -> np.ndarray:
    """Pairwise squared Euclidean distances, computed exactly (no expansion).

    Parameters
    ----------
    A : ndarray, shape (n, d)
    B : ndarray, shape (m, d), optional
        Defaults to ``A``.

    Returns
    -------
    ndarray, shape (n, m)
    """
    A = np.asarray(A, dtype=float)
    B = A if B is None else np.asarray(B, dtype=float)
    return cdist(A, B, "sqeuclidean")


def squared_differences(A: np.ndarray, B: np.ndarray | None = None) -> np.ndarray:
    """Per-input squared differences, the building block of the ARD kernel.

    Parameters
    ----------
    A : ndarray, shape (n, d)
    B : ndarray, shape (m, d), optional
        Defaults to ``A``.

    Returns
    -------
    ndarray, shape (d, n, m)
        ``[k, i, j] = (A[i, k] - B[j, k])**2``.
    """
    A = np.asarray(A, dtype=float)
    B = A if B is None else np.asarray(B, dtype=float)
    return (A.T[:, :, None] - B.T[:, None, :]) ** 2


def correlation_from_squared(sq: np.ndarray, length_scale: np.ndarray) -> np.ndarray:
    """Correlation from precomputed squared distances or differences.

    Parameters
    ----------
    sq : ndarray, shape (n, m) or (d, n, m)
        :func:`squared_distances` for the isotropic kernel, or
        :func:`squared_differences` for ARD.
    length_scale : ndarray, shape (1,) or (d,)
        Squared length scales ``l``.

    Returns
    -------
    ndarray, shape (n, m)
    """
    if sq.ndim == 2:
        return np.exp(sq * (-0.5 / length_scale[0]))
    return np.exp(np.tensordot(-0.5 / length_scale, sq, axes=1))


def correlation(A: np.ndarray, B: np.ndarray, length_scale: np.ndarray) -> np.ndarray:
    """Correlation between two sets of inputs without storing per-input differences.

    The inputs are scaled by ``1 / sqrt(l)`` (one scale, or one per input), so
    ``R = exp(-|a~ - b~|^2 / 2)``; this costs ``O(n m)`` memory for either
    kernel, which matters when ``B`` holds 10,000 candidates.

    Parameters
    ----------
    A : ndarray, shape (n, d)
    B : ndarray, shape (m, d)
    length_scale : ndarray, shape (1,) or (d,)
        Squared length scales ``l``.

    Returns
    -------
    ndarray, shape (n, m)
    """
    scale = 1.0 / np.sqrt(length_scale)
    sq = cdist(np.asarray(A, float) * scale, np.asarray(B, float) * scale, "sqeuclidean")
    return np.exp(-0.5 * sq)


def correlation_grad_log_length_scale(R: np.ndarray, sq: np.ndarray, length_scale: np.ndarray) -> np.ndarray:
    """Derivatives of ``R`` with respect to ``log l`` (each length scale).

    ``dR/d(log l) = R * sq / (2 l)`` for the isotropic kernel and
    ``dR/d(log l_d) = R * sq_d / (2 l_d)`` for ARD.

    Parameters
    ----------
    R : ndarray, shape (n, m)
        :func:`correlation_from_squared` of the same ``sq`` and ``length_scale``.
    sq : ndarray, shape (n, m) or (d, n, m)
    length_scale : ndarray, shape (1,) or (d,)

    Returns
    -------
    ndarray, shape (1, n, m) or (d, n, m)
    """
    if sq.ndim == 2:
        return (R * sq * (0.5 / length_scale[0]))[None]
    return R[None] * sq * (0.5 / length_scale)[:, None, None]
